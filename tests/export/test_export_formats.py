"""The other export formats: a physics-only model's state space (MATLAB, python-control) and the FMU (fmpy)."""

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from hypa.ann.base import SequenceBlock

from cli_helpers import hypa_run
from conftest import ROOT
from test_export import TINY, _train, physical  # noqa: F401 -- physical: the module's fixture

pytest.importorskip("onnxruntime")
control = pytest.importorskip("control")
fmpy = pytest.importorskip("fmpy")
pytest.importorskip("pythonfmu")


@pytest.fixture(scope="module")
def v2(tmp_path_factory, hypa_cache) -> Path:
    return _train(tmp_path_factory, "v2", ["model=v2", "ann=lstm", "ann.hidden_size=8", *TINY,
                                           "identification.max_seconds=5"])


def _export(folder: Path, out: Path, heads: tuple[str, ...] = (), **kwargs):
    """``export_run`` of a trained run, its networks' ``heads`` set far from their zero start (so that the
    networks show in the outputs); the export and the model."""
    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import export_run

    run = load_run(folder)
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for name in heads:
            head = run.module.model.blocks[name].head
            head.weight.copy_(0.3 * torch.randn(head.weight.shape, generator=generator))
    return export_run(run, run_datamodule(run), out, **kwargs), run.module.model


def _reference(folder: Path, table: str = "reference.csv") -> tuple[dict, np.ndarray, np.ndarray, np.ndarray]:
    """export.json, and from the first exported sample on: the inputs (S, m + q), hypa's outputs (S, p)
    (``table``: reference.csv, float32, or reference_float64.csv) and their σ (p,)."""
    description = json.loads((folder / "export.json").read_text())
    table = np.genfromtxt(folder / table, delimiter=",", names=True)
    first = description["reference"]["first_sample"]
    u = np.stack([table[s["name"]] for s in description["inputs"]], -1)[first:]
    y = np.stack([table[s["name"]] for s in description["outputs"]], -1)[first:]
    std = np.array([description["check"]["outputs"][s["name"]]["std"] for s in description["outputs"]])
    return description, u, y, std


def test_statespace_of_a_physical_run(physical, tmp_path) -> None:  # noqa: F811
    """The composed matrices are the blocks' own, the .mat file and load_statespace hold them, and the
    discrete system from x0 reproduces hypa's free run."""
    from scipy.io import loadmat
    from scipy.signal import cont2discrete

    from hypa.export import load_statespace

    export, model = _export(physical, tmp_path, format="statespace")
    assert set(export.files) == {"model.onnx", "reference.csv", "export.json", "statespace.mat", "statespace.json"}
    assert export.checks["statespace"].passed and "fmu" not in export.checks
    with torch.no_grad():
        track = model.blocks["single_track"].state_space(torch.float64)
        gains = torch.cat([model.blocks[b].state_space(torch.float64).d for b in ("front_steering", "rear_steering")])
    a, b = track.a.numpy(), (track.b @ gains).numpy()  # the steering ratios in series with the single track
    dt = json.loads(export.files["export.json"].read_text())["dt"]
    ad, bd = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), dt, "zoh")[:2]

    mat = loadmat(export.files["statespace.mat"])
    np.testing.assert_allclose(mat["A"], a, rtol=1e-12)
    np.testing.assert_allclose(mat["B"], b, rtol=1e-12)
    np.testing.assert_array_equal(mat["C"], np.eye(2))
    np.testing.assert_array_equal(mat["D"], np.zeros((2, 1)))
    np.testing.assert_allclose(mat["Ad"], ad, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(mat["Bd"], bd, rtol=1e-9, atol=1e-12)
    assert mat["Ts"].item() == dt and "e" not in mat  # no drift: no affine terms
    assert [str(n[0]) for n in mat["StateName"][:, 0]] == ["yaw_rate", "side_slip"]
    assert [str(n[0]) for n in mat["OutputUnit"][:, 0]] == ["rad/s", "rad"]
    names = [str(n[0]) for n in mat["ParameterName"][:, 0]]
    assert mat["ParameterValue"][names.index("cf"), 0] == pytest.approx(
        model.parameters_.as_floats()["cf"], rel=1e-12)

    continuous = load_statespace(export.folder)
    discrete = load_statespace(export.files["statespace.json"], discrete=True)
    np.testing.assert_array_equal(continuous.A, mat["A"])
    assert discrete.dt == dt and continuous.input_labels == ["steering_wheel_angle"]
    assert continuous.output_labels == ["yaw_rate", "side_slip"]
    description, u, y, std = _reference(export.folder)
    x0 = json.loads(export.files["statespace.json"].read_text())["x0"]
    simulated = control.forced_response(discrete, U=u.T, X0=x0).outputs.T  # python-control's own simulation
    assert (np.abs(simulated - y).max(0) / std <= 1e-5).all()
    assert description["checks"]["statespace"]["passed"]
    assert (np.abs(simulated - y).max(0) / std > 0).all()  # the figures are real: not the reference itself


def test_statespace_under_a_first_order_hold(tmp_path_factory, hypa_cache, tmp_path) -> None:
    """Under a first-order hold the discrete system is MATLAB's and scipy's standard form (x̃ = x - Γ_1 u,
    a feedthrough Dd), and its x0 comes from the step's x[k-1], u[k-1]."""
    from scipy.io import loadmat
    from scipy.signal import cont2discrete

    folder = _train(tmp_path_factory, "foh", ["model=physical", "physics.hold=foh", *TINY,
                                              "identification.max_seconds=5"])
    export, _ = _export(folder, tmp_path, format="statespace")
    assert export.checks["statespace"].passed
    mat = loadmat(export.files["statespace.mat"])
    expected = cont2discrete((mat["A"], mat["B"], mat["C"], mat["D"]), mat["Ts"].item(), "foh")[:4]
    for name, value in zip(("Ad", "Bd", "Cd", "Dd"), expected):
        np.testing.assert_allclose(mat[name], value, rtol=1e-8, atol=1e-12, err_msg=name)
    assert np.abs(mat["Dd"]).max() > 0 and str(mat["hold"][0]) == "foh"


def test_statespace_refused_for_a_hybrid_run(v2, tmp_path) -> None:
    from hypa.export import ExportError

    with pytest.raises(ExportError, match=r"format=statespace: block 'rear_steering' is a network") as error:
        _export(v2, tmp_path, format="statespace")
    assert "\n" not in str(error.value) and not list(tmp_path.iterdir())  # nothing written


def _check_fmu(path: Path, description: dict, u: np.ndarray, y: np.ndarray, std: np.ndarray,
               feedthrough: bool = False) -> np.ndarray:
    """The FMU in fmpy over the reference inputs: the largest |FMU - hypa| / σ per output. fmpy's
    ``simulate_fmu`` reads the outputs after a ``doStep`` before it sets the next inputs, so a model
    with ``feedthrough`` is stepped by hand: set the inputs of sample k, read the outputs, ``doStep``."""
    model = fmpy.read_model_description(str(path))
    variables = {v.name: v for v in model.modelVariables}
    for signal in (*description["inputs"], *description["outputs"]):
        assert variables[signal["name"]].unit == (signal["unit"] or None)
    starts = [float(variables[f"initial_state[{i + 1}]"].start) for i in range(len(description["state"]))]
    np.testing.assert_allclose(starts, description["initial_state"], rtol=1e-6, atol=1e-12)
    assert float(model.defaultExperiment.stepSize) == description["dt"]
    dt, t0 = description["dt"], description["reference"]["first_time"]
    names = [s["name"] for s in description["inputs"]]
    signals = np.zeros(len(u), dtype=[("time", float), *((n, float) for n in names)])
    signals["time"] = t0 + dt * np.arange(len(u))
    for i, n in enumerate(names):
        signals[n] = u[:, i]
    outputs = [s["name"] for s in description["outputs"]]
    if not feedthrough:
        result = fmpy.simulate_fmu(str(path), start_time=t0, stop_time=t0 + dt * (len(u) - 1), step_size=dt,
                                   output_interval=dt, input=signals, output=outputs)
        simulated = np.stack([result[n] for n in outputs], -1)
    else:
        fmu = fmpy.instantiate_fmu(fmpy.extract(str(path), path.parent / "unzipped"), model)
        fmu.setupExperiment(startTime=t0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        rows = []
        for k, u_k in enumerate(u):
            fmu.setReal([variables[n].valueReference for n in names], list(u_k))
            rows.append(fmu.getReal([variables[n].valueReference for n in outputs]))
            fmu.doStep(currentCommunicationPoint=t0 + k * dt, communicationStepSize=dt)
        fmu.terminate()
        fmu.freeInstance()
        simulated = np.array(rows)
    assert simulated.shape == y.shape
    return np.abs(simulated - y).max(0) / std


def test_fmu_of_a_physical_run(physical, tmp_path) -> None:  # noqa: F811
    export, _ = _export(physical, tmp_path, format="fmu")
    assert export.checks["fmu"].passed and "statespace" not in export.checks
    description, u, y, std = _reference(export.folder)
    assert (_check_fmu(export.files["model.fmu"], description, u, y, std) <= 1e-5).all()
    variables = {v.name: v for v in fmpy.read_model_description(str(export.files["model.fmu"])).modelVariables}
    assert variables["parameter.cf"].unit == "N/rad" and variables["parameter.cf"].causality == "calculatedParameter"
    assert fmpy.validation.validate_fmu(str(export.files["model.fmu"])) == []


def test_every_format_of_a_hybrid_run(v2, tmp_path) -> None:
    """format=all of V2 (LSTM networks): ONNX and the FMU, the state space skipped with its reason; the FMU's
    step (a network's feedthrough) checked by hypa's own loop and by fmpy's."""
    export, _ = _export(v2, tmp_path, heads=("rear_steering", "correction"), format="all")
    assert set(export.checks) == {"onnx", "fmu", "c"} and all(c.passed for c in export.checks.values())
    assert "network" in export.skipped["statespace"] and "statespace.mat" not in export.files
    description, u, y, std = _reference(export.folder)
    assert description["skipped"] == export.skipped and "model.fmu" in description["files"]
    assert description["checks"]["fmu"]["passed"]
    errors = _check_fmu(export.files["model.fmu"], description, u, y, std, feedthrough=True)
    assert (errors <= 1e-5).all() and (errors > 0).all()
    native = {**description, "initial_state": description["c"]["initial_state"]}  # the float64 step's
    description, u, y, std = _reference(export.folder, "reference_float64.csv")
    assert (_check_fmu(export.files["native.fmu"], native, u, y, std, feedthrough=True) <= 1e-9).all()
    assert description["c"]["model_exchange"]["passed"]


def _library_needs(library: Path) -> set[str]:
    """The shared libraries ``library`` loads (ldd), by name without version."""
    lines = subprocess.run(["ldd", str(library)], capture_output=True, text=True, check=True).stdout.splitlines()
    return {line.split()[0].split(".so")[0].split("/")[-1] for line in lines if line.strip()}


@pytest.mark.skipif(shutil.which("cc") is None or shutil.which("ldd") is None, reason="no C compiler or ldd")
def test_native_fmu_of_a_physical_run_from_the_command_line(physical, hypa_cache, tmp_path) -> None:  # noqa: F811
    """hypa export format=c: native.fmu, a source-code FMU (co-simulation and model exchange) with nothing but
    C inside, validated by fmpy, stepped by fmpy (our own loop) to hypa's float64 free run and within the
    tolerance of its float32 one (reference.csv); its sources compile again with the warnings as errors."""
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    out = tmp_path / "export"
    result = hypa_run(["export", f"run={physical}", "format=c", f"hydra.run.dir={out}"], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "per C FMU (fmpy) step" in result.stdout and "C step (float64" in result.stdout
    path = out / "native.fmu"
    assert fmpy.validation.validate_fmu(str(path)) == []
    model = fmpy.read_model_description(str(path))
    assert model.coSimulation.modelIdentifier == model.modelExchange.modelIdentifier == "hypa_physical"
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
        archive.extractall(tmp_path / "unzipped")
    assert {"sources/step.c", "sources/fmu.c", "sources/fmi2Functions.h", "documentation/build.txt",
            "binaries/linux64/hypa_physical.so"} <= names
    assert not [n for n in names if n.endswith((".py", ".onnx"))]  # no Python, no ONNX inside
    assert _library_needs(tmp_path / "unzipped" / "binaries" / "linux64" / "hypa_physical.so") <= {
        "linux-vdso", "libc", "libm", "ld-linux-x86-64"}
    sources = tmp_path / "unzipped" / "sources"
    compiled = subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", "-O2", "-c", "fmu.c", "-o", str(tmp_path / "a.o")],
                              cwd=sources, capture_output=True, text=True, check=False)
    assert compiled.returncode == 0, compiled.stderr
    description, u, y, std = _reference(out, "reference_float64.csv")
    native = {**description, "initial_state": description["c"]["initial_state"]}
    assert (_check_fmu(path, native, u, y, std, feedthrough=True) <= 1e-9).all()
    _, _, y32, _ = _reference(out)
    assert (_check_fmu(path, native, u, y32, std, feedthrough=True) <= 1e-5).all()
    figures = description["c"]
    assert figures["bare_seconds_per_step"] > 0 and figures["model_exchange"]["passed"]
    assert description["checks"]["c"]["against"] == "hypa float64"


def test_an_operation_without_a_c_form_is_refused_naming_the_network(tmp_path) -> None:
    """A network of one's own whose ONNX has no C form: format=c refuses in one line naming the block and the
    operation; the ONNX and pythonfmu FMU remain for it."""
    import warnings

    from omegaconf import OmegaConf

    from hypa.conf import CONF
    from hypa.export import ExportError, ModelStep
    from hypa.export.api import block_labels
    from hypa.export.ccode import c_step
    from hypa.models.composed import ComposedModel
    from hypa.models.spec import parse_model_spec

    spec = parse_model_spec(OmegaConf.to_container(OmegaConf.load(CONF / "model" / "v1.yaml")))
    scale = dict.fromkeys(("steering_wheel_angle", "yaw_rate", "side_slip"), (0.0, 1.0))
    model = ComposedModel(spec, None, ["steering_wheel_angle"], ["yaw_rate", "side_slip"], scale, scale, 0.01,
                          horizon=10, ann_name="test_export_formats.CumulativeBlock", ann_hparams={})
    step = ModelStep(model.to(torch.float32)).eval()
    path = tmp_path / "step.onnx"
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(step, (torch.zeros(step.state_size), torch.zeros(1)), str(path), dynamo=False,
                          input_names=["state", "u"], output_names=["next_state", "y"], opset_version=17)
    with pytest.raises(ExportError) as error:
        c_step(path, block_labels(model))
    message = str(error.value)
    assert "\n" not in message and "format=fmu" in message
    assert "block 'rear_steering' (CumulativeBlock network) uses the ONNX operation CumSum" in message


class CumulativeBlock(SequenceBlock):
    """A network of one's own whose step runs a cumulative sum (ONNX CumSum, which has no C form in hypa)."""

    def __init__(self, d_in: int, d_out: int, *, zero_init: bool = False) -> None:
        super().__init__(d_in, d_out, zero_init=zero_init)
        self.head = self._make_head(d_in)

    def forward(self, x, state=None):
        state = self.default_state(x.shape[0], x.device, x.dtype) if state is None else state
        return self.head(torch.cumsum(x, -1)), state

    def default_state(self, batch, device, dtype):
        return torch.zeros(batch, 1, dtype=dtype, device=device)


@pytest.mark.slow
def test_every_format_of_a_physical_run_from_the_command_line(physical, hypa_cache, tmp_path) -> None:  # noqa: F811
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    out = tmp_path / "export"
    result = subprocess.run([sys.executable, "-m", "hypa", "export", f"run={physical}", "format=all",
                             f"hydra.run.dir={out}"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
                            check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    for engine in ("ONNX", "FMU (fmpy)", "state space (numpy)"):
        assert f"per {engine} step" in result.stdout
    assert "skipped" not in result.stdout
    assert {p.name for p in out.iterdir()} >= {"model.onnx", "model.fmu", "statespace.mat", "statespace.json",
                                               "reference.csv", "export.json"}
