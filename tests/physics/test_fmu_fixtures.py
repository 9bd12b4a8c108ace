"""The test FMUs compiled here from C (tests/fmu_fixtures.py, tests/fmus/*.c) are what they claim: valid FMI 2.0,
the single-track model's model exchange (fmpy's CVode) and co-simulation (RK4 inside) equal scipy's solution of
the same equations written here, its directional derivatives equal differences of its derivatives, its FMU
state round-trips, a start override changes the response, and cosim_lag's fmi2DoStep is the exact lag.

fmpy's input semantics, which the references follow: the steering is given as a staircase (each sample held over
its interval, the steps as repeated time points), so model exchange sees input events where CVode restarts and
both interfaces integrate with the input held (zero-order hold) over [t_k, t_k+1). fmpy's co-simulation reads
the outputs after fmi2DoStep and before the next input is set: its lateral_acceleration at t_k is the one at the
state x_k and the input u_k-1 (model exchange reads it after the input of t_k is set).
"""

from __future__ import annotations

import ctypes
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmu_fixtures import build_fmu, start_values, value_references

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi2 import FMU2Model, FMU2Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

DT, STOP = 0.01, 4.0
OUTPUTS = ("yaw_rate", "side_slip", "lateral_acceleration")
DEFAULTS = start_values("single_track")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fmus")
    build_fmu("single_track", folder)
    build_fmu("cosim_lag", folder)
    return folder


def bicycle(x, swa, rwa=0.0, p=DEFAULTS):
    """The single-track model: (dr/dt, dbeta/dt) and the lateral acceleration at x = (r, beta)."""
    r, beta = x
    fyf = p["cf"] * (swa / p["steering_ratio"] - beta - p["lf"] * r / p["v"])
    fyr = p["cr"] * (rwa - beta + p["lr"] * r / p["v"])
    dbeta = (fyf + fyr) / (p["m"] * p["v"]) - r
    dr = (p["lf"] * fyf - p["lr"] * fyr) / p["Iz"]
    return np.array([dr, dbeta]), p["v"] * (dbeta + r)


def steering() -> tuple[np.ndarray, np.ndarray]:
    """The grid and a steering-wheel sine on it [rad] (0.5 Hz, 0.5 rad: about 2 m/s2 of lateral acceleration)."""
    t = np.arange(round(STOP / DT) + 1) * DT
    return t, 0.5 * np.sin(2 * np.pi * 0.5 * t)


def staircase(t, u) -> np.ndarray:
    """fmpy's input signal holding u[k] over [t_k, t_k+1): every step a repeated time point (an input event)."""
    times, values = np.repeat(t, 2)[1:], np.repeat(u, 2)[:-1]
    return np.array(list(zip(times, values)), dtype=[("time", float), ("steering_wheel_angle", float)])


def reference(t, u, p=DEFAULTS, x0=(0.0, 0.0)) -> np.ndarray:
    """The states on the grid from x0, the input held over each interval: solve_ivp (rtol 1e-10) per interval."""
    xs = [np.asarray(x0, float)]
    for k in range(len(t) - 1):
        solution = solve_ivp(lambda _, x, k=k: bicycle(x, u[k], p=p)[0], (t[k], t[k + 1]), xs[-1], method="DOP853",
                             rtol=1e-10, atol=1e-14)
        xs.append(solution.y[:, -1])
    return np.array(xs)


def expected_outputs(x, u, p=DEFAULTS, *, previous_input=False) -> np.ndarray:
    """yaw rate, side slip, lateral acceleration (T, 3) at the states x with u[k] (or u[k-1]: fmpy's CS)."""
    held = np.r_[u[:1], u[:-1]] if previous_input else u
    return np.c_[x, [bicycle(xk, uk, p=p)[1] for xk, uk in zip(x, held)]]


def simulated(path: Path, interface: str, **options) -> np.ndarray:
    t, u = steering()
    result = simulate_fmu(str(path), fmi_type=interface, stop_time=STOP, output_interval=DT, input=staircase(t, u),
                          output=list(OUTPUTS), **options)
    assert np.allclose(result["time"], t)
    return np.stack([result[name] for name in OUTPUTS], -1)


def error(y, expected) -> np.ndarray:
    """The largest deviation of each output, in units of its standard deviation."""
    return np.abs(y - expected).max(0) / expected.std(0)


@pytest.fixture(scope="module")
def truth() -> np.ndarray:
    t, u = steering()
    return reference(t, u)


@pytest.mark.parametrize("kind", ["single_track", "cosim_lag"])
def test_each_fixture_validates_and_says_what_it_offers(fmus, kind) -> None:
    path = fmus / f"{kind}.fmu"
    assert validate_fmu(str(path)) == []
    description = read_model_description(str(path))
    assert {v.name: v.valueReference for v in description.modelVariables} == value_references(kind)
    assert float(description.defaultExperiment.stepSize) == DT
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
    assert {f"binaries/linux64/{kind}.so", f"sources/{kind}.c", "sources/model.h",
            "sources/fmi2Functions.h"} <= names
    cs = description.coSimulation
    assert cs is not None and cs.modelIdentifier == kind and cs.canHandleVariableCommunicationStepSize
    if kind == "cosim_lag":
        assert description.modelExchange is None
        assert not cs.providesDirectionalDerivative and not cs.canGetAndSetFMUstate
        assert [u.variable.name for u in description.outputs] == ["y"] and not description.derivatives
        return
    me = description.modelExchange
    for interface in (me, cs):
        assert interface.providesDirectionalDerivative and interface.canGetAndSetFMUstate
        assert not interface.canSerializeFMUstate
    assert [(d.variable.name, d.variable.derivative.name) for d in description.derivatives] == [
        ("der(yaw_rate)", "yaw_rate"), ("der(side_slip)", "side_slip")]
    assert [u.variable.name for u in description.outputs] == list(OUTPUTS)
    variables = {v.name: v for v in description.modelVariables}
    units = {"m": "kg", "Iz": "kg.m2", "lf": "m", "lr": "m", "cf": "N/rad", "cr": "N/rad", "v": "m/s",
             "steering_ratio": "1", "yaw_rate": "rad/s", "side_slip": "rad", "lateral_acceleration": "m/s2",
             "steering_wheel_angle": "rad", "rear_wheel_angle": "rad"}
    assert {name: variables[name].unit for name in units} == units
    assert all(variables[n].causality == "parameter" and variables[n].variability == "tunable"
               for n in ("m", "Iz", "lf", "lr", "cf", "cr", "v", "steering_ratio"))
    assert (variables["n_sub"].type, variables["n_sub"].variability, variables["n_sub"].start) == \
        ("Integer", "fixed", "10")
    assert variables["yaw_rate"].initial == "exact" and variables["rear_wheel_angle"].start == "0.0"


def test_single_track_model_exchange_matches_solve_ivp(fmus, truth) -> None:
    """fmpy's CVode (rtol 1e-10; the states' nominals make its absolute tolerance) to 1e-6 of each output's σ."""
    y = simulated(fmus / "single_track.fmu", "ModelExchange", relative_tolerance=1e-10, record_events=False)
    _, u = steering()
    assert (error(y, expected_outputs(truth, u)) < 1e-6).all()


def test_single_track_co_simulation_is_rk4(fmus, truth) -> None:
    """With many substeps (n_sub = 200, h = 5e-5 s) it is the solution to 1e-6 of σ; RK4's error falls as h^4
    (1 -> 2 substeps: 16 times less), so the default n_sub = 10 errs at most 10^-4 times one substep's."""
    path = fmus / "single_track.fmu"
    _, u = steering()
    expected = expected_outputs(truth, u, previous_input=True)
    assert (error(simulated(path, "CoSimulation", start_values={"n_sub": 200}), expected) < 1e-6).all()
    one, two, ten = (error(simulated(path, "CoSimulation", start_values={"n_sub": n}), expected)[:2]
                     for n in (1, 2, 10))
    assert ((one / two > 12) & (one / two < 20)).all(), one / two
    assert (ten <= 1.5e-4 * one).all() and (one < 1e-3).all()
    assert (error(simulated(path, "CoSimulation"), expected)[:2] == ten).all()  # n_sub's start value is 10


def instance(path: Path, cls, folder: Path):
    """An instance of the FMU (model exchange: FMU2Model, co-simulation: FMU2Slave), instantiated."""
    description = read_model_description(str(path))
    interface = description.modelExchange if cls is FMU2Model else description.coSimulation
    model = cls(guid=description.guid, unzipDirectory=extract(str(path), unzipdir=str(folder)),
                modelIdentifier=interface.modelIdentifier, instanceName="test")
    model.instantiate()
    return model


def test_directional_derivatives_equal_finite_differences(fmus, tmp_path) -> None:
    """Unknowns: the derivatives and the outputs; knowns: the states and the inputs, at a state and inputs off
    zero. Central differences of fmi2GetDerivatives and the outputs (exact but for rounding: the model is
    linear) to 1e-6 relative; the co-simulation instance gives the same."""
    refs = value_references("single_track")
    unknowns = [refs[n] for n in ("der(yaw_rate)", "der(side_slip)", *OUTPUTS)]
    knowns = ["yaw_rate", "side_slip", "steering_wheel_angle", "rear_wheel_angle"]
    point = {"yaw_rate": 0.2, "side_slip": -0.01, "steering_wheel_angle": 0.4, "rear_wheel_angle": 0.02}
    path = fmus / "single_track.fmu"
    model = instance(path, FMU2Model, tmp_path / "me")
    model.setupExperiment(startTime=0.0)
    model.enterInitializationMode()
    model.exitInitializationMode()
    model.newDiscreteStates()
    model.enterContinuousTimeMode()

    def unknowns_at(values: dict) -> np.ndarray:
        model.setContinuousStates((ctypes.c_double * 2)(values["yaw_rate"], values["side_slip"]), 2)
        model.setReal([refs["steering_wheel_angle"], refs["rear_wheel_angle"]],
                      [values["steering_wheel_angle"], values["rear_wheel_angle"]])
        dx = (ctypes.c_double * 2)()
        model.getDerivatives(dx, 2)
        return np.array([*dx, *model.getReal([refs[n] for n in OUTPUTS])])

    differences, directional = [], []
    for name in knowns:
        eps = 1e-6 * max(abs(point[name]), 1e-2)
        up, down = unknowns_at(point | {name: point[name] + eps}), unknowns_at(point | {name: point[name] - eps})
        differences.append((up - down) / (2 * eps))
        unknowns_at(point)
        directional.append(model.getDirectionalDerivative(unknowns, [refs[name]], [1.0]))
    jacobian = np.array(directional).T
    scale = np.abs(jacobian).max(1, keepdims=True)
    assert np.all(np.abs(jacobian - np.array(differences).T) <= 1e-6 * scale)
    assert np.allclose(jacobian[2:4], [[1, 0, 0, 0], [0, 1, 0, 0]], rtol=0, atol=0)  # the states as outputs
    combined = model.getDirectionalDerivative(unknowns, [refs[n] for n in knowns], [1.0, 2.0, -1.0, 0.5])
    assert np.allclose(combined, jacobian @ [1.0, 2.0, -1.0, 0.5], rtol=1e-12, atol=0)
    model.terminate()
    model.freeInstance()

    slave = instance(path, FMU2Slave, tmp_path / "cs")
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([refs[n] for n in knowns], [point[n] for n in knowns])
    slave.exitInitializationMode()
    again = np.array([slave.getDirectionalDerivative(unknowns, [refs[n]], [1.0]) for n in knowns]).T
    assert np.allclose(again, jacobian, rtol=1e-14, atol=0)
    slave.terminate()
    slave.freeInstance()


def test_co_simulation_starts_from_a_set_state_and_its_fmu_state_round_trips(fmus, tmp_path) -> None:
    """The states set in initialization mode start the vehicle (a decay with the wheel straight, as solve_ivp
    says); fmi2GetFMUstate after some steps, more steps, fmi2SetFMUstate, the same steps again: the same."""
    refs = value_references("single_track")
    x0 = (0.15, -0.01)
    slave = instance(fmus / "single_track.fmu", FMU2Slave, tmp_path / "cs")
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([refs["yaw_rate"], refs["side_slip"]], list(x0))
    slave.exitInitializationMode()
    states = [refs["yaw_rate"], refs["side_slip"]]
    run = [slave.getReal(states)]
    for k in range(100):
        slave.doStep(k * DT, DT)
        run.append(slave.getReal(states))
    t = np.arange(101) * DT
    expected = reference(t, np.zeros_like(t), x0=x0)
    assert np.abs(np.array(run) - expected).max() < 1e-9 * np.abs(x0).max()

    saved = slave.getFMUstate()
    slave.setReal([refs["steering_wheel_angle"]], [0.3])

    def steps(start: int) -> np.ndarray:
        ys = []
        for k in range(start, start + 20):
            slave.doStep(k * DT, DT)
            ys.append(slave.getReal([refs[n] for n in OUTPUTS]))
        return np.array(ys)

    first = steps(100)
    slave.setFMUstate(saved)
    assert slave.getReal(states) == run[-1] and slave.getReal([refs["steering_wheel_angle"]]) == [0.0]
    assert slave.getRealStatus(fmpy.fmi2.fmi2LastSuccessfulTime) == pytest.approx(1.0)
    slave.setReal([refs["steering_wheel_angle"]], [0.3])
    assert np.array_equal(steps(100), first)
    slave.freeFMUstate(saved)
    slave.terminate()
    slave.freeInstance()


def test_a_start_override_is_the_fmus_value_and_changes_the_response(fmus, tmp_path, truth) -> None:
    """cf 15 % off: the model description, model.h and the response (co-simulation, n_sub large) are the
    override's; the same start values again reuse the FMU; bad overrides are refused."""
    cf = 0.85 * DEFAULTS["cf"]
    path = build_fmu("single_track", tmp_path, cf=cf)
    assert validate_fmu(str(path)) == []
    variables = {v.name: v for v in read_model_description(str(path)).modelVariables}
    assert float(variables["cf"].start) == cf and float(variables["cr"].start) == DEFAULTS["cr"]
    with zipfile.ZipFile(path) as archive:
        assert f"#define START_cf {cf!r}" in archive.read("sources/model.h").decode()
    stamp = path.stat().st_mtime_ns
    assert build_fmu("single_track", tmp_path, cf=cf) == path and path.stat().st_mtime_ns == stamp

    t, u = steering()
    off = reference(t, u, p=DEFAULTS | {"cf": cf})
    y = simulated(path, "CoSimulation", start_values={"n_sub": 200})
    assert (error(y, expected_outputs(off, u, DEFAULTS | {"cf": cf}, previous_input=True)) < 1e-6).all()
    change = error(expected_outputs(off, u), expected_outputs(truth, u))
    assert (change > 0.03).all(), change  # the response moves by several per cent of its σ

    for bad in ({"cf": float("nan")}, {"m": 0.0}, {"n_sub": 0}, {"n_sub": 2.5}, {"lateral_acceleration": 1.0},
                {"nope": 1.0}):
        with pytest.raises(ValueError):
            build_fmu("single_track", tmp_path / "bad", **bad)
    with pytest.raises(ValueError, match="no test FMU"):
        build_fmu("pendulum", tmp_path)


def test_cosim_lag_do_step_is_the_exact_lag(fmus, tmp_path) -> None:
    """fmi2DoStep over steps of any size, the input changing between them, from a start y set in initialization
    mode: y(t + h) = K u + (y - K u) exp(-h / tau); fmpy's co-simulation of a sine the same recursion; the FMU
    offers no FMU state."""
    refs = value_references("cosim_lag")
    k_gain, tau = start_values("cosim_lag")["K"], start_values("cosim_lag")["tau"]
    slave = instance(fmus / "cosim_lag.fmu", FMU2Slave, tmp_path / "lag")
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([refs["y"]], [0.3])
    slave.exitInitializationMode()
    y, t = 0.3, 0.0
    for h, u in [(0.01, 1.0), (0.3, 1.0), (1.7, -0.5), (0.0, 2.0), (1e-4, 2.0), (5.0, 0.25)]:
        slave.setReal([refs["u"]], [u])
        slave.doStep(t, h)
        t += h
        y = k_gain * u + (y - k_gain * u) * np.exp(-h / tau)
        assert slave.getReal([refs["y"]])[0] == pytest.approx(y, rel=1e-14, abs=1e-15)
    assert slave.getRealStatus(fmpy.fmi2.fmi2LastSuccessfulTime) == pytest.approx(t)
    with pytest.raises(Exception):  # noqa: B017 -- fmpy raises its FMICallException on fmi2Error
        slave.getFMUstate()
    slave.terminate()
    slave.freeInstance()

    grid = np.arange(201) * DT
    u = np.sin(2 * np.pi * grid)
    signal = np.array(list(zip(grid, u)), dtype=[("time", float), ("u", float)])
    result = simulate_fmu(str(fmus / "cosim_lag.fmu"), stop_time=2.0, output_interval=DT, input=signal,
                          output=["y"])
    expected = [0.0]
    for k in range(200):
        expected.append(k_gain * u[k] + (expected[-1] - k_gain * u[k]) * np.exp(-DT / tau))
    assert np.allclose(result["y"], expected, rtol=0, atol=1e-13)


def test_build_skips_without_gcc(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(pytest.skip.Exception, match=r"gcc|linux64"):
        build_fmu("cosim_lag", tmp_path)
