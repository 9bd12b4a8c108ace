"""The C step as a source-code FMI 2.0 FMU, co-simulation and model exchange, with its binary for this machine.

The step's C99 source (``step.c``: ``hypa_step`` and ``HYPA_STATE_SIZE``, ``HYPA_INPUT_SIZE``,
``HYPA_OUTPUT_SIZE``) travels in the FMU with a hand-written FMI 2.0 wrapper (``hypa/export/c/fmu.c``,
which includes ``step.c`` and the generated ``model.h``: one compilation unit), the FMI 2.0 headers (from
fmpy) and a build description; ``binaries/<platform>/`` holds the library the machine's C compiler built
from them, which needs nothing but libc and libm. The variables are today's pythonfmu FMU's
(``hypa.export.fmu``): the inputs and scheduling signals, the outputs (direct feedthrough), the fixed
parameters ``initial_state[i]`` and the read-only calculated parameters ``parameter.<name>``, SI with units.

The step is a discrete-time system on the grid t_k = startTime + k dt:

* co-simulation: ``fmi2DoStep(t, h)`` advances h / dt samples (h a whole multiple of dt), inputs held;
  fmpy steps it with ``hypa.export.fmu.run_fmu``;
* model exchange: no continuous states; the event iteration at t_k (``fmi2NewDiscreteStates``) latches
  state[k+1] from state[k] and the inputs at t_k, the one at t_{k+1} makes it the state (sample and hold),
  each asks for the next time event; over [t_k, t_{k+1}) the state is state[k] and the outputs follow the
  inputs, as in co-simulation between communication points; :func:`run_native_me` steps it.

``compile_check`` compiles the sources again with the warnings as errors, ``validate`` runs fmpy's
validation, ``time_c_step`` times the bare C step.
"""

from __future__ import annotations

import platform
import re
import shutil
import subprocess
import tempfile
import time
import uuid
import zipfile
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING
from xml.etree import ElementTree

import numpy as np

from hypa.core.compiler import c_compiler as core_compiler
from hypa.core.compiler import compile_c, first_error
from hypa.export.blocks import ExportError

if TYPE_CHECKING:
    from hypa.export.blocks import StateSlot
    from hypa.export.reference import Reference

PLATFORMS = {("Linux", "x86_64"): "linux64", ("Linux", "amd64"): "linux64", ("Darwin", "x86_64"): "darwin64",
             ("Darwin", "arm64"): "darwin64", ("Windows", "amd64"): "win64", ("Windows", "x86_64"): "win64"}
SUFFIXES = {"linux64": ".so", "darwin64": ".dylib", "win64": ".dll"}
HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
LIBRARY_FLAGS = ("-shared", "-fPIC", "-O2", "-std=c99", "-fvisibility=hidden")
# compile_check: the strictest set of warnings the sources compile without (as errors), tried in this order
WARNING_LEVELS = (("-Wall", "-Wextra", "-Wpedantic"), ("-Wall",))
SIZES = ("HYPA_STATE_SIZE", "HYPA_INPUT_SIZE", "HYPA_OUTPUT_SIZE")
PARAMETER_TEXT = "fitted value, read-only: the step has it baked in"
C_SOURCES = Path(__file__).parent / "c"  # fmu.c: the FMI 2.0 wrapper; bench.c: time_c_step's program




def c_identifier(name: str) -> str:
    """An FMU model identifier from a model's name: an ASCII C identifier, "hypa_" and the name with every
    character outside [A-Za-z0-9_] replaced by "_"."""
    return "hypa_" + re.sub(r"[^A-Za-z0-9_]", "_", name)


def platform_folder() -> str:
    """The FMI 2.0 binaries folder of this machine (linux64, darwin64, win64); ``ExportError`` on others."""
    key = (platform.system(), platform.machine().lower())
    if key not in PLATFORMS:
        raise ExportError(f"format=c: no FMI 2.0 platform for {key[0]} on {key[1]} "
                          "(linux64, darwin64 and win64 are)")
    return PLATFORMS[key]


def c_compiler() -> str:
    """The machine's C compiler (cc, gcc or clang from PATH); ``ExportError`` when there is none."""
    found = core_compiler()
    if found is None:
        raise ExportError("format=c needs a C compiler: none of cc, gcc, clang is on PATH")
    return found


def step_sizes(step_c: str) -> tuple[int, int, int]:
    """(r, m + q, p): the state, input and output sizes the step source defines."""
    sizes = []
    for name in SIZES:
        found = re.search(rf"^\s*#\s*define\s+{name}\s+\(?\s*(\d+)\s*\)?", step_c, re.MULTILINE)
        if found is None:
            raise ExportError(f"the C step source defines no {name}")
        sizes.append(int(found.group(1)))
    return sizes[0], sizes[1], sizes[2]


def build_native_fmu(step_c: str, path: Path, description: dict, reference: Reference, slots: list[StateSlot],
                     parameters: dict[str, tuple[float, str]]) -> Path:
    """Write the source-code FMU of the C step ``step_c`` to ``path``, its binary built for this machine;
    ``description``: ``export.json``'s contents ("model", "dt", "inputs", "outputs": names and units)."""
    folder, cc = platform_folder(), c_compiler()
    _check_step(step_c, description, reference, slots, parameters)
    name = c_identifier(description["model"])
    guid = "{" + str(uuid.uuid4()) + "}"
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sources = root / "sources"
        sources.mkdir()
        _write_sources(sources, step_c, description, reference, parameters, guid)
        (root / "modelDescription.xml").write_bytes(
            _model_description(name, guid, description, reference, slots, parameters))
        (root / "documentation").mkdir()
        (root / "documentation" / "build.txt").write_text(_build_text(name), encoding="utf-8")
        library = root / "binaries" / folder / f"{name}{SUFFIXES[folder]}"
        library.parent.mkdir(parents=True)
        extra = ["-Wl,-z,defs"] if folder == "linux64" else []
        _compile([cc, *LIBRARY_FLAGS, *extra, "-o", str(library), "fmu.c", "-lm"], sources, "build the FMU's binary")
        _zip(root, Path(path))
    return Path(path)


def _check_step(step_c: str, description: dict, reference: Reference, slots: list[StateSlot],
                 parameters: dict[str, tuple[float, str]]) -> None:
    """``ExportError`` unless the step source's sizes are the export's and the reference's, and the values the
    FMU holds are finite."""
    r, m, p = step_sizes(step_c)
    inputs = [s["name"] for s in description["inputs"]]
    outputs = [s["name"] for s in description["outputs"]]
    if (r, m, p) != (len(reference.initial_state), len(inputs), len(outputs)) or len(slots) != r:
        raise ExportError(f"the C step's sizes (state {r}, inputs {m}, outputs {p}) are not the export's (state "
                          f"{len(reference.initial_state)}, inputs {len(inputs)}, outputs {len(outputs)})")
    if tuple(inputs) != tuple(reference.input_names) or tuple(outputs) != tuple(reference.output_names):
        raise ExportError("export.json's inputs and outputs are not the reference's, in name or order")
    values = [*reference.initial_state, *reference.u[reference.first], *(v for v, _ in parameters.values())]
    if not np.isfinite(values).all() or not float(description["dt"]) > 0:
        raise ExportError("the initial state, the first inputs or the parameters are not finite, or dt is not "
                          "positive: the FMU cannot hold them")


def _write_sources(sources: Path, step_c: str, description: dict, reference: Reference,
                   parameters: dict[str, tuple[float, str]], guid: str) -> None:
    """sources/: step.c, fmu.c, model.h, the FMI 2.0 headers (from fmpy) and buildDescription.xml."""
    try:
        import fmpy
    except ImportError as error:
        raise ExportError(f"format=c needs fmpy (its FMI 2.0 headers): pip install -e '.[export]' ({error})") \
            from None
    headers = Path(fmpy.__file__).parent / "c-code"
    for header in HEADERS:
        shutil.copy(headers / header, sources / header)
    (sources / "step.c").write_text(step_c, encoding="utf-8")
    shutil.copy(C_SOURCES / "fmu.c", sources / "fmu.c")
    (sources / "model.h").write_text(_model_h(description, reference, parameters, guid), encoding="utf-8")
    (sources / "buildDescription.xml").write_bytes(_build_description(c_identifier(description["model"])))


def _c_array(name: str, values) -> str:
    """A static const double array of ``values`` (one 0 where there are none: C99 has no empty arrays)."""
    items = [repr(float(v)) for v in values] or ["0.0"]
    return f"static const double {name}[{len(items)}] = {{{', '.join(items)}}};\n"


def _model_h(description: dict, reference: Reference, parameters: dict[str, tuple[float, str]], guid: str) -> str:
    """model.h: the GUID, the sizes, dt and the start time [s], and the start values, SI."""
    return ("/* This model's constants, for fmu.c (written by hypa.export.native): SI, times in s. */\n"
            f"#define FMU_GUID \"{guid}\"\n"
            f"#define FMU_STATE_SIZE {len(reference.initial_state)}\n"
            f"#define FMU_INPUT_SIZE {len(description['inputs'])}\n"
            f"#define FMU_OUTPUT_SIZE {len(description['outputs'])}\n"
            f"#define FMU_PARAMETER_COUNT {len(parameters)}\n"
            f"#define FMU_DT {float(description['dt'])!r}\n"
            f"#define FMU_START_TIME {float(reference.time[reference.first])!r}\n"
            + _c_array("fmu_initial_state", reference.initial_state)
            + _c_array("fmu_input_start", reference.u[reference.first])
            + _c_array("fmu_parameters", [value for value, _ in parameters.values()]))


def _build_description(name: str) -> bytes:
    """sources/buildDescription.xml (FMI 3.0's form): one C99 compilation unit, fmu.c, and libm."""
    root = ElementTree.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    configuration = ElementTree.SubElement(root, "BuildConfiguration", {
        "modelIdentifier": name, "description": "fmu.c includes step.c, model.h and the FMI 2.0 headers"})
    files = ElementTree.SubElement(configuration, "SourceFileSet", {"language": "C99"})
    ElementTree.SubElement(files, "SourceFile", {"name": "fmu.c"})
    ElementTree.SubElement(configuration, "Library", {"name": "m", "description": "the C math library"})
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)


def _build_text(name: str) -> str:
    """documentation/build.txt: the command that builds the binary from the sources."""
    return (f"{name}: a source-code FMI 2.0 FMU (co-simulation and model exchange) written by hypa.\n"
            "sources/fmu.c is its one compilation unit (it includes step.c, model.h and the FMI 2.0 headers\n"
            "beside it). In the unzipped FMU's folder:\n\n"
            f"  Linux:   gcc {' '.join(LIBRARY_FLAGS)} -o binaries/linux64/{name}.so sources/fmu.c -lm\n"
            f"  macOS:   clang {' '.join(LIBRARY_FLAGS)} -o binaries/darwin64/{name}.dylib sources/fmu.c\n"
            f"  Windows: cl /nologo /LD /O2 sources\\fmu.c /Fe:binaries\\win64\\{name}.dll\n")


def _variables(description: dict, reference: Reference, slots: list[StateSlot],
               parameters: dict[str, tuple[float, str]]) -> list[tuple[dict, dict]]:
    """(ScalarVariable's attributes, Real's) of each variable, in value-reference order."""
    def variable(name, causality, variability, text, unit, start=None, initial=None):
        attributes = {"name": name, "valueReference": "", "description": text, "causality": causality,
                      "variability": variability} | ({"initial": initial} if initial else {})
        real = ({"unit": unit} if unit else {}) | ({} if start is None else {"start": repr(float(start))})
        return attributes, real

    rows = [variable(s["name"], "input", "continuous", "scheduling signal" if s.get("role") == "scheduling"
                     else "input", s["unit"], start) for s, start in zip(description["inputs"],
                                                                         reference.u[reference.first])]
    rows += [variable(s["name"], "output", "continuous", "output: the step's at the state and inputs now",
                      s["unit"]) for s in description["outputs"]]
    rows += [variable(f"initial_state[{i + 1}]", "parameter", "fixed", f"{s.block}: {s.name} ({s.kind})", s.unit,
                      start, "exact") for i, (s, start) in enumerate(zip(slots, reference.initial_state))]
    rows += [variable(f"parameter.{n}", "calculatedParameter", "fixed", PARAMETER_TEXT, unit, initial="calculated")
             for n, (_, unit) in parameters.items()]
    for vr, (attributes, _) in enumerate(rows):
        attributes["valueReference"] = str(vr)
    return rows


def _model_description(name: str, guid: str, description: dict, reference: Reference, slots: list[StateSlot],
                       parameters: dict[str, tuple[float, str]]) -> bytes:
    """modelDescription.xml (FMI 2.0): both interfaces, the units, the default experiment, the variables and
    the model structure."""
    root = ElementTree.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": description["model"], "guid": guid,
        "description": f"hypa model {description['model']}: one step of {description['dt']:g} s (C, sources/step.c)",
        "generationTool": "hypa",
        "generationDateAndTime": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    common = {"modelIdentifier": name, "needsExecutionTool": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
              "canNotUseMemoryManagementFunctions": "false", "canGetAndSetFMUstate": "false",
              "canSerializeFMUstate": "false", "providesDirectionalDerivative": "false"}
    interfaces = [("ModelExchange", {"completedIntegratorStepNotNeeded": "true"}),
                  ("CoSimulation", {"canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
                                    "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false"})]
    for tag, own in interfaces:
        element = ElementTree.SubElement(root, tag, common | own)
        ElementTree.SubElement(ElementTree.SubElement(element, "SourceFiles"), "File", {"name": "fmu.c"})
    rows = _variables(description, reference, slots, parameters)
    units = sorted({real["unit"] for _, real in rows if "unit" in real})
    if units:
        definitions = ElementTree.SubElement(root, "UnitDefinitions")
        for unit in units:
            ElementTree.SubElement(definitions, "Unit", {"name": unit})
    categories = ElementTree.SubElement(root, "LogCategories")
    ElementTree.SubElement(categories, "Category", {"name": "logStatusError", "description": "errors"})
    ElementTree.SubElement(root, "DefaultExperiment", {"startTime": repr(float(reference.time[reference.first])),
                                                       "stepSize": repr(float(description["dt"]))})
    variables = ElementTree.SubElement(root, "ModelVariables")
    for attributes, real in rows:
        ElementTree.SubElement(ElementTree.SubElement(variables, "ScalarVariable", attributes), "Real", real)
    _model_structure(root, rows)
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)


def _model_structure(root: ElementTree.Element, rows: list[tuple[dict, dict]]) -> None:
    """ModelStructure: the outputs (on every input and state), and the initial unknowns: the outputs and
    the calculated parameters (on nothing)."""
    structure = ElementTree.SubElement(root, "ModelStructure")
    causalities = [attributes["causality"] for attributes, _ in rows]
    outputs = [i + 1 for i, c in enumerate(causalities) if c == "output"]
    if outputs:
        element = ElementTree.SubElement(structure, "Outputs")
        for index in outputs:
            ElementTree.SubElement(element, "Unknown", {"index": str(index)})
    unknowns = [(i + 1, c) for i, c in enumerate(causalities) if c in ("output", "calculatedParameter")]
    if unknowns:
        element = ElementTree.SubElement(structure, "InitialUnknowns")
        for index, causality in unknowns:
            ElementTree.SubElement(element, "Unknown", {"index": str(index)}
                                   | ({"dependencies": ""} if causality == "calculatedParameter" else {}))


def _zip(root: Path, path: Path) -> None:
    """The folder ``root`` as the FMU ``path``, modelDescription.xml first."""
    files = sorted((p for p in root.rglob("*") if p.is_file()), key=lambda p: (p.name != "modelDescription.xml", p))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for file in files:
            archive.write(file, file.relative_to(root).as_posix())


def _compile(command: list[str], cwd: Path, what: str) -> None:
    """Run the compiler; ``ExportError`` with its first error line when it fails."""
    error = compile_c(command, cwd)
    if error:
        raise ExportError(f"the C compiler ({Path(command[0]).name}) could not {what}: {error}")


def _sources(path: Path, tmp: Path) -> Path:
    """The sources folder of an FMU (a zip, unzipped into ``tmp``), of an unzipped FMU, or ``path`` itself."""
    if path.is_file():
        with zipfile.ZipFile(path) as archive:
            archive.extractall(tmp, [n for n in archive.namelist() if n.startswith("sources/")])
        path = tmp
    sources = path / "sources" if (path / "sources").is_dir() else path
    if not (sources / "fmu.c").is_file():
        raise ExportError(f"{path} holds no FMU sources (sources/fmu.c)")
    return sources


def compile_check(path: Path) -> tuple[str, ...]:
    """Compile the FMU's sources (``path``: the FMU, its unzipped folder or its sources/) once more, C99, -O2,
    the warnings errors: the strictest of ``WARNING_LEVELS`` they pass, returned; ``ExportError`` with the
    compiler's first error line when they fail even -Wall."""
    cc = c_compiler()
    with tempfile.TemporaryDirectory() as tmp:
        sources = _sources(Path(path), Path(tmp))
        for flags in WARNING_LEVELS:
            command = [cc, "-std=c99", "-O2", *flags, "-Werror", "-c", "-o", str(Path(tmp) / "fmu.o"), "fmu.c"]
            error = compile_c(command, sources)
            if not error:
                return flags
    raise ExportError(f"the FMU's C sources do not compile with -std=c99 -O2 {' '.join(WARNING_LEVELS[-1])} "
                      f"-Werror: {error}")


def validate(path: Path) -> None:
    """fmpy's validation of the FMU (its modelDescription.xml against the schema, the model structure, the
    units, the start values); ``ExportError`` listing the problems otherwise."""
    from fmpy.validation import validate_fmu

    problems = validate_fmu(str(path))
    if problems:
        raise ExportError(f"the FMU {Path(path).name} does not validate (fmpy): "
                          + "; ".join(" ".join(str(p).split()) for p in problems))


def run_native_me(path: Path, reference: Reference) -> tuple[np.ndarray, float]:
    """The FMU's model exchange through fmpy over the reference record from the sample ``first`` on: at the
    time event t_k set the inputs of sample k, run the event iteration (the state becomes state[k], state[k+1]
    is latched), read the outputs. Outputs (S, p) and the seconds per sample."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Model

    description = read_model_description(str(path))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    inputs, outputs = [refs[n] for n in reference.input_names], [refs[n] for n in reference.output_names]
    dt = float(description.defaultExperiment.stepSize)
    rows = reference.u[reference.first :]
    unzipped = extract(str(path))
    try:
        model = FMU2Model(guid=description.guid, unzipDirectory=unzipped,
                          modelIdentifier=description.modelExchange.modelIdentifier, instanceName="check")
        model.instantiate()
        t = float(reference.time[reference.first])
        model.setupExperiment(startTime=t)
        model.enterInitializationMode()
        model.exitInitializationMode()
        ys = []
        started = time.perf_counter()
        for k, u in enumerate(rows):
            if k > 0:  # continuous-time mode up to the time event t
                model.setTime(t)
                model.completedIntegratorStep()
                model.enterEventMode()
            model.setReal(inputs, [float(v) for v in u])
            next_time = _time_event(model, t, dt)
            ys.append(model.getReal(outputs))
            model.enterContinuousTimeMode()
            t = next_time
        seconds = (time.perf_counter() - started) / max(len(rows), 1)
        model.terminate()
        model.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    return np.array(ys, dtype=float).reshape(len(rows), -1), seconds


def _time_event(model, t: float, dt: float) -> float:
    """The event iteration at ``t`` (fmi2NewDiscreteStates until it needs no more); the next time event,
    which must be t + dt."""
    for _ in range(10):
        needed, terminate, _, _, defined, next_time = model.newDiscreteStates()
        if not needed:
            break
    if terminate or not defined or abs(next_time - (t + dt)) > 1e-6 * dt:
        raise ExportError(f"the FMU's model exchange asks for its next time event at {next_time if defined else None}"
                          f" s, not t + dt = {t + dt} s" + (" (it terminated)" if terminate else ""))
    return next_time


def time_c_step(step_c: str, state0, u_rows) -> float:
    """Seconds per step of the bare C step, compiled -O2: the rows ``u_rows`` (S, m + q) in turn from the
    state ``state0`` (r,), repeated, the steps doubled until a run takes 0.2 s or 10⁶ steps."""
    r, m, _ = step_sizes(step_c)
    state0, u_rows = np.ascontiguousarray(state0, dtype=np.float64), np.ascontiguousarray(u_rows, dtype=np.float64)
    if state0.shape != (r,) or u_rows.ndim != 2 or u_rows.shape[1] != m or len(u_rows) == 0:
        raise ExportError(f"time_c_step: the step takes a state of {r} and rows of {m} inputs, not "
                          f"{state0.shape} and {u_rows.shape}")
    cc = c_compiler()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "step.c").write_text(step_c, encoding="utf-8")
        shutil.copy(C_SOURCES / "bench.c", folder / "bench.c")
        data = folder / "data.bin"
        data.write_bytes(np.int64(len(u_rows)).tobytes() + state0.tobytes() + u_rows.tobytes())
        program = folder / ("bench.exe" if platform.system() == "Windows" else "bench")
        _compile([cc, "-O2", "-std=c99", "-o", str(program), "bench.c", "-lm"], folder, "build the step's benchmark")
        result = subprocess.run([str(program), str(data)], capture_output=True, text=True, timeout=600, check=False)
    if result.returncode != 0:
        raise ExportError(f"the C step's benchmark failed: {first_error(result)}")
    return float(result.stdout.split()[0]) * 1e-9
