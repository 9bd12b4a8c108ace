"""Test FMUs compiled here from C (tests/fmus/*.c), nothing downloaded: ``build_fmu(kind, folder, **start)``.

Kinds (Linux x86-64 binaries built with the machine's gcc, in ``binaries/linux64`` for FMI 2.0 and
``binaries/x86_64-linux`` for FMI 3.0; sources and the FMI headers fmpy ships in ``sources/``):

* ``single_track``: model exchange and co-simulation; the linear single-track (bicycle) vehicle model with the
  states ``yaw_rate`` [rad/s] and ``side_slip`` [rad] (each one variable, causality output, initial exact:
  settable before the initialization ends), their derivatives ``der(yaw_rate)``, ``der(side_slip)``, the
  inputs ``steering_wheel_angle``, ``rear_wheel_angle`` [rad], the output ``lateral_acceleration`` [m/s2],
  tunable parameters ``m Iz lf lr cf cr v steering_ratio`` and the fixed Integer ``n_sub`` (RK4 substeps per
  ``fmi2DoStep``). Directional derivatives (knowns: states, inputs; unknowns: derivatives, outputs) and the
  FMU state (get/set/free, no serialization).
* ``cosim_lag``: co-simulation only, y' = (K u - y) / tau integrated exactly over any step; the input ``u``,
  the output ``y`` (initial exact), the fixed parameters ``K`` [1] and ``tau`` [s]. Nothing optional.
* ``single_track_fmi3``: ``single_track`` as an FMI 3.0 FMU (fmiVersion 3.0, instantiationToken = the GUID):
  model exchange and co-simulation (no event mode in co-simulation, no scheduled execution), the same
  variables, value references, units and start values, every one Float64 but ``n_sub`` (Int32), and the
  independent variable ``time`` [s] (value reference 16) that FMI 3.0 requires; the same equations, RK4 per
  ``fmi3DoStep``, directional derivatives and FMU state. Every function of fmi3Functions.h is exported (fmpy
  binds them all); the unsupported ones log an error and return fmi3Error.
* ``single_track_events``: model exchange only; ``single_track``'s model, variables and value references
  (``n_sub`` kept, unused) and three more: the tunable parameters ``yaw_limit`` [rad/s] (start 1.0, out of reach
  in ordinary driving), whose one event indicator is z = yaw_rate - yaw_limit (numberOfEventIndicators 1), and
  ``request_event_at`` [s] (start -1: never), and the output ``completed_steps`` [1] (continuous: it changes
  outside events; initial calculated; depends on no state or input), the fmi2CompletedIntegratorStep calls since
  fmi2Instantiate or fmi2Reset. completedIntegratorStepNotNeeded is false; fmi2CompletedIntegratorStep returns
  enterEventMode true where request_event_at >= 0 and the time >= it. No directional derivatives, no FMU state;
  every fmi2Functions.h function is exported, the unsupported ones (co-simulation too) log an error and return
  fmi2Error. Nothing discrete changes at an event.

``start`` overrides the start values by variable name (parameters, inputs, states: any variable with one),
written into both modelDescription.xml and the generated ``sources/model.h``, so an FMU built with
``cf=0.85 * 80000`` simulates with that value when the importer sets nothing. An FMU already in ``folder``
built from the same C source and variables (start values included) is reused: its GUID (FMI 3.0: its
instantiation token) is a hash of them; another one there is replaced (so a variant wants its own folder).
Without gcc (or on a machine other than Linux x86-64) ``build_fmu`` skips the test with one line.
"""

from __future__ import annotations

import hashlib
import math
import os
import platform
import re
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import pytest

SOURCES = Path(__file__).parent / "fmus"
FLAGS = ("-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror")
HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
HEADERS_FMI3 = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
INTEGER_TYPES = ("Integer", "Int32")  # FMI 2.0, FMI 3.0
STEP_SIZE = 0.01  # DefaultExperiment stepSize [s]

# the units: name -> base-unit exponents (FMI 2.0 BaseUnit)
UNITS = {
    "1": {}, "s": {"s": 1}, "m": {"m": 1}, "kg": {"kg": 1}, "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1}, "rad/s2": {"rad": 1, "s": -2}, "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2}, "kg.m2": {"kg": 1, "m": 2}, "N/rad": {"kg": 1, "m": 1, "s": -2, "rad": -1},
}


def _var(name, vr, causality, variability, unit, start=None, description="", *, initial=None, type_="Real",
         derivative=None, positive=False, nominal=None):
    return {"name": name, "vr": vr, "causality": causality, "variability": variability, "unit": unit,
            "start": start, "description": description, "initial": initial, "type": type_,
            "derivative": derivative, "positive": positive, "nominal": nominal}


def _parameter(name, vr, unit, start, description, *, variability="tunable", positive=False, type_="Real"):
    return _var(name, vr, "parameter", variability, unit, start, description, initial="exact", type_=type_,
                positive=positive)


# The variables of each kind in ModelVariables order (index = position + 1); "vr" is the value reference.
VARIABLES: dict[str, list[dict]] = {
    "single_track": [
        _var("yaw_rate", 0, "output", "continuous", "rad/s", 0.0, "yaw rate r (a state)", initial="exact",
             nominal=0.1),
        _var("side_slip", 1, "output", "continuous", "rad", 0.0, "side slip angle beta (a state)",
             initial="exact", nominal=0.01),
        _var("der(yaw_rate)", 2, "local", "continuous", "rad/s2", description="dr/dt", derivative=1),
        _var("der(side_slip)", 3, "local", "continuous", "rad/s", description="dbeta/dt", derivative=2),
        _var("steering_wheel_angle", 4, "input", "continuous", "rad", 0.0, "steering wheel angle"),
        _var("rear_wheel_angle", 5, "input", "continuous", "rad", 0.0, "rear wheel steering angle"),
        _var("lateral_acceleration", 6, "output", "continuous", "m/s2", description="v (dbeta/dt + r)",
             initial="calculated"),
        _parameter("m", 7, "kg", 1500.0, "vehicle mass", positive=True),
        _parameter("Iz", 8, "kg.m2", 2500.0, "yaw moment of inertia", positive=True),
        _parameter("lf", 9, "m", 1.2, "centre of gravity to front axle"),
        _parameter("lr", 10, "m", 1.5, "centre of gravity to rear axle"),
        _parameter("cf", 11, "N/rad", 80000.0, "front axle cornering stiffness"),
        _parameter("cr", 12, "N/rad", 90000.0, "rear axle cornering stiffness"),
        _parameter("v", 13, "m/s", 20.0, "longitudinal speed", positive=True),
        _parameter("steering_ratio", 14, "1", 15.0, "steering wheel angle per front wheel angle", positive=True),
        _parameter("n_sub", 15, None, 10, "co-simulation: RK4 substeps per fmi2DoStep", variability="fixed",
                   positive=True, type_="Integer"),
    ],
    "cosim_lag": [
        _var("u", 0, "input", "continuous", "1", 0.0, "input"),
        _var("y", 1, "output", "continuous", "1", 0.0, "lag output (its state), settable before the "
             "initialization ends", initial="exact"),
        _parameter("K", 2, "1", 2.0, "gain", variability="fixed"),
        _parameter("tau", 3, "s", 0.5, "time constant", variability="fixed", positive=True),
    ],
}


def _fmi3(variables: list[dict], time_vr: int) -> list[dict]:
    """FMI 2.0 variables as FMI 3.0 ones: Real -> Float64, Integer -> Int32, ``derivative`` the state's value
    reference (FMI 2.0: its index), "fmi2" -> "fmi3" in the descriptions; the independent ``time`` first."""
    converted = [_var("time", time_vr, "independent", "continuous", "s", description="simulation time",
                      type_="Float64")]
    for v in variables:
        v = dict(v, type={"Real": "Float64", "Integer": "Int32"}[v["type"]],
                 description=v["description"].replace("fmi2", "fmi3"))
        if v["derivative"] is not None:
            v["derivative"] = variables[v["derivative"] - 1]["vr"]
        converted.append(v)
    return converted


VARIABLES["single_track_fmi3"] = _fmi3(VARIABLES["single_track"], 16)
VARIABLES["single_track_events"] = [
    *(v if v["name"] != "n_sub" else dict(v, description="unused (model exchange only): single_track's n_sub")
      for v in VARIABLES["single_track"]),
    _parameter("yaw_limit", 16, "rad/s", 1.0, "the event indicator is yaw_rate - yaw_limit"),
    _parameter("request_event_at", 17, "s", -1.0, "fmi2CompletedIntegratorStep asks for an event from this time "
               "on (negative: never)"),
    # the one variable with "dependencies": "" (it depends on no state or input)
    dict(_var("completed_steps", 18, "output", "continuous", "1", description="fmi2CompletedIntegratorStep calls "
              "since fmi2Instantiate or fmi2Reset", initial="calculated"), dependencies=""),
]
KINDS = tuple(VARIABLES)
FMI_VERSION = {"single_track": "2.0", "cosim_lag": "2.0", "single_track_fmi3": "3.0", "single_track_events": "2.0"}
INTERFACES = {"single_track": ("ModelExchange", "CoSimulation"), "cosim_lag": ("CoSimulation",),
              "single_track_fmi3": ("ModelExchange", "CoSimulation"), "single_track_events": ("ModelExchange",)}
# directional derivatives and the FMU state
OPTIONAL = {"single_track": True, "cosim_lag": False, "single_track_fmi3": True, "single_track_events": False}
EVENT_INDICATORS = {"single_track_events": 1}  # FMI 2.0 numberOfEventIndicators; 0 where not given
# FMI 2.0 <ModelExchange> completedIntegratorStepNotNeeded; "true" where not given
COMPLETED_STEP_NOT_NEEDED = {"single_track_events": "false"}


def start_values(kind: str) -> dict[str, float]:
    """The default start values of ``kind``'s variables that have one, by name."""
    return {v["name"]: v["start"] for v in _variables(kind) if v["start"] is not None}


def value_references(kind: str) -> dict[str, int]:
    """The value reference of each of ``kind``'s variables, by name."""
    return {v["name"]: v["vr"] for v in _variables(kind)}


def build_fmu(kind: str, folder: Path, **start: float) -> Path:
    """``<folder>/<kind>.fmu`` built from tests/fmus/<kind>.c with the start values ``start`` (by variable name)
    in place of the defaults; reused where one of the same source and start values is already there."""
    variables = _with_start(kind, start)
    fmi3 = FMI_VERSION[kind] == "3.0"
    binaries = _platform(FMI_VERSION[kind])
    cc = shutil.which("gcc")
    if cc is None:
        pytest.skip("the test FMUs are compiled from C: gcc is not on PATH")
    fmpy = pytest.importorskip("fmpy", reason="the test FMUs take their FMI headers from fmpy")
    source = (SOURCES / f"{kind}.c").read_text(encoding="utf-8")
    key = "\n".join([kind, source, " ".join(FLAGS), repr(variables)])
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "hypa-test-fmu:" + hashlib.sha256(key.encode()).hexdigest()))
    guid += "}"
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{kind}.fmu"
    if _guid(path) == guid:
        return path
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        root = Path(tmp) / "fmu"
        sources = root / "sources"
        sources.mkdir(parents=True)
        for header in HEADERS_FMI3 if fmi3 else HEADERS:
            shutil.copy(Path(fmpy.__file__).parent / "c-code" / header, sources / header)
        (sources / f"{kind}.c").write_text(source, encoding="utf-8")
        (sources / "model.h").write_text(_model_h(kind, guid, variables), encoding="utf-8")
        describe = _model_description_fmi3 if fmi3 else _model_description
        (root / "modelDescription.xml").write_bytes(describe(kind, guid, variables))
        if fmi3:
            (sources / "buildDescription.xml").write_bytes(_build_description(kind))
        library = root / "binaries" / binaries / f"{kind}.so"
        library.parent.mkdir(parents=True)
        command = [cc, *FLAGS, "-o", str(library), f"{kind}.c", "-lm"]
        result = subprocess.run(command, cwd=sources, capture_output=True, text=True, timeout=120, check=False)
        if result.returncode != 0:
            raise RuntimeError(f"gcc could not build the test FMU {kind}:\n{result.stderr}{result.stdout}")
        partial = Path(tmp) / f"{kind}.fmu"
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
            for file in sorted(root.rglob("*"), key=lambda p: (p.name != "modelDescription.xml", p)):
                if file.is_file():
                    archive.write(file, file.relative_to(root).as_posix())
        os.replace(partial, path)
    return path


def _variables(kind: str) -> list[dict]:
    if kind not in VARIABLES:
        raise ValueError(f"no test FMU {kind!r}: the kinds are {', '.join(KINDS)}")
    return VARIABLES[kind]


def _with_start(kind: str, start: dict) -> list[dict]:
    """``kind``'s variables with the start values ``start`` in place of the defaults (checked)."""
    variables = [dict(v) for v in _variables(kind)]
    by_name = {v["name"]: v for v in variables if v["start"] is not None}
    unknown = sorted(set(start) - set(by_name))
    if unknown:
        raise ValueError(f"{kind}: {unknown} have no start value to override; these do: {', '.join(by_name)}")
    for name, value in start.items():
        variable = by_name[name]
        if variable["type"] in INTEGER_TYPES:
            if value != int(value):
                raise ValueError(f"{kind}: {name} is an {variable['type']}, not {value!r}")
            value = int(value)
        else:
            value = float(value)
        if not math.isfinite(value) or (variable["positive"] and not value > 0):
            raise ValueError(f"{kind}: {name} = {value!r} is not a finite{' positive' * variable['positive']} "
                             "value")
        variable["start"] = value
    return variables


def _platform(version: str = "2.0") -> str:
    """The folder of the binaries (FMI 2.0: linux64, FMI 3.0: x86_64-linux); skips on another machine."""
    if (platform.system(), platform.machine().lower()) not in (("Linux", "x86_64"), ("Linux", "amd64")):
        pytest.skip(f"the test FMUs are built for linux64 only, not {platform.system()} {platform.machine()}")
    return "x86_64-linux" if version == "3.0" else "linux64"


def _guid(path: Path) -> str | None:
    """The GUID (FMI 3.0: the instantiation token) in an FMU's modelDescription.xml; None where there is no
    readable FMU."""
    try:
        with zipfile.ZipFile(path) as archive:
            root = ElementTree.fromstring(archive.read("modelDescription.xml"))
            return root.get("guid") if root.get("fmiVersion") != "3.0" else root.get("instantiationToken")
    except (OSError, KeyError, zipfile.BadZipFile, ElementTree.ParseError):
        return None


def _macro(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_")


def _number(variable: dict) -> str:
    return str(variable["start"]) if variable["type"] in INTEGER_TYPES else repr(float(variable["start"]))


def _model_h(kind: str, guid: str, variables: list[dict]) -> str:
    """sources/model.h: the GUID, VR_<name>, START_<name> and NOMINAL_<name> (as the model description says)."""
    lines = [f"/* {kind}: generated by tests/fmu_fixtures.py. */", f'#define FMU_GUID "{guid}"']
    for v in variables:
        lines.append(f"#define VR_{_macro(v['name'])} {v['vr']}")
        if v["start"] is not None:
            lines.append(f"#define START_{_macro(v['name'])} {_number(v)}")
        if v["nominal"] is not None:
            lines.append(f"#define NOMINAL_{_macro(v['name'])} {v['nominal']!r}")
    return "\n".join(lines) + "\n"


def _model_description(kind: str, guid: str, variables: list[dict]) -> bytes:
    """modelDescription.xml (FMI 2.0)."""
    optional = "true" if OPTIONAL[kind] else "false"
    root = ElementTree.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": kind, "guid": guid, "description": f"hypa test fixture {kind}",
        "generationTool": "tests/fmu_fixtures.py", "variableNamingConvention": "structured",
        "numberOfEventIndicators": str(EVENT_INDICATORS.get(kind, 0))})
    common = {"modelIdentifier": kind, "needsExecutionTool": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
              "canNotUseMemoryManagementFunctions": "false", "canGetAndSetFMUstate": optional,
              "canSerializeFMUstate": "false", "providesDirectionalDerivative": optional}
    own = {"ModelExchange": {"completedIntegratorStepNotNeeded": COMPLETED_STEP_NOT_NEEDED.get(kind, "true")},
           "CoSimulation": {"canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
                            "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false"}}
    for interface in INTERFACES[kind]:
        element = ElementTree.SubElement(root, interface, common | own[interface])
        ElementTree.SubElement(ElementTree.SubElement(element, "SourceFiles"), "File", {"name": f"{kind}.c"})
    definitions = ElementTree.SubElement(root, "UnitDefinitions")
    for unit in sorted({v["unit"] for v in variables if v["unit"] is not None}):
        ElementTree.SubElement(ElementTree.SubElement(definitions, "Unit", {"name": unit}), "BaseUnit",
                               {k: str(e) for k, e in UNITS[unit].items()})
    categories = ElementTree.SubElement(root, "LogCategories")
    ElementTree.SubElement(categories, "Category", {"name": "logStatusError", "description": "errors"})
    ElementTree.SubElement(root, "DefaultExperiment", {"startTime": "0.0", "stepSize": repr(STEP_SIZE)})
    model_variables = ElementTree.SubElement(root, "ModelVariables")
    for v in variables:
        attributes = {"name": v["name"], "valueReference": str(v["vr"]), "description": v["description"],
                      "causality": v["causality"], "variability": v["variability"]}
        if v["initial"] and v["causality"] not in ("parameter", "input"):
            attributes["initial"] = v["initial"]
        typed = {}
        if v["unit"] is not None:
            typed["unit"] = v["unit"]
        if v["nominal"] is not None:
            typed["nominal"] = repr(v["nominal"])
        if v["derivative"] is not None:
            typed["derivative"] = str(v["derivative"])
        if v["start"] is not None:
            typed["start"] = _number(v)
        ElementTree.SubElement(ElementTree.SubElement(model_variables, "ScalarVariable", attributes), v["type"],
                               typed)
    _model_structure(root, variables)
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)


def _model_structure(root: ElementTree.Element, variables: list[dict]) -> None:
    """Outputs and Derivatives with their dependencies on the states and inputs (a variable's own
    "dependencies" where it has them; a state output on itself; the others, being linear in all of them, on every
    state and input); InitialUnknowns: the derivatives and the calculated outputs (dependencies not given: on
    everything)."""
    index = {v["name"]: i + 1 for i, v in enumerate(variables)}
    states = [variables[v["derivative"] - 1]["name"] for v in variables if v["derivative"] is not None]
    inputs = [v["name"] for v in variables if v["causality"] == "input"]
    structure = ElementTree.SubElement(root, "ModelStructure")

    def dependencies(v: dict) -> str:
        if "dependencies" in v:  # given
            return v["dependencies"]
        if v["name"] in states:
            return str(index[v["name"]])
        if not states:  # co-simulation without declared states: the lag has no direct feedthrough
            return ""
        return " ".join(str(index[n]) for n in sorted(states + inputs, key=index.get))

    outputs = [v for v in variables if v["causality"] == "output"]
    element = ElementTree.SubElement(structure, "Outputs")
    for v in outputs:
        ElementTree.SubElement(element, "Unknown", {"index": str(index[v["name"]]), "dependencies": dependencies(v)})
    derivatives = [v for v in variables if v["derivative"] is not None]
    if derivatives:
        element = ElementTree.SubElement(structure, "Derivatives")
        for v in derivatives:
            ElementTree.SubElement(element, "Unknown", {"index": str(index[v["name"]]),
                                                        "dependencies": dependencies(v)})
    initial = [v for v in variables if v["derivative"] is not None
               or (v["causality"] == "output" and v["initial"] in ("calculated", "approx"))]
    if initial:
        element = ElementTree.SubElement(structure, "InitialUnknowns")
        for v in sorted(initial, key=lambda v: index[v["name"]]):
            ElementTree.SubElement(element, "Unknown", {"index": str(index[v["name"]])})


def _model_description_fmi3(kind: str, guid: str, variables: list[dict]) -> bytes:
    """modelDescription.xml (FMI 3.0): the variables as <Float64>/<Int32> elements, ``derivative`` the state's
    value reference, the model structure by value reference."""
    optional = "true" if OPTIONAL[kind] else "false"
    root = ElementTree.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": kind, "instantiationToken": guid,
        "description": f"hypa test fixture {kind}", "generationTool": "tests/fmu_fixtures.py",
        "variableNamingConvention": "structured"})
    common = {"modelIdentifier": kind, "needsExecutionTool": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
              "canGetAndSetFMUState": optional, "canSerializeFMUState": "false",
              "providesDirectionalDerivatives": optional, "providesAdjointDerivatives": "false",
              "providesPerElementDependencies": "false"}
    own = {"ModelExchange": {"needsCompletedIntegratorStep": "false", "providesEvaluateDiscreteStates": "false"},
           "CoSimulation": {"canHandleVariableCommunicationStepSize": "true", "maxOutputDerivativeOrder": "0",
                            "providesIntermediateUpdate": "false", "mightReturnEarlyFromDoStep": "false",
                            "canReturnEarlyAfterIntermediateUpdate": "false", "hasEventMode": "false",
                            "providesEvaluateDiscreteStates": "false"}}
    for interface in INTERFACES[kind]:
        ElementTree.SubElement(root, interface, common | own[interface])
    definitions = ElementTree.SubElement(root, "UnitDefinitions")
    for unit in sorted({v["unit"] for v in variables if v["unit"] is not None}):
        ElementTree.SubElement(ElementTree.SubElement(definitions, "Unit", {"name": unit}), "BaseUnit",
                               {k: str(e) for k, e in UNITS[unit].items()})
    categories = ElementTree.SubElement(root, "LogCategories")
    ElementTree.SubElement(categories, "Category", {"name": "logStatusError", "description": "errors"})
    ElementTree.SubElement(root, "DefaultExperiment", {"startTime": "0.0", "stepSize": repr(STEP_SIZE)})
    model_variables = ElementTree.SubElement(root, "ModelVariables")
    for v in variables:
        attributes = {"name": v["name"], "valueReference": str(v["vr"]), "description": v["description"],
                      "causality": v["causality"], "variability": v["variability"]}
        if v["initial"] and v["causality"] not in ("parameter", "input", "independent"):
            attributes["initial"] = v["initial"]
        if v["unit"] is not None:
            attributes["unit"] = v["unit"]
        if v["nominal"] is not None:
            attributes["nominal"] = repr(v["nominal"])
        if v["derivative"] is not None:
            attributes["derivative"] = str(v["derivative"])
        if v["start"] is not None:
            attributes["start"] = _number(v)
        ElementTree.SubElement(model_variables, v["type"], attributes)
    _model_structure_fmi3(root, variables)
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)


def _model_structure_fmi3(root: ElementTree.Element, variables: list[dict]) -> None:
    """As _model_structure, in FMI 3.0's terms (elements Output, ContinuousStateDerivative, InitialUnknown;
    value references for indices): the outputs and the derivatives with their dependencies on the states and
    inputs, the initial unknowns (the derivatives and the calculated outputs) without."""
    by_vr = {v["vr"]: v for v in variables}
    states = [by_vr[v["derivative"]] for v in variables if v["derivative"] is not None]
    knowns = sorted([v["vr"] for v in states] + [v["vr"] for v in variables if v["causality"] == "input"])
    structure = ElementTree.SubElement(root, "ModelStructure")

    def dependencies(v: dict) -> str:
        return str(v["vr"]) if v in states else " ".join(map(str, knowns))

    for v in variables:
        if v["causality"] == "output":
            ElementTree.SubElement(structure, "Output", {"valueReference": str(v["vr"]),
                                                         "dependencies": dependencies(v)})
    for v in variables:
        if v["derivative"] is not None:
            ElementTree.SubElement(structure, "ContinuousStateDerivative", {"valueReference": str(v["vr"]),
                                                                            "dependencies": dependencies(v)})
    for v in variables:
        if v["derivative"] is not None or (v["causality"] == "output" and v["initial"] in ("calculated", "approx")):
            ElementTree.SubElement(structure, "InitialUnknown", {"valueReference": str(v["vr"])})


def _build_description(kind: str) -> bytes:
    """sources/buildDescription.xml (FMI 3.0): the one C file (C99) and its model identifier."""
    root = ElementTree.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    configuration = ElementTree.SubElement(root, "BuildConfiguration", {"modelIdentifier": kind})
    files = ElementTree.SubElement(configuration, "SourceFileSet", {"language": "C99"})
    ElementTree.SubElement(files, "SourceFile", {"name": f"{kind}.c"})
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)
