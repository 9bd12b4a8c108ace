"""The FMI 2.0 test FMU single_track_events (tests/fmu_fixtures.py, tests/fmus/single_track_events.c) is what it
claims: valid model exchange (fmpy's schema and its validate_fmu) with one event indicator and
completedIntegratorStepNotNeeded false, every fmi2Functions.h function exported, single_track's outputs to 1e-8
of each one's σ while the indicator z = yaw_rate - yaw_limit never crosses, a state event where it does, a
completed_steps output that counts the fmi2CompletedIntegratorStep calls (fmi2Reset: 0 again), and
request_event_at that makes fmi2CompletedIntegratorStep ask for event mode.

fmpy 0.3.x as these checks found it:

* With event indicators fmpy's CVode root function calls ``input.apply(t)`` (the value left of a step at a
  step's time), and after an input event CVodeReInit evaluates it first at the event time: the first internal
  step after each step of a staircase input runs on the input from before the step. single_track (no event
  indicators, so no root function) does not see that, and at fmpy's default rtol 1e-5 the two differ by ~2e-4
  σ (0 with the root function's input.apply taken out): the comparison runs CVode at rtol 1e-10 (~1e-9 σ) and
  fmpy's forward Euler (no root function: bit for bit).
* simulate_fmu calls fmi2CompletedIntegratorStep once per solver.step (each output point, input event and
  root), not per CVode internal step; with record_events it samples an event's time twice (before and after).
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
from fmpy.fmi2 import FMU2Model, FMU2Slave, fmi2Error  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="the test FMUs are compiled with gcc")

KIND = "single_track_events"
DT, STOP = 0.01, 3.0
GRID = np.arange(round(STOP / DT) + 1) * DT
OUTPUTS = ("yaw_rate", "side_slip", "lateral_acceleration")
REFS = value_references(KIND)
X0 = {"yaw_rate": 0.05, "side_slip": -0.004}  # a start state off zero (initial exact)
LIMIT = 0.1  # [rad/s]: the staircase's yaw rate crosses it twice (up near 0.58 s, down near 1.55 s)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fmus")
    build_fmu(KIND, folder)
    build_fmu("single_track", folder)
    return folder


def staircase() -> np.ndarray:
    """Steering wheel angle steps on the output grid (fmpy: an input event at each), the rear wheels straight."""
    times = np.array([0.0, 0.5, 0.5, 1.5, 1.5, 2.5, 2.5, STOP])
    swa = np.array([0.0, 0.0, 0.6, 0.6, -0.3, -0.3, 0.2, 0.2])
    return np.array(list(zip(times, swa, 0.0 * swa)),
                    dtype=[("time", float), ("steering_wheel_angle", float), ("rear_wheel_angle", float)])


def simulated(path: Path, outputs=OUTPUTS, **options) -> np.ndarray:
    return simulate_fmu(str(path), fmi_type="ModelExchange", stop_time=STOP, output_interval=DT, input=staircase(),
                        output=list(outputs), **options)


def on_grid(result: np.ndarray) -> np.ndarray:
    """The rows at the output points (of two at an input event, the later one: after the event)."""
    keep = np.isclose(result["time"][:, None], GRID, rtol=0, atol=1e-9)
    rows = [np.flatnonzero(keep[:, k])[-1] for k in range(len(GRID))]
    return result[rows]


class Log:
    """The FMU's log messages as fmpy's default logger prints them ("[ERROR] message"), read from capsys. (A
    logger of one's own would need fmpy.logging.addLoggerProxy to see the formatted message, and that proxy
    keeps one logger for the whole process, fmpy's default instances included: the tests leave it alone.)"""

    def __init__(self, capsys) -> None:
        self.capsys = capsys
        self.messages: list[str] = []

    def read(self) -> list[str]:
        self.messages += [line for line in self.capsys.readouterr().out.splitlines() if line]
        return self.messages


def instance(path: Path, cls, folder: Path):
    description = read_model_description(str(path))
    model = cls(guid=description.guid, unzipDirectory=extract(str(path), unzipdir=str(folder)),
                modelIdentifier=KIND, instanceName="test")
    model.instantiate()  # fmpy's default callbacks: its logger prints
    return model


def refused(log: Log, call, *args, match: str) -> None:
    """call(*args) returns fmi2Error (fmpy raises) and the FMU logs one error that says ``match``."""
    before = len(log.read())
    with pytest.raises(FMICallException, match="status 3"):
        call(*args)
    new = log.read()[before:]
    assert len(new) == 1 and new[0].startswith("[ERROR] ") and re.search(match, new[0]), new


def test_it_is_valid_model_exchange_with_one_event_indicator(fmus, tmp_path) -> None:
    path = fmus / f"{KIND}.fmu"
    description = read_model_description(str(path), validate=True)
    assert validate_fmu(str(path)) == []
    assert description.fmiVersion == "2.0" and description.numberOfEventIndicators == 1
    assert description.numberOfContinuousStates == 2
    me = description.modelExchange
    assert description.coSimulation is None and me.modelIdentifier == KIND
    assert me.needsCompletedIntegratorStep  # completedIntegratorStepNotNeeded="false"
    assert not me.canGetAndSetFMUstate and not me.providesDirectionalDerivative
    assert value_references("single_track").items() <= REFS.items()
    assert {n: REFS[n] for n in ("yaw_limit", "request_event_at", "completed_steps")} == {
        "yaw_limit": 16, "request_event_at": 17, "completed_steps": 18}
    assert {n: start_values(KIND)[n] for n in ("yaw_limit", "request_event_at")} == {
        "yaw_limit": 1.0, "request_event_at": -1.0}
    variables = {v.name: v for v in description.modelVariables}
    for name, unit in (("yaw_limit", "rad/s"), ("request_event_at", "s")):
        assert (variables[name].causality, variables[name].variability, variables[name].unit) == \
            ("parameter", "tunable", unit)
    steps = variables["completed_steps"]
    assert (steps.type, steps.causality, steps.variability, steps.initial, steps.unit, steps.start) == \
        ("Real", "output", "continuous", "calculated", "1", None)
    assert [u.variable.name for u in description.outputs] == [*OUTPUTS, "completed_steps"]
    assert description.outputs[3].dependencies == []
    assert "completed_steps" in {u.variable.name for u in description.initialUnknowns}

    folder = Path(extract(str(path), unzipdir=str(tmp_path / "x")))
    header = (folder / "sources" / "fmi2Functions.h").read_text()
    declared = re.findall(r"^\s*FMI2_Export\s+\w+TYPE\s+(fmi2\w+);", header, re.MULTILINE)
    assert len(declared) == 44
    library = ctypes.CDLL(str(folder / "binaries" / "linux64" / f"{KIND}.so"))
    assert [name for name in declared if not hasattr(library, name)] == []
    assert not any(hasattr(library, name) for name in ("evaluate", "restart", "fail", "allowed", "is_real"))
    with zipfile.ZipFile(path) as archive:
        assert {f"binaries/linux64/{KIND}.so", f"sources/{KIND}.c", "sources/model.h"} <= set(archive.namelist())


def test_fmpy_simulates_it_as_single_track_while_the_limit_is_out_of_reach(fmus) -> None:
    """The staircase from X0, yaw_limit at its start value 1.0: single_track's outputs to 1e-8 σ (CVode at rtol
    1e-10; forward Euler bit for bit); completed_steps counts fmpy's one call a communication step."""
    for options in ({"relative_tolerance": 1e-10}, {"solver": "Euler", "step_size": DT / 4}):
        options |= {"start_values": X0, "record_events": False}
        events = simulated(fmus / f"{KIND}.fmu", (*OUTPUTS, "completed_steps"), **options)
        two = simulated(fmus / "single_track.fmu", **options)
        assert np.array_equal(events["time"], GRID) and np.array_equal(two["time"], GRID)
        assert [events[n][0] for n in ("yaw_rate", "side_slip")] == [X0["yaw_rate"], X0["side_slip"]]
        for name in OUTPUTS:
            sigma = np.std(two[name])
            assert sigma > 0 and np.abs(events[name] - two[name]).max() <= 1e-8 * sigma, name
        if options.get("solver") == "Euler":
            assert all(np.array_equal(events[n], two[n]) for n in OUTPUTS)
        assert np.array_equal(events["completed_steps"], np.arange(len(GRID)))
        assert np.abs(two["yaw_rate"]).max() < start_values(KIND)["yaw_limit"]


def test_a_low_yaw_limit_makes_state_events_where_the_yaw_rate_crosses_it(fmus) -> None:
    """yaw_limit = 0.1: fmpy's CVode finds both crossings of z = yaw_rate - yaw_limit (recorded off the grid, at
    yaw_rate = 0.1, where the grid run crosses it), and nothing else changes; single_track records none."""
    options = {"start_values": X0, "relative_tolerance": 1e-10}
    reference = simulated(fmus / f"{KIND}.fmu", record_events=False, **options)
    z = reference["yaw_rate"] - LIMIT
    k = np.flatnonzero(np.sign(z[1:]) != np.sign(z[:-1]))
    crossings = GRID[k] - z[k] * DT / (z[k + 1] - z[k])
    assert len(crossings) == 2

    limited = simulated(fmus / f"{KIND}.fmu", (*OUTPUTS, "completed_steps"),
                        start_values=options["start_values"] | {"yaw_limit": LIMIT},
                        relative_tolerance=1e-10)
    off_grid = ~np.isclose(limited["time"][:, None], GRID, rtol=0, atol=1e-9).any(1)
    events = limited[off_grid]
    assert len(events) == 4  # each event time twice (record_events: before and after)
    times = np.unique(events["time"])
    assert np.abs(times - crossings).max() < 1e-3, (times, crossings)
    assert np.abs(events["yaw_rate"] - LIMIT).max() < 1e-9
    assert np.all(np.diff(limited["completed_steps"]) >= 0)
    grid = on_grid(limited)
    for name in OUTPUTS:
        assert np.abs(grid[name] - reference[name]).max() <= 1e-7 * np.std(reference[name]), name

    plain = simulate_fmu(str(fmus / "single_track.fmu"), stop_time=STOP, output_interval=DT, input=staircase(),
                         output=list(OUTPUTS), start_values=X0, relative_tolerance=1e-10)
    assert np.isclose(plain["time"][:, None], GRID, rtol=0, atol=1e-9).any(1).all()


def test_completed_steps_counts_the_calls_and_request_event_at_asks_for_event_mode(fmus, tmp_path, capsys) -> None:
    """FMU2Model: completed_steps is each fmi2CompletedIntegratorStep call since fmi2Instantiate or fmi2Reset;
    enterEventMode is true from request_event_at on (set in event mode) and false otherwise; the event
    indicator is yaw_rate - yaw_limit; what it does not offer is fmi2Error with a logged message."""
    log = Log(capsys)
    path = fmus / f"{KIND}.fmu"
    model = instance(path, FMU2Model, tmp_path / "me")
    steps = [REFS["completed_steps"]]
    z = (ctypes.c_double * 1)()
    for run in range(2):  # the second after fmi2Reset
        assert model.getReal(steps) == [0.0]
        assert model.getReal([REFS["yaw_limit"], REFS["request_event_at"]]) == [1.0, -1.0]
        model.setupExperiment(startTime=0.0)
        model.enterInitializationMode()
        model.setReal([REFS["yaw_limit"]], [0.15])
        model.exitInitializationMode()
        assert model.newDiscreteStates() == (False, False, False, False, False, 0.0)
        model.enterContinuousTimeMode()
        model.setContinuousStates((ctypes.c_double * 2)(0.2, -0.01), 2)
        model.getEventIndicators(z, 1)
        assert z[0] == pytest.approx(0.2 - 0.15, abs=1e-15)
        for k in range(1, 6):
            model.setTime(k * DT)
            assert model.completedIntegratorStep() == (False, False)
            assert model.getReal(steps) == [float(k)]
        if run == 0:
            model.enterEventMode()
            model.setReal([REFS["request_event_at"]], [0.08])
            model.newDiscreteStates()
            model.enterContinuousTimeMode()
            model.setTime(0.07)
            assert model.completedIntegratorStep() == (False, False)
            for t in (0.08, 0.09):
                model.setTime(t)
                assert model.completedIntegratorStep() == (True, False)
            assert model.getReal(steps) == [8.0]
            model.enterEventMode()  # as the importer does on enterEventMode true
            model.newDiscreteStates()
            model.enterContinuousTimeMode()
            model.setTime(0.1)
            assert model.completedIntegratorStep() == (True, False)
            assert model.getReal(steps) == [9.0]

            refused(log, model.getEventIndicators, (ctypes.c_double * 2)(), 2, match="1 event indicator")
            refused(log, model.setReal, steps, [0.0], match="no input, state or parameter")
            refused(log, model.setReal, [REFS["yaw_limit"]], [0.2], match="tunable parameter")
            refused(log, model.getReal, [REFS["n_sub"]], match="unknown value reference")
            refused(log, model.getDirectionalDerivative, [REFS["der(yaw_rate)"]], [REFS["yaw_rate"]], [1.0],
                    match="providesDirectionalDerivative false")
            refused(log, model.getFMUstate, match="canGetAndSetFMUstate false")
            do_step = model.dll.fmi2DoStep  # FMU2Model binds no co-simulation function: the library's own
            do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
            do_step.restype = ctypes.c_int
            assert do_step(model.component, 0.0, DT, 1) == fmi2Error
            assert log.read()[-1] == "[ERROR] fmi2DoStep: model exchange only"
            model.enterEventMode()
            refused(log, model.completedIntegratorStep, match="not allowed")
            model.terminate()
            model.reset()
    model.terminate()
    model.freeInstance()
    assert len(log.read()) == 8

    with pytest.raises(Exception, match="Failed to instantiate"):
        instance(path, FMU2Slave, tmp_path / "cs")
    assert log.read()[-1] == "[ERROR] fmi2Instantiate: model exchange only"
    assert len(log.messages) == 9


def test_fmpy_handles_the_requested_step_events(fmus) -> None:
    """request_event_at = 1.0 through simulate_fmu: from 1.0 s on every completed step is an event (record_events:
    each of those points twice), before it none; the outputs stay single_track's."""
    result = simulated(fmus / f"{KIND}.fmu", (*OUTPUTS, "completed_steps"), relative_tolerance=1e-10,
                       start_values=X0 | {"request_event_at": 1.0})
    times, counts = np.unique(np.round(result["time"], 9), return_counts=True)
    assert np.allclose(times, GRID, rtol=0, atol=1e-9)
    inputs = np.isclose(times[:, None], [0.5, 1.5, 2.5]).any(1)
    assert np.array_equal(counts, np.where((times >= 1.0 - 1e-9) | inputs, 2, 1))
    assert result["completed_steps"][-1] == len(GRID) - 1
    reference = simulated(fmus / f"{KIND}.fmu", record_events=False, relative_tolerance=1e-10, start_values=X0)
    grid = on_grid(result)
    for name in OUTPUTS:
        assert np.abs(grid[name] - reference[name]).max() <= 1e-7 * np.std(reference[name]), name
