"""The C step's source-code FMU (``hypa.export.native``) on hand-written steps: a discrete linear system
x⁺ = A x + B u, y = C x + D u (2 states; an input and a scheduling signal; 2 outputs) and a stateless one,
checked against numpy through fmpy's co-simulation (``run_fmu``) and model exchange (``run_native_me``)."""

import shlex
import shutil
import subprocess
import zipfile
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from hypa.export.blocks import ExportError, StateSlot
from hypa.export.fmu import run_fmu
from hypa.export.native import (
    build_native_fmu,
    c_identifier,
    compile_check,
    run_native_me,
    step_sizes,
    time_c_step,
    validate,
)
from hypa.export.reference import Reference

fmpy = pytest.importorskip("fmpy")
validate_fmu = pytest.importorskip("fmpy.validation").validate_fmu
pytestmark = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler")

DT = 0.01  # s
A = np.array([[0.95, 0.08], [-0.1, 0.9]])
B = np.array([[0.05, -0.02], [0.1, 0.03]])
C = np.array([[1.0, 0.0], [0.3, -2.0]])
D = np.array([[0.0, 0.5], [1.5, 0.0]])
X0 = np.array([0.2, -0.4])
DESCRIPTION = {"model": "toy", "dt": DT,
               "inputs": [{"name": "force", "unit": "N", "role": "input"},
                          {"name": "load", "unit": "kg", "role": "scheduling"}],
               "outputs": [{"name": "position", "unit": "m", "role": "output"},
                           {"name": "speed", "unit": "m/s", "role": "output"}]}
SLOTS = [StateSlot("plant", "x", "physics", "m"), StateSlot("plant", "v", "physics", "m/s")]
PARAMETERS = {"mass": (1200.0, "kg"), "cf": (5.0e4, "N/rad")}


def linear_step_c(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> str:
    """The step source of x⁺ = A x + B u, y = C x + D u, as the contract with hypa.export.ccode has it."""
    r, m, p = b.shape[0], d.shape[1], d.shape[0]

    def sums(matrix, vector, i):
        return " + ".join(f"{float(matrix[i, j])!r} * {vector}[{j}]" for j in range(matrix.shape[1])) or "0.0"

    outputs = "\n".join(f"    y[{i}] = {sums(c, 'state', i) if r else '0.0'} + {sums(d, 'u', i)};" for i in range(p))
    states = "\n".join(f"    next_state[{i}] = {sums(a, 'state', i)} + {sums(b, 'u', i)};" for i in range(r))
    unused = "" if r else "    (void)state;\n    (void)next_state;\n"
    return (f"#include <math.h>\n\n#define HYPA_STATE_SIZE {r}\n#define HYPA_INPUT_SIZE {m}\n"
            f"#define HYPA_OUTPUT_SIZE {p}\n\n"
            "static void hypa_step(const double *state, const double *u, double *next_state, double *y) {\n"
            f"{unused}{outputs}\n{states}\n}}\n")


def simulate(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, x0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """y[k] of the linear system from x0 over the rows of u, in numpy."""
    x, ys = x0.copy(), []
    for row in u:
        ys.append(c @ x + d @ row)
        x = a @ x + b @ row
    return np.array(ys)


def reference(x0: np.ndarray, samples: int = 200, first: int = 3) -> Reference:
    """A record of ``samples`` samples from t = 0.5 s, the export taking over at ``first``."""
    rng = np.random.default_rng(0)
    u = np.stack([np.sin(0.05 * np.arange(samples)) + 0.1 * rng.standard_normal(samples),
                  800.0 + 10.0 * rng.standard_normal(samples)], -1)
    return Reference("toy", 0.5 + DT * np.arange(samples), ("force", "load"), u, ("position", "speed"),
                     np.zeros((samples, 2)), np.ones(2), first, x0, 0.0)


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> tuple[Path, Reference, np.ndarray]:
    """The linear system's FMU, its reference and numpy's outputs from the sample ``first`` on."""
    ref = reference(X0)
    path = build_native_fmu(linear_step_c(A, B, C, D), tmp_path_factory.mktemp("native") / "toy.fmu", DESCRIPTION,
                            ref, SLOTS, PARAMETERS)
    return path, ref, simulate(A, B, C, D, X0, ref.u[ref.first :])


def test_the_fmu_validates_and_describes_its_variables(toy) -> None:
    path, ref, _ = toy
    validate(path)
    assert validate_fmu(str(path)) == []
    md = fmpy.read_model_description(str(path))
    assert md.fmiVersion == "2.0" and md.generationTool == "hypa" and md.numberOfEventIndicators == 0
    assert md.coSimulation.modelIdentifier == md.modelExchange.modelIdentifier == "hypa_toy"
    assert md.buildConfigurations[0].sourceFileSets[0].sourceFiles == ["fmu.c"]
    assert float(md.defaultExperiment.startTime) == ref.time[ref.first] and float(md.defaultExperiment.stepSize) == DT
    variables = {v.name: v for v in md.modelVariables}
    assert [v.name for v in md.modelVariables] == ["force", "load", "position", "speed", "initial_state[1]",
                                                   "initial_state[2]", "parameter.mass", "parameter.cf"]
    assert [v.valueReference for v in md.modelVariables] == list(range(8))
    assert (variables["load"].causality, variables["load"].unit, float(variables["load"].start)) == (
        "input", "kg", ref.u[ref.first, 1])
    assert (variables["speed"].causality, variables["speed"].unit) == ("output", "m/s")
    assert float(variables["initial_state[2]"].start) == X0[1] and variables["initial_state[2]"].unit == "m/s"
    assert variables["initial_state[1]"].description == "plant: x (physics)"
    assert (variables["parameter.cf"].causality, variables["parameter.cf"].unit) == ("calculatedParameter", "N/rad")
    assert {u.name for u in md.unitDefinitions} == {"N", "kg", "m", "m/s", "N/rad"}
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
    assert names == {"modelDescription.xml", "binaries/linux64/hypa_toy.so", "documentation/build.txt",
                     *(f"sources/{n}" for n in ("fmu.c", "step.c", "model.h", "buildDescription.xml",
                                                "fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"))}


def test_the_build_description_is_fmi3s(toy, tmp_path) -> None:
    from lxml import etree

    with zipfile.ZipFile(toy[0]) as archive:
        root = etree.fromstring(archive.read("sources/buildDescription.xml"))
    schema = etree.XMLSchema(file=str(Path(fmpy.__file__).parent / "schema" / "fmi3" / "fmi3BuildDescription.xsd"))
    assert schema.validate(root), schema.error_log
    assert root.find("BuildConfiguration").get("modelIdentifier") == "hypa_toy"


def test_co_simulation_and_model_exchange_match_numpy(toy) -> None:
    path, ref, expected = toy
    y, seconds = run_fmu(path, ref)
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12)
    assert seconds > 0
    y, seconds = run_native_me(path, ref)
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12)
    assert seconds > 0


def test_fmpys_model_exchange_simulation_is_its_co_simulation(toy) -> None:
    """fmpy's own drivers, the inputs at their start values: over [t_k, t_k+1) model exchange's outputs are
    co-simulation's at t_k (the state is state[k] in both)."""
    path, ref, _ = toy
    stop = ref.time[ref.first] + 10 * DT
    cs = fmpy.simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=stop, output=["position", "speed"])
    me = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", stop_time=stop, output=["position", "speed"],
                           output_interval=DT / 4)
    for (t, *y), (t_next, *_) in pairwise(cs):
        inside = me[(me["time"] > t + 1e-9) & (me["time"] < t_next - 1e-9)]
        assert len(inside) >= 2
        np.testing.assert_allclose(np.stack([inside["position"], inside["speed"]], -1), np.tile(y, (len(inside), 1)),
                                   rtol=0, atol=1e-12)


def test_fmpys_cmake_build_of_the_sources(toy, tmp_path) -> None:
    """fmpy builds the binary from the sources as modelDescription.xml's SourceFiles list them."""
    if shutil.which("cmake") is None:
        pytest.skip("no cmake")
    from fmpy.build import build_platform_binary

    path, ref, expected = toy
    with zipfile.ZipFile(path) as archive:
        archive.extractall(tmp_path / "fmu", [n for n in archive.namelist() if not n.startswith("binaries/")])
    (tmp_path / "build").mkdir()
    build_platform_binary(str(tmp_path / "fmu"), build_dir=tmp_path / "build", all_warnings=True)
    rebuilt = Path(shutil.make_archive(str(tmp_path / "rebuilt"), "zip", tmp_path / "fmu"))
    np.testing.assert_allclose(run_fmu(rebuilt, ref)[0], expected, rtol=0, atol=1e-12)


def test_do_step_takes_whole_multiples_of_dt_only(toy) -> None:
    """h = 3 dt is three samples; h = 1.5 dt is refused; a parameter set before the initialization holds."""
    from fmpy import extract, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    path, ref, _ = toy
    md = read_model_description(str(path))
    unzipped = extract(str(path))
    try:
        slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="hypa_toy", instanceName="check")
        slave.instantiate()
        t = float(ref.time[ref.first])
        slave.setupExperiment(startTime=t)
        slave.setReal([4, 5], [1.0, 2.0])  # initial_state[1], [2]
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        u = ref.u[ref.first]
        slave.setReal([0, 1], list(u))
        slave.doStep(currentCommunicationPoint=t, communicationStepSize=3 * DT)
        expected = simulate(A, B, C, D, np.array([1.0, 2.0]), np.stack([u] * 4))[-1]
        np.testing.assert_allclose(slave.getReal([2, 3]), expected, rtol=0, atol=1e-12)
        assert slave.getReal([6, 7]) == [1200.0, 5.0e4]
        with pytest.raises(FMICallException):
            slave.doStep(currentCommunicationPoint=t + 3 * DT, communicationStepSize=1.5 * DT)
        with pytest.raises(FMICallException):
            slave.setReal([2], [0.0])  # an output
        slave.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)


def test_the_library_needs_nothing_but_libc_and_libm(toy, tmp_path) -> None:
    ldd = shutil.which("ldd")
    if ldd is None:
        pytest.skip("no ldd")
    with zipfile.ZipFile(toy[0]) as archive:
        library = Path(archive.extract("binaries/linux64/hypa_toy.so", tmp_path))
    listed = subprocess.run([ldd, str(library)], capture_output=True, text=True, check=True).stdout.split("\n")
    needed = {line.split()[0] for line in listed if line.strip()}
    assert needed, listed
    for name in needed:
        assert name.startswith(("linux-vdso", "libc.so", "libm.so", "/lib64/ld-linux", "/lib/ld-linux")), name
    exported = subprocess.run(["nm", "-D", "--defined-only", str(library)], capture_output=True, text=True,
                              check=False).stdout.split()
    if exported:  # binutils' nm: the library exports the fmi2 functions and nothing of the step or the wrapper
        assert "fmi2DoStep" in exported and "fmi2NewDiscreteStates" in exported
        assert not [s for s in exported if s.startswith(("hypa_", "fmu_"))]


def test_the_documented_build_command_builds_it(toy, tmp_path) -> None:
    with zipfile.ZipFile(toy[0]) as archive:
        archive.extractall(tmp_path, [n for n in archive.namelist() if not n.startswith("binaries/")])
    line = next(li for li in (tmp_path / "documentation" / "build.txt").read_text().splitlines() if "Linux:" in li)
    command = shlex.split(line.split("Linux:")[1])
    (tmp_path / "binaries" / "linux64").mkdir(parents=True)
    subprocess.run([shutil.which("gcc") or shutil.which("cc"), *command[1:]], cwd=tmp_path, check=True)
    assert (tmp_path / "binaries" / "linux64" / "hypa_toy.so").stat().st_size > 0


def test_compile_check_passes_the_toy_and_refuses_a_warning(toy, tmp_path) -> None:
    assert compile_check(toy[0]) == ("-Wall", "-Wextra", "-Wpedantic")
    broken = linear_step_c(A, B, C, D).replace("double *y) {\n", "double *y) {\n    int unused = 1;\n")
    path = build_native_fmu(broken, tmp_path / "broken.fmu", DESCRIPTION, reference(X0), SLOTS, PARAMETERS)
    with pytest.raises(ExportError, match="unused") as error:
        compile_check(path)
    assert "\n" not in str(error.value)


def test_a_non_ascii_name_gives_a_c_identifier(tmp_path) -> None:
    name = c_identifier("Fahrzeug-ü 2")
    assert name == "hypa_Fahrzeug___2" and name.isascii() and name.isidentifier()
    ref = reference(X0)
    path = build_native_fmu(linear_step_c(A, B, C, D), tmp_path / "car.fmu", DESCRIPTION | {"model": "Fahrzeug-ü 2"},
                            ref, SLOTS, PARAMETERS)
    md = fmpy.read_model_description(str(path))
    assert md.modelName == "Fahrzeug-ü 2" and md.coSimulation.modelIdentifier == name
    assert validate_fmu(str(path)) == []
    np.testing.assert_allclose(run_fmu(path, ref)[0], simulate(A, B, C, D, X0, ref.u[ref.first :]), rtol=0,
                               atol=1e-12)


def test_a_stateless_step(tmp_path) -> None:
    """r = 0: y = D u, no initial_state parameters; no parameters either."""
    empty = np.zeros((0, 0))
    step_c = linear_step_c(empty, np.zeros((0, 2)), np.zeros((2, 0)), D)
    assert step_sizes(step_c) == (0, 2, 2)
    ref = reference(np.zeros(0))
    path = build_native_fmu(step_c, tmp_path / "static.fmu", DESCRIPTION, ref, [], {})
    assert validate_fmu(str(path)) == []
    assert compile_check(path) == ("-Wall", "-Wextra", "-Wpedantic")
    expected = ref.u[ref.first :] @ D.T
    np.testing.assert_allclose(run_fmu(path, ref)[0], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run_native_me(path, ref)[0], expected, rtol=0, atol=1e-12)
    assert time_c_step(step_c, np.zeros(0), ref.u) > 0


def test_the_step_is_refused_when_it_does_not_fit(tmp_path) -> None:
    with pytest.raises(ExportError, match="sizes"):
        build_native_fmu(linear_step_c(A, B, C, D), tmp_path / "x.fmu", DESCRIPTION, reference(np.zeros(3)),
                         SLOTS, PARAMETERS)
    with pytest.raises(ExportError, match="HYPA_OUTPUT_SIZE"):
        step_sizes("#define HYPA_STATE_SIZE 1\n#define HYPA_INPUT_SIZE 1\n")


def test_without_a_c_compiler_the_export_says_so(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(ExportError, match="needs a C compiler") as error:
        build_native_fmu(linear_step_c(A, B, C, D), tmp_path / "x.fmu", DESCRIPTION, reference(X0), SLOTS, PARAMETERS)
    assert "\n" not in str(error.value) and not (tmp_path / "x.fmu").exists()


def test_time_c_step(toy) -> None:
    _, ref, _ = toy
    seconds = time_c_step(linear_step_c(A, B, C, D), X0, ref.u[ref.first :])
    assert np.isfinite(seconds) and seconds > 0
