"""The FMI 3.0 test FMU single_track_fmi3 (tests/fmu_fixtures.py, tests/fmus/single_track_fmi3.c) is what it
claims: valid FMI 3.0 (fmpy's schema and its validate_fmu), the single_track model of the FMI 2.0 fixture to
1e-8 of each output's σ in fmpy's model exchange and co-simulation, exact directional derivatives, an FMU state
that round-trips, every fmi3Functions.h function exported (fmpy binds them all) and nothing else, and fmi3Error
with a logged message for a call in the wrong state or a feature it does not offer.

fmpy's FMI 3.0 importer (0.3.x), which these checks follow: it sets the start values in the instantiated state,
calls fmi3EnterInitializationMode(tolerance, startTime, stopTime), sets the inputs, fmi3ExitInitializationMode;
model exchange then loops fmi3UpdateDiscreteStates, fmi3EnterContinuousTimeMode, and CVode drives fmi3SetTime,
fmi3SetContinuousStates, fmi3GetContinuousStateDerivatives (each input step: fmi3EnterEventMode, the input,
fmi3UpdateDiscreteStates, fmi3EnterContinuousTimeMode); co-simulation (no event mode) sets the inputs and calls
fmi3DoStep(t, h, noSetFMUStatePriorToCurrentPoint, &eventHandlingNeeded, &terminateSimulation, &earlyReturn,
&lastSuccessfulTime) per step. So both interfaces see the inputs as the FMI 2.0 FMU does.
"""

from __future__ import annotations

import ctypes
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmu_fixtures import build_fmu, start_values, value_references

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi3 import FMU3Model, FMU3ScheduledExecution, FMU3Slave, fmi3Error  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="the test FMUs are compiled with gcc")

KIND = "single_track_fmi3"
DT, STOP = 0.01, 3.0
OUTPUTS = ("yaw_rate", "side_slip", "lateral_acceleration")
KNOWNS = ("yaw_rate", "side_slip", "steering_wheel_angle", "rear_wheel_angle")
UNKNOWNS = ("der(yaw_rate)", "der(side_slip)", *OUTPUTS)
REFS = value_references(KIND)
X0 = {"yaw_rate": 0.12, "side_slip": -0.008}  # the start state (initial exact: set before the initialization)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fmus")
    build_fmu(KIND, folder)
    build_fmu("single_track", folder)
    return folder


class Log:
    """The FMU's log messages (fmi3LogMessageCallback), kept."""

    def __init__(self) -> None:
        self.messages: list[tuple[int, str, str]] = []

    def __call__(self, environment, status, category, message) -> None:
        self.messages.append((status, category.decode(), message.decode()))


def instance(path: Path, cls, folder: Path, log: Log, **options):
    """An instance of the FMU (FMU3Model, FMU3Slave or FMU3ScheduledExecution), instantiated."""
    description = read_model_description(str(path))
    interface = {FMU3Model: description.modelExchange, FMU3Slave: description.coSimulation}.get(cls)
    model = cls(guid=description.guid, unzipDirectory=extract(str(path), unzipdir=str(folder)),
                modelIdentifier=interface.modelIdentifier if interface else KIND, instanceName="test")
    model.instantiate(logMessage=log, **options)
    return model


def refused(log: Log, call, *args, match: str) -> None:
    """call(*args) returns fmi3Error (fmpy raises) and the FMU logs an error that says ``match``."""
    before = len(log.messages)
    with pytest.raises(FMICallException) as caught:
        call(*args)
    assert caught.value.status == fmi3Error
    assert [(s, c) for s, c, _ in log.messages[before:]] == [(fmi3Error, "logStatusError")]
    assert re.search(match, log.messages[-1][2]), log.messages[-1][2]


def staircase() -> np.ndarray:
    """Steering wheel and rear wheel staircases held over each interval (fmpy: every step an input event)."""
    t = np.arange(round(STOP / DT) + 1) * DT
    swa = 0.4 * np.sign(np.sin(2 * np.pi * 0.7 * t + 0.3)) * (1 + 0.5 * np.floor(t / 0.9))
    rwa = 0.01 * (t >= 1.3)
    times = np.repeat(t, 2)[1:]
    return np.array(list(zip(times, np.repeat(swa, 2)[:-1], np.repeat(rwa, 2)[:-1])),
                    dtype=[("time", float), ("steering_wheel_angle", float), ("rear_wheel_angle", float)])


def simulated(path: Path, interface: str, **options) -> np.ndarray:
    result = simulate_fmu(str(path), fmi_type=interface, stop_time=STOP, output_interval=DT, input=staircase(),
                          output=list(OUTPUTS), **options)
    assert np.allclose(result["time"], np.arange(round(STOP / DT) + 1) * DT)
    return np.stack([result[name] for name in OUTPUTS], -1)


def test_it_is_valid_fmi3_with_the_fmi2_fixture_s_variables(fmus) -> None:
    path = fmus / f"{KIND}.fmu"
    description = read_model_description(str(path), validate=True)
    assert validate_fmu(str(path)) == []
    assert description.fmiVersion == "3.0" and description.guid.startswith("{")
    assert {v.name: v.valueReference for v in description.modelVariables} == REFS
    assert value_references("single_track") | {"time": 16} == REFS
    variables = {v.name: v for v in description.modelVariables}
    assert {v.type for n, v in variables.items() if n != "n_sub"} == {"Float64"}
    assert (variables["n_sub"].type, variables["n_sub"].variability, variables["n_sub"].start) == \
        ("Int32", "fixed", "10")
    assert variables["time"].causality == "independent"
    two = {v.name: v for v in read_model_description(str(fmus / "single_track.fmu")).modelVariables}
    for name, v in two.items():
        three = variables[name]
        assert (three.causality, three.variability, three.initial, three.unit, three.start, three.nominal) == \
            (v.causality, v.variability, v.initial, v.unit, v.start, v.nominal), name
    assert [(d.variable.name, d.variable.derivative.name) for d in description.derivatives] == [
        ("der(yaw_rate)", "yaw_rate"), ("der(side_slip)", "side_slip")]
    assert description.numberOfContinuousStates == 2 and description.numberOfEventIndicators == 0
    assert [u.variable.name for u in description.outputs] == list(OUTPUTS)
    assert [d.name for d in description.outputs[2].dependencies] == list(KNOWNS)
    assert {u.variable.name for u in description.initialUnknowns} == {"der(yaw_rate)", "der(side_slip)",
                                                                        "lateral_acceleration"}
    me, cs = description.modelExchange, description.coSimulation
    assert me.modelIdentifier == cs.modelIdentifier == KIND and description.scheduledExecution is None
    assert me.canGetAndSetFMUstate and cs.canGetAndSetFMUstate and not cs.canSerializeFMUstate
    assert cs.canHandleVariableCommunicationStepSize and not cs.hasEventMode
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
        xml = archive.read("modelDescription.xml").decode()
    # fmpy keeps FMI 3.0's providesDirectionalDerivatives in no attribute of its own: read it from the XML
    assert xml.count('providesDirectionalDerivatives="true"') == 2
    assert {f"binaries/x86_64-linux/{KIND}.so", f"sources/{KIND}.c", "sources/model.h", "sources/fmi3Functions.h",
            "sources/buildDescription.xml"} <= names
    assert description.buildConfigurations[0].sourceFileSets[0].sourceFiles == [f"{KIND}.c"]


def test_it_exports_every_fmi3_function_and_nothing_else(fmus, tmp_path) -> None:
    """Every function fmi3Functions.h declares (the ones fmpy binds on loading), and the helpers static."""
    folder = Path(extract(str(fmus / f"{KIND}.fmu"), unzipdir=str(tmp_path / "x")))
    header = (folder / "sources" / "fmi3Functions.h").read_text()
    declared = re.findall(r"^FMI3_Export\s+\w+TYPE\s+(fmi3\w+);", header, re.MULTILINE)
    assert len(declared) == 75
    library = ctypes.CDLL(str(folder / "binaries" / "x86_64-linux" / f"{KIND}.so"))
    assert [name for name in declared if not hasattr(library, name)] == []
    assert not any(hasattr(library, name) for name in ("evaluate", "rk4", "restart", "fail", "allowed", "create"))
    library.fmi3GetVersion.restype = ctypes.c_char_p
    assert library.fmi3GetVersion() == b"3.0"


@pytest.mark.parametrize("interface", ["ModelExchange", "CoSimulation"])
def test_fmpy_simulates_it_as_the_fmi2_fixture(fmus, interface) -> None:
    """The same staircase inputs from the same start state: the FMI 2.0 fixture's outputs to 1e-8 of each one's
    σ (model exchange: CVode on both, rtol 1e-10; co-simulation: the default n_sub, and n_sub = 3 with cf 10 %
    off as start values: fmi3SetInt32 and a tunable parameter through fmpy)."""
    settings = [{"start_values": X0}]
    if interface == "ModelExchange":
        settings = [{"start_values": X0, "relative_tolerance": 1e-10, "record_events": False}]
    else:
        settings.append({"start_values": X0 | {"n_sub": 3, "cf": 0.9 * start_values(KIND)["cf"]}})
    responses = []
    for options in settings:
        three = simulated(fmus / f"{KIND}.fmu", interface, **options)
        two = simulated(fmus / "single_track.fmu", interface, **options)
        assert three[0, :2].tolist() == [X0["yaw_rate"], X0["side_slip"]]
        assert (np.abs(three - two).max(0) <= 1e-8 * two.std(0)).all(), np.abs(three - two).max(0) / two.std(0)
        assert (two.std(0) > 0).all()
        responses.append(three)
    if interface == "CoSimulation":
        assert np.abs(responses[1] - responses[0]).max() > 1e-3  # the start values were the FMU's


def test_directional_derivatives_equal_finite_differences(fmus, tmp_path) -> None:
    """FMU3Model in continuous-time mode at a state and inputs off zero: fmi3GetDirectionalDerivative (unknowns:
    the derivatives and outputs; knowns: the states and inputs) equals central differences of
    fmi3GetContinuousStateDerivatives and the outputs to 1e-6 relative; the model exchange calls around it."""
    log = Log()
    model = instance(fmus / f"{KIND}.fmu", FMU3Model, tmp_path / "me", log)
    assert model.getNumberOfContinuousStates() == 2 and model.getNumberOfEventIndicators() == 0
    model.enterInitializationMode(startTime=0.0)
    model.exitInitializationMode()
    assert model.updateDiscreteStates() == (False, False, False, False, False, 0.0)
    model.enterContinuousTimeMode()
    nominals = (ctypes.c_double * 2)()
    model.getNominalsOfContinuousStates(nominals, 2)
    assert list(nominals) == [0.1, 0.01]
    point = {"yaw_rate": 0.2, "side_slip": -0.01, "steering_wheel_angle": 0.4, "rear_wheel_angle": 0.02}
    unknowns = [REFS[n] for n in UNKNOWNS]

    def unknowns_at(values: dict) -> np.ndarray:
        model.setContinuousStates((ctypes.c_double * 2)(values["yaw_rate"], values["side_slip"]), 2)
        model.setFloat64([REFS["steering_wheel_angle"], REFS["rear_wheel_angle"]],
                         [values["steering_wheel_angle"], values["rear_wheel_angle"]])
        dx = (ctypes.c_double * 2)()
        model.getContinuousStateDerivatives(dx, 2)
        return np.array([*dx, *model.getFloat64([REFS[n] for n in OUTPUTS])])

    differences, directional = [], []
    for name in KNOWNS:
        eps = 1e-6 * max(abs(point[name]), 1e-2)
        up, down = unknowns_at(point | {name: point[name] + eps}), unknowns_at(point | {name: point[name] - eps})
        differences.append((up - down) / (2 * eps))
        unknowns_at(point)
        directional.append(model.getDirectionalDerivative(unknowns, [REFS[name]], [1.0]))
    jacobian = np.array(directional).T
    scale = np.abs(jacobian).max(1, keepdims=True)
    assert np.all(np.abs(jacobian - np.array(differences).T) <= 1e-6 * scale)
    assert np.array_equal(jacobian[2:4], [[1, 0, 0, 0], [0, 1, 0, 0]])  # the states as outputs
    combined = model.getDirectionalDerivative(unknowns, [REFS[n] for n in KNOWNS], [1.0, 2.0, -1.0, 0.5])
    assert np.allclose(combined, jacobian @ [1.0, 2.0, -1.0, 0.5], rtol=1e-12, atol=0)
    assert model.completedIntegratorStep() == (False, False)
    model.setTime(0.5)
    assert model.getFloat64([REFS["time"]]) == [0.5]
    model.terminate()
    model.freeInstance()
    assert log.messages == []


def test_co_simulation_steps_and_its_fmu_state_round_trips(fmus, tmp_path) -> None:
    """fmi3DoStep's outputs (no event, no termination, no early return, the step's end), fmi3Get/SetFMUState
    and fmi3FreeFMUState: the same steps again from a saved state give the same outputs; fmi3Reset restarts."""
    log = Log()
    slave = instance(fmus / f"{KIND}.fmu", FMU3Slave, tmp_path / "cs", log)
    slave.enterInitializationMode(startTime=0.0)
    slave.setFloat64([REFS["yaw_rate"], REFS["side_slip"]], [X0["yaw_rate"], X0["side_slip"]])
    slave.setInt32([REFS["n_sub"]], [4])
    slave.exitInitializationMode()
    assert slave.getInt32([REFS["n_sub"]]) == [4]
    for k in range(50):
        assert slave.doStep(k * DT, DT) == (False, False, False, pytest.approx((k + 1) * DT))
    saved = slave.getFMUState()
    reached = slave.getFloat64([REFS[n] for n in OUTPUTS])
    slave.setFloat64([REFS["steering_wheel_angle"]], [0.3])

    def steps() -> np.ndarray:
        ys = []
        for k in range(50, 70):
            slave.doStep(k * DT, DT)
            ys.append(slave.getFloat64([REFS[n] for n in OUTPUTS]))
        return np.array(ys)

    first = steps()
    slave.setFMUState(saved)
    assert slave.getFloat64([REFS[n] for n in OUTPUTS]) == reached
    assert slave.getFloat64([REFS["time"], REFS["steering_wheel_angle"]]) == [pytest.approx(0.5), 0.0]
    slave.setFloat64([REFS["steering_wheel_angle"]], [0.3])
    assert np.array_equal(steps(), first)
    slave.freeFMUState(saved)
    slave.terminate()
    slave.reset()
    assert slave.getFloat64([REFS["yaw_rate"]]) == [0.0] and slave.getInt32([REFS["n_sub"]]) == [10]
    slave.freeInstance()
    assert log.messages == []


def test_wrong_states_and_what_it_does_not_offer_are_fmi3_errors(fmus, tmp_path) -> None:
    """A call in the wrong state, a variable it has not, a feature it does not offer: fmi3Error and one logged
    error; scheduled execution, event mode in co-simulation and a wrong token: no instance."""
    path = fmus / f"{KIND}.fmu"
    log = Log()
    model = instance(path, FMU3Model, tmp_path / "me", log)
    refused(log, model.enterContinuousTimeMode, match="not allowed")
    refused(log, model.getDirectionalDerivative, [REFS["der(yaw_rate)"]], [REFS["yaw_rate"]], [1.0],
            match="not allowed")
    model.enterInitializationMode()
    refused(log, model.fmi3DoStep, model.component, 0.0, DT, True, None, None, None, None, match="not allowed")
    refused(log, model.setContinuousStates, (ctypes.c_double * 2)(0.1, 0.0), 2, match="not allowed")
    model.exitInitializationMode()
    model.enterContinuousTimeMode()
    refused(log, model.setFloat64, [REFS["yaw_rate"]], [0.1], match="states are set before")
    refused(log, model.setFloat64, [REFS["cf"]], [1.0], match="tunable parameter")
    refused(log, model.setFloat64, [REFS["time"]], [1.0], match="independent")
    refused(log, model.setInt32, [REFS["n_sub"]], [3], match="not allowed")
    refused(log, model.getFloat64, [99], match="no Float64 variable")
    refused(log, model.getBoolean, [0], match="no fmi3Boolean variable")
    refused(log, model.getDirectionalDerivative, [REFS["m"]], [REFS["yaw_rate"]], [1.0], match="unknowns")
    refused(log, model.getAdjointDerivative, [REFS["der(yaw_rate)"]], [REFS["yaw_rate"]], [1.0],
            match="directional derivatives only")
    state = model.getFMUState()
    refused(log, model.serializeFMUState, state, match="not serializable")
    model.freeFMUState(state)
    refused(log, model.enterConfigurationMode, match="structural parameters")
    refused(log, model.fmi3EvaluateDiscreteStates, model.component, match="discrete states")
    assert model.getBoolean([]) == []  # no variables asked for: fine
    model.enterEventMode()
    refused(log, model.enterEventMode, match="not allowed")
    model.terminate()
    refused(log, model.terminate, match="not allowed")
    model.freeInstance()

    slave = instance(path, FMU3Slave, tmp_path / "cs", log)
    refused(log, slave.doStep, 0.0, DT, match="not allowed")
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    refused(log, slave.enterEventMode, match="no event mode")
    refused(log, slave.enterStepMode, match="no event mode")
    refused(log, slave.getOutputDerivatives, [REFS["yaw_rate"]], [1], match="no output derivatives")
    refused(log, slave.fmi3GetContinuousStates, slave.component, (ctypes.c_double * 2)(), 2,
            match="model exchange function")
    refused(log, slave.doStep, 0.0, -DT, match="step size")
    slave.freeInstance()

    for cls, options, match in [(FMU3ScheduledExecution, {}, "model exchange and co-simulation only"),
                                (FMU3Slave, {"eventModeUsed": True}, "no event mode")]:
        before = len(log.messages)
        with pytest.raises(Exception, match="Failed to instantiate"):
            instance(path, cls, tmp_path / cls.__name__, log, **options)
        assert len(log.messages) == before + 1 and match in log.messages[-1][2]
    description = read_model_description(str(path))
    wrong = FMU3Model(guid="{not-this-one}", unzipDirectory=extract(str(path), unzipdir=str(tmp_path / "token")),
                      modelIdentifier=description.modelExchange.modelIdentifier)
    with pytest.raises(Exception, match="Failed to instantiate"):
        wrong.instantiate(logMessage=log)
    assert "instantiation token" in log.messages[-1][2]
