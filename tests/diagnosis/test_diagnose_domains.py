"""Two domains of the tests' own making, each with a state the model lacks and a parameter that
differs with a direction, hidden at random sizes and seeds: the generic ``missing_mode`` and
``direction_parameter`` entries must name them with their sizes, and neither where there is none.

- **An electrochemical cell with a nonlinear output**: the user's class of ``test_cell_model``
  (a state of charge, capacity in Ah, one RC pair R1 C1 of 30 s, a series resistance R0; terminal
  voltage OCV(SOC) - v1 - R0 I, the OCV a nonlinear output), driven at 1 Hz by ``drive_cycle``'s
  charge and discharge pulses and rests: two hours from 85 % SOC down to about 25 % (the OCV's
  slope rising by half towards its knee) to fit, 40 min from 50 % to judge; the states estimated
  from 100 s of the past (a slow pair's state is not seen in fewer). (1) The truth has a second,
  slower RC pair (τ2 1.5-3 τ1, R2 a third to all of R1), the capacity and R0 declared uncertain (an
  aged cell; the RC pair from a pulse test): ``missing_mode`` on the current, with τ2 and R2.
  (2) The truth's charge-transfer resistance R1 differs in charge and discharge, R1 (1 + d sgn I)
  (C1 the same), R0 and R1 declared uncertain: ``direction_parameter`` on r1 by the current, with d,
  and R1 itself left at its value. A series resistance R0 that differs with the direction (the
  first thought) cannot be named: R0 enters only the output equation, and a dependent parameter
  acts on the state equation alone (``hypa/physics/dependent.py``; the catalogue does not propose
  it); R1 enters the state equation (v1's decay and gain), so the direction is hidden there.
- **A flexible structure**: a payload on a vibration mount (mass m, spring k, damper c: one
  lightly damped mode, 3.2 Hz, 10 % damping), driven by an actuator's force (a multisine of
  0.1-8 Hz), its position and its acceleration measured every 10 ms, k and c declared uncertain.
  (3) ``missing_mode`` adds a *first-order* mode from an input into the outputs; a second lightly
  damped mode (second order) is outside what it expresses, so the missing state is a first-order
  one: the actuator and the position sensor share a frame that sits on a creeping rubber isolator
  (no mass, a spring kf and a damper in parallel, τf 1.5-3 times the mode's decay time); the
  actuator's reaction pushes the frame back by F / kf through that lag, so the sensor on the
  frame reads x + lag(F) / kf and the accelerometer on the payload nothing of it:
  ``missing_mode`` on the force, with τf and 1 / kf on the position and about 0 on the
  acceleration. (4) The damper damps one direction of motion more, c (1 + d sgn v) (a shock
  absorber's rebound and compression): ``direction_parameter`` on c by v, with d, with the
  position alone measured, and with the accelerometer too.

The truths are the tests' own recursions, not hypa's engine: the cell's exact sampled recursion
under a current held over each second (1 mV noise); the structure by fixed-step Runge-Kutta at a
quarter of a sample under a force held over it, the frame's lag exact (0.02 mm and 0.02 m/s²
noise). A negative control per domain: no hidden effect, a nominal parameter 30 % off and a
sensor bias (something besides the value to name, and a drift or a level that a slow mode or a
direction could bend towards): neither ``missing_mode`` nor ``direction_parameter`` is named.

Expected to fail today (``xfail``, not strict, the figures in the reason): the cell's second
seed, whose mode the score test screens out (``CELL_MODE_XFAIL``). (Found by these tests and
fixed: the score test's least squares zeroed the whole step where the time constant's column is 0
at weights 0, so ``missing_mode`` never ran where the nominal's values were right; a scanned
candidate's key carried its start value, which moves with each fold's identified values, so it
never reached the second fold; a dependent parameter kept C and D at its nominal value, so the
accelerometer's part of the direction, -c d |v| / m, was left to a stand-in: d -0.242 -> -0.175
and an acceleration offset of 0.292 m/s² named on seed 0.)
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from hypa.diagnosis.problem import Problem
from hypa.diagnosis.search import name_causes
from hypa.models.spec import parse_model_spec

from data_helpers import importable
from test_cell_model import CELL, TRUE, drive_cycle, ocv
from test_diagnose_time_scales import _datamodule, _files

MOUNT_SYSTEM = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class Mount(LTIModel):
    """A payload m on a mount (spring k, damper c) driven by a force; its position and acceleration measured."""
    state_names = ("x", "v")
    input_names = ("force",)
    output_names = ("position", "acceleration")
    parameters = (ParameterSpec("m", 2.0, "kg"), ParameterSpec("k", 800.0, "N/m"), ParameterSpec("c", 8.0, "N*s/m"))

    def matrices(self, p):
        m, k, c = p["m"], p["k"], p["c"]
        zero, one = torch.zeros_like(m), torch.ones_like(m)
        a = torch.stack([torch.stack([zero, one]), torch.stack([-k / m, -c / m])])
        b = torch.stack([zero, 1 / m]).reshape(2, 1)
        c_out = torch.stack([torch.stack([one, zero]), torch.stack([-k / m, -c / m])])
        return StateSpace(a, b, c_out, torch.stack([zero, 1 / m]).reshape(2, 1))


class MountPosition(Mount):
    """The mount with its position measured alone."""
    output_names = ("position",)

    def matrices(self, p):
        ss = super().matrices(p)
        return StateSpace(ss.a, ss.b, ss.c[:1], ss.d[:1])
'''
MOUNT = {"m": 2.0, "k": 800.0, "c": 8.0}  # [kg], [N/m], [N s/m]: 3.2 Hz, 10 % damping, decay time 2 m / c = 0.5 s
DT = 0.01  # [s] the structure's sample time
CELL_VALUES = {"capacity": TRUE["capacity_ah"] * 3600, "r0": TRUE["r0"], "r1": TRUE["r1"], "c1": TRUE["c1"]}
TAU1 = TRUE["r1"] * TRUE["c1"]  # [s] 30 s


@pytest.fixture
def user_systems(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    yield from importable(tmp_path, monkeypatch, {"cellmodel": CELL, "mount_system": MOUNT_SYSTEM})


def _seeds(n: int = 2) -> list:
    """Seed 0 in the default run, the others slow."""
    return [pytest.param(s, marks=() if s == 0 else pytest.mark.slow) for s in range(n)]


# -- the cell --------------------------------------------------------------------------------------

def cell_current(samples: int, rng: np.random.Generator, soc0: float) -> np.ndarray:
    """``drive_cycle``'s pulses and rests [A], positive discharging; a pulse that would take the SOC
    below 12 % or above 95 % runs the other way."""
    current, soc, q = drive_cycle(samples, rng), soc0, TRUE["capacity_ah"] * 3600
    for k in range(samples):
        if (soc < 0.12 and current[k] > 0) or (soc > 0.95 and current[k] < 0):
            end = k + int(np.argmax(current[k:] != current[k])) if np.any(current[k:] != current[k]) else samples
            current[k:end] = -current[k:end]
        soc -= current[k] / q
    return current


def cell_truth(seed: int, seconds: int, soc0: float, r2: float = 0.0, tau2: float = 60.0, d: float = 0.0,
               bias: float = 0.0) -> dict[str, np.ndarray]:
    """The exact sampled cell under a held current: SOC, v1 (R1 (1 + d sgn I)), v2 (R2, τ2); 1 mV noise;
    ``bias``: the current sensor's [A]."""
    rng = np.random.default_rng(seed)
    current = cell_current(seconds, rng, soc0)
    q, c1 = TRUE["capacity_ah"] * 3600, TRUE["c1"]
    soc, v1, v2 = soc0, 0.0, 0.0
    voltage = np.empty(seconds)
    decay2 = np.exp(-1.0 / tau2)
    for k, i in enumerate(current):
        voltage[k] = ocv(soc) - v1 - v2 - TRUE["r0"] * i
        r1 = TRUE["r1"] * (1 + d * np.sign(i))
        decay1 = np.exp(-1.0 / (r1 * c1))
        soc, v1, v2 = soc - i / q, decay1 * v1 + (1 - decay1) * r1 * i, decay2 * v2 + (1 - decay2) * r2 * i
    return {"time": np.arange(seconds, dtype=float), "current": current + bias,
            "voltage": voltage + 1e-3 * rng.standard_normal(seconds)}


def diagnose_cell(folder: Path, seed: int, uncertain: tuple[str, ...], r0_off: float = 1.0, **truth):
    """Two hours from 85 % SOC to train, 40 min from 50 % to judge, ``uncertain`` the parameters declared
    uncertain; the states estimated from 100 s of the past (three time constants of the RC pair)."""
    split = {"train": cell_truth(seed, 7200, 0.85, **truth), "val": cell_truth(seed + 1, 2400, 0.5, **truth)}
    _files(folder, split)
    dm = _datamodule(folder, 1.0, {"current": {"role": "input", "unit": "A"},
                                   "voltage": {"role": "output", "unit": "V"}}, window=100, past=100)
    values = {**CELL_VALUES, "r0": r0_off * CELL_VALUES["r0"]}
    spec = parse_model_spec({"name": "cell", "hold": "zoh", "blocks": {"cell": {
        "kind": "physics", "system": "cellmodel:Cell", "inputs": ["current"], "outputs": ["voltage"],
        "initial_state": "estimate", "trainable": list(uncertain)}}, "outputs": ["voltage"]})
    return name_causes(spec, Problem(dm, values, hold="zoh", horizon=100, workers=1), max_causes=2)


def _named(search) -> dict:
    return {f.cause: f for f in search.named}


def _tried(search) -> list[str]:
    """The first round's five best, for a failure's message."""
    return [f.describe() for f in (search.rounds[0][:5] if search.rounds else [])]


# Why the cell's second seed is not named (found by these tests): a finite-difference column of the
# mode's weight is not the first-order one: at a small weight the mode's state, estimated from the
# outputs with the others, is barely observable and moves the window's start; on seed 1's fit windows
# a step of 1e-6 of the true weight promises 95 %, 1e-4 62 %, 1e-2 7 %, the score test's own step
# 0.03 %, and a tenth of the weight raises the fit error (229 -> 306) that the whole one lowers to 11
# (at τ 90 s; 1.2 at the truth's).
CELL_MODE_XFAIL = ("seed 1 (R2 20 mOhm, tau2 73.8 s): the mode promises 0.03 % of the fit error, out of the round's 3 "
                   "best promises (its weight's finite-difference column is dominated by the mode's estimated initial "
                   "state, see above; the true mode lowers the fit error from 229 to 1.2): nothing named")


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=[pytest.mark.slow, pytest.mark.xfail(
    strict=False, raises=AssertionError, reason=CELL_MODE_XFAIL)])])
def test_a_cells_missing_slow_rc_pair_is_named_through_its_nonlinear_output(
        tmp_path: Path, user_systems: Path, seed: int) -> None:
    rng = np.random.default_rng(500 + seed)
    r2, tau2 = float(rng.uniform(1 / 3, 1.0) * TRUE["r1"]), float(rng.uniform(1.5, 3.0) * TAU1)
    started = time.perf_counter()
    search = diagnose_cell(user_systems, int(rng.integers(1000)), ("capacity", "r0"), r2=r2, tau2=tau2)
    named = _named(search)
    described = [f.describe() for f in search.named]
    print(f"cell, a second RC pair, seed {seed}: R2 {r2 * 1e3:.3g} mOhm, tau2 {tau2:.3g} s; named {described}, "
          f"{time.perf_counter() - started:.1f} s")
    assert "missing_mode" in named, (r2, tau2, described, _tried(search))
    found = named["missing_mode"]
    assert found.target.startswith("current"), found.describe()
    tau = found.values["cell/mode_current_tau_s"]
    scale = found.candidate.spec.block("cell").parameters["mode_current_scale_on_voltage"]
    gain = -found.values["cell/mode_current_on_voltage"] * scale  # the pair's drop lowers the voltage
    print(f"  R2 {r2 * 1e3:.3g} -> {gain * 1e3:.3g} mOhm, tau2 {tau2:.3g} -> {tau:.3g} s")
    assert tau == pytest.approx(tau2, rel=0.2), (tau2, found.describe())
    assert gain == pytest.approx(r2, rel=0.2), (r2, gain, found.describe())
    assert "direction_parameter" not in named, described


@pytest.mark.parametrize("seed", _seeds())
def test_a_cells_resistance_by_direction_of_the_current_is_named_with_its_size(
        tmp_path: Path, user_systems: Path, seed: int) -> None:
    rng = np.random.default_rng(510 + seed)
    d = float(rng.choice([-1, 1]) * rng.uniform(0.2, 0.5))
    started = time.perf_counter()
    search = diagnose_cell(user_systems, int(rng.integers(1000)), ("r0", "r1"), d=d)
    named = _named(search)
    described = [f.describe() for f in search.named]
    r1 = float(search.spec.parameters.get("r1", CELL_VALUES["r1"]))
    print(f"cell, R1 by direction, seed {seed}: d {d:.3f}; named {described} (R1 {r1 * 1e3:.3g} mOhm), "
          f"{time.perf_counter() - started:.1f} s")
    assert "direction_parameter" in named, (d, described, _tried(search))
    found = named["direction_parameter"]
    assert found.target == "r1 on current", found.describe()
    assert found.values["cell/r1_direction_current"] == pytest.approx(d, rel=0.25), (d, found.describe())
    assert r1 == pytest.approx(TRUE["r1"], rel=0.1), (r1, described)  # the direction, not a new nominal R1
    for f in search.named:  # an identified value is reported as the model written holds it (re-fitted by the causes)
        if f.cause == "parameter_mismatch":
            assert f.values[f.target] == pytest.approx(float(search.spec.parameters[f.target]), rel=1e-9), described
    assert "missing_mode" not in named, described


def test_a_cell_without_either_effect_names_neither(tmp_path: Path, user_systems: Path) -> None:
    # R0 30 % off and a 50 mA bias of the current sensor (the SOC drifts by 8 mV of OCV in 25 min): something
    # to name besides the nominal's value, and a drift that a slow mode of the current or a resistance by
    # its direction could bend towards
    started = time.perf_counter()
    search = diagnose_cell(user_systems, 21, ("r0", "r1"), r0_off=1.3, bias=0.05)
    causes = {f.cause for f in search.named}
    described = [f.describe() for f in search.named]
    print(f"cell, R0 30 % off, a 50 mA current bias: named {described}, {time.perf_counter() - started:.1f} s")
    assert {"parameter_mismatch", "input_offset"} <= causes, described
    assert not causes & {"missing_mode", "direction_parameter"}, described


# -- the flexible structure ------------------------------------------------------------------------

def mount_truth(seed: int, seconds: float, d: float = 0.0, compliance: float = 0.0, tau_f: float = 1.0,
                offset: float = 0.0) -> dict[str, np.ndarray]:
    """A random-phase multisine force of 0.1-8 Hz held over each sample; the payload by RK4 at a quarter
    of a sample with the damper c (1 + d sgn v); the frame x_f exact, τf ẋf = -compliance F - xf; the
    position sensor on the frame reads x - xf (``offset``: its bias [m]), the accelerometer on the payload
    its acceleration."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds / DT))
    t = np.arange(n) * DT
    freqs, phases = rng.uniform(0.1, 8.0, 20), rng.uniform(0, 2 * np.pi, 20)
    force = 20 * np.sum(np.sin(2 * np.pi * freqs * t[:, None] + phases), -1) / np.sqrt(20)
    m, k, c = MOUNT["m"], MOUNT["k"], MOUNT["c"]

    def rates(s: np.ndarray, f: float) -> np.ndarray:
        return np.array([s[1], (f - k * s[0] - c * (1 + d * np.sign(s[1])) * s[1]) / m])

    state, frame, h = np.zeros(2), 0.0, DT / 4
    decay = np.exp(-DT / tau_f)
    position, acceleration = np.empty(n), np.empty(n)
    for j in range(n):
        position[j] = state[0] - frame
        acceleration[j] = rates(state, force[j])[1]
        for _ in range(4):
            k1 = rates(state, force[j])
            k2 = rates(state + h / 2 * k1, force[j])
            k3 = rates(state + h / 2 * k2, force[j])
            k4 = rates(state + h * k3, force[j])
            state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        frame = decay * frame - (1 - decay) * compliance * force[j]
    return {"time": t, "force": force, "position": position + offset + 2e-5 * rng.standard_normal(n),
            "acceleration": acceleration + 2e-2 * rng.standard_normal(n)}


SENSORS = {"position": "m", "acceleration": "m/s^2"}


def diagnose_mount(folder: Path, seed: int, c_off: float = 1.0, sensors: tuple[str, ...] = tuple(SENSORS), **truth):
    """80 s to train, 30 s to judge; k and c uncertain, the mass known (weighed); ``sensors``: the
    outputs measured (the position alone: the class ``MountPosition``)."""
    split = {"train": mount_truth(seed, 80.0, **truth), "val": mount_truth(seed + 1, 30.0, **truth)}
    for columns in split.values():
        for name in set(SENSORS) - set(sensors):
            del columns[name]
    _files(folder, split)
    dm = _datamodule(folder, DT, {"force": {"role": "input", "unit": "N"},
                                  **{s: {"role": "output", "unit": SENSORS[s]} for s in sensors}}, window=100, past=4)
    values = {**MOUNT, "c": c_off * MOUNT["c"]}
    system = "mount_system:Mount" if len(sensors) == 2 else "mount_system:MountPosition"
    spec = parse_model_spec({"name": "mount", "hold": "zoh", "blocks": {"mount": {
        "kind": "physics", "system": system, "inputs": ["force"], "outputs": list(sensors),
        "initial_state": "estimate", "trainable": ["k", "c"]}}, "outputs": list(sensors)})
    return name_causes(spec, Problem(dm, values, hold="zoh", horizon=100, workers=1), max_causes=2)


@pytest.mark.parametrize("seed", _seeds())
def test_a_structures_creeping_frame_is_named_as_a_missing_mode_of_the_force(
        tmp_path: Path, user_systems: Path, seed: int) -> None:
    rng = np.random.default_rng(520 + seed)
    decay_s = 2 * MOUNT["m"] / MOUNT["c"]
    compliance, tau_f = float(rng.uniform(0.2, 0.6) / MOUNT["k"]), float(rng.uniform(1.5, 3.0) * decay_s)
    started = time.perf_counter()
    search = diagnose_mount(user_systems, int(rng.integers(1000)), compliance=compliance, tau_f=tau_f)
    named = _named(search)
    described = [f.describe() for f in search.named]
    print(f"structure, a creeping frame, seed {seed}: 1/kf {compliance * 1e3:.3g} mm/N, tau_f {tau_f:.3g} s; "
          f"named {described}, {time.perf_counter() - started:.1f} s")
    assert "missing_mode" in named, (compliance, tau_f, described, _tried(search))
    found = named["missing_mode"]
    assert found.target.startswith("force"), found.describe()
    block = found.candidate.spec.block("mount").parameters
    tau = found.values["mount/mode_force_tau_s"]
    gain = found.values["mount/mode_force_on_position"] * block["mode_force_scale_on_position"]
    on_acceleration = found.values["mount/mode_force_on_acceleration"] * block["mode_force_scale_on_acceleration"]
    print(f"  1/kf {compliance * 1e3:.3g} -> {gain * 1e3:.3g} mm/N, tau_f {tau_f:.3g} -> {tau:.3g} s, into the "
          f"acceleration {on_acceleration:.2g} (m/s^2)/N")
    assert tau == pytest.approx(tau_f, rel=0.2), (tau_f, found.describe())
    assert gain == pytest.approx(compliance, rel=0.2), (compliance, gain, found.describe())
    assert abs(on_acceleration) < 0.05 / MOUNT["m"], found.describe()  # next to the force's own 1 / m
    assert "direction_parameter" not in named, described


DIRECTION_CASES = [(("position",), 0), (tuple(SENSORS), 0), (("position",), 1), (tuple(SENSORS), 1)]


@pytest.mark.parametrize("sensors, seed", [
    pytest.param(sensors, seed, id=f"{'+'.join(sensors)}-{seed}",
                 marks=() if seed == 0 and sensors == ("position",) else (pytest.mark.slow,))
    for sensors, seed in DIRECTION_CASES])
def test_a_structures_damping_by_direction_is_named_with_its_size(
        tmp_path: Path, user_systems: Path, sensors: tuple[str, ...], seed: int) -> None:
    rng = np.random.default_rng(530 + seed)  # the same truth measured by either set of sensors
    d = float(rng.choice([-1, 1]) * rng.uniform(0.2, 0.5))
    started = time.perf_counter()
    search = diagnose_mount(user_systems, int(rng.integers(1000)), sensors=sensors, d=d)
    named = _named(search)
    described = [f.describe() for f in search.named]
    print(f"structure, damping by direction, {'+'.join(sensors)}, seed {seed}: d {d:.3f}; named {described}, "
          f"{time.perf_counter() - started:.1f} s")
    assert "direction_parameter" in named, (d, described, _tried(search))
    found = named["direction_parameter"]
    assert found.target == "c on v", found.describe()
    assert found.values["mount/c_direction_v"] == pytest.approx(d, rel=0.25), (d, found.describe())
    assert not {"missing_mode", "output_offset"} & set(named), described


def test_a_structure_without_either_effect_names_neither(tmp_path: Path, user_systems: Path) -> None:
    # c 30 % off and a 2 mm bias of the position sensor: something to name besides the nominal's value,
    # and a level that a slow mode of the force could bend towards
    started = time.perf_counter()
    search = diagnose_mount(user_systems, 31, c_off=1.3, offset=2e-3)
    causes = {f.cause for f in search.named}
    described = [f.describe() for f in search.named]
    print(f"structure, c 30 % off, a 2 mm position bias: named {described}, {time.perf_counter() - started:.1f} s")
    assert "parameter_mismatch" in causes and {"output_offset", "input_offset"} & causes, described
    assert not causes & {"missing_mode", "direction_parameter"}, described
