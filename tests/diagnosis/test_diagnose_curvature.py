"""A nonlinearity on a state of a system hypa never saw, hidden at random magnitudes: named by the
generic ``cubic_state`` and ``square_state`` entries, with its size, at two time scales.

- **slow**: a ship's roll (a user's class), its righting moment k φ (1 + h φ²) stiffening or
  softening at large angles, sampled every 0.5 s (a 12 s roll period), records of 40 min;
- **fast**: a series RLC (a user's class) whose capacitor is shunted by i = g1 v + g3 v³ (a
  varistor), sampled at 40 kHz (a 1.6 kHz resonance), records of a quarter second;
- **slow, one-sided**: a tank draining through an orifice, dh/dt = -K √h + B u, every 4 s for 3 h,
  whose nominal model is its linearisation about the mean level: ``square_state`` must be named,
  with w = -σ / (4 μ), the Taylor coefficient of √h about the level μ (σ: the level's spread).

The truth comes from scipy's ODE solver, the nominal model is the linear class with the true
linear parameters. The diagnosis must name ``cubic_state`` (the tank: ``square_state``) first,
on the state the nonlinearity reads, and its weight must give back the hidden coefficient: the
coupling from x_j bends as A_rj w (x_j - μ_j) ((x_j - μ_j) / σ_j)², so h = w / σ² (roll) and
g3 = g1 w / σ² (circuit) where the operating point μ is near 0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from hypa.diagnosis.problem import Problem
from hypa.diagnosis.search import name_causes
from hypa.models.spec import parse_model_spec

from data_helpers import importable
from test_diagnose_time_scales import _datamodule, _files
from test_fast_circuit import SYSTEM as CIRCUIT_SYSTEM

ROLL_SYSTEM = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class ShipRoll(LTIModel):
    """I φ'' + d φ' + k φ = M: roll angle [rad] and rate [rad/s] from the wave moment [N m]."""
    state_names = ("angle", "rate")
    input_names = ("moment",)
    output_names = ("angle",)
    parameters = (ParameterSpec("inertia", 1.0e7, "kg m^2"), ParameterSpec("damping", 1.0e6, "N m s/rad"),
                  ParameterSpec("stiffness", 2.7e6, "N m/rad"))

    def matrices(self, p):
        i, d, k = p["inertia"], p["damping"], p["stiffness"]
        z, one = torch.zeros_like(i), torch.ones_like(i)
        a = torch.stack([torch.stack([z, one]), torch.stack([-k / i, -d / i])])
        return StateSpace(a, torch.stack([z, 1 / i]).reshape(2, 1), torch.stack([one, z]).reshape(1, 2),
                          i.new_zeros(1, 1))

'''
TANK_SYSTEM = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class Tank(LTIModel):
    """dh/dt = -h / tau + k u + e: a tank linearised about its level."""
    state_names = ("level",)
    input_names = ("inflow",)
    output_names = ("level",)
    parameters = (ParameterSpec("tau", 100.0, "s"), ParameterSpec("gain", 0.03, "m/(s V)"),
                  ParameterSpec("drift", 0.0, "m/s", positive=False))

    def matrices(self, p):
        t = p["tau"]
        return StateSpace((-1 / t).reshape(1, 1), p["gain"].reshape(1, 1), torch.ones(1, 1, dtype=t.dtype),
                          t.new_zeros(1, 1), p["drift"].reshape(1))
'''
ORIFICE_SYSTEM = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class OrificeTank(LTIModel):
    """dh/dt = -K sqrt(h) + k u: the user's own physics of the tank's outflow."""
    state_names = ("level",)
    input_names = ("inflow",)
    output_names = ("level",)
    parameters = (ParameterSpec("outflow", 0.01, "m^0.5/s"), ParameterSpec("gain", 0.03, "m/(s V)"))

    def matrices(self, p):
        g = p["gain"]
        return StateSpace(g.new_zeros(1, 1), g.reshape(1, 1), torch.ones(1, 1, dtype=g.dtype), g.new_zeros(1, 1))

    def feedback(self, p):
        return (-p["outflow"]).reshape(1, 1)

    def nonlinearity(self, x, u, p):
        return torch.sqrt(x.clamp_min(1e-9))
'''
ROLL = {"inertia": 1.0e7, "damping": 1.0e6, "stiffness": 2.7e6}
CIRCUIT = {"inductance": 0.01, "capacitance": 1e-6, "resistance": 20.0, "conductance": 1e-3}


@pytest.fixture
def user_systems(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    # the circuit is test_fast_circuit's user system; its nominal values do not matter here (given)
    yield from importable(tmp_path, monkeypatch, {"ship_roll": ROLL_SYSTEM, "circuit_system": CIRCUIT_SYSTEM,
                                                  "tank_system": TANK_SYSTEM, "orifice_system": ORIFICE_SYSTEM})


def roll_truth(seed: int, hardening: float, minutes: float) -> dict[str, np.ndarray]:
    """Waves of 6-20 s (filtered noise, linear between samples), roll up to about 0.3 rad, 2 mrad noise."""
    dt, rng = 0.5, np.random.default_rng(seed)
    n = int(minutes * 60 / dt)
    t = np.arange(n) * dt
    b, a = signal.butter(2, [0.05 / 1.0, 0.17 / 1.0], btype="band")
    moment = signal.lfilter(b, a, rng.standard_normal(n + 200))[200:]
    moment *= 1.3e5 / np.std(moment)  # [N m]
    i, d, k = ROLL["inertia"], ROLL["damping"], ROLL["stiffness"]

    def rhs(time: float, x: np.ndarray) -> np.ndarray:
        return np.array([x[1], (np.interp(time, t, moment) - d * x[1] - k * x[0] * (1 + hardening * x[0] ** 2)) / i])

    x = solve_ivp(rhs, (0, t[-1]), np.zeros(2), t_eval=t, rtol=1e-9, atol=1e-12, max_step=dt).y
    return {"time": t, "moment": moment, "angle": x[0] + 0.002 * rng.standard_normal(n)}


def circuit_truth(seed: int, cubic: float, seconds: float) -> dict[str, np.ndarray]:
    """A multisine of 200 Hz-4 kHz whose amplitude sweeps (so the nonlinearity shows), 5 mV noise."""
    rate, rng = 40_000.0, np.random.default_rng(seed)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    freqs, amps, phases = rng.uniform(200, 4000, 30), rng.uniform(0.5, 1.0, 30), rng.uniform(0, 2 * np.pi, 30)
    sweep = rng.uniform(8, 16)

    def source(time: float | np.ndarray) -> float | np.ndarray:
        envelope = 1.0 + 0.8 * np.sin(2 * np.pi * sweep * np.asarray(time))
        return 0.5 * envelope * np.sum(amps * np.sin(2 * np.pi * freqs * np.asarray(time)[..., None] + phases), -1)

    ind, c, r, g = (CIRCUIT[k] for k in ("inductance", "capacitance", "resistance", "conductance"))

    def rhs(time: float, x: np.ndarray) -> np.ndarray:
        return np.array([(source(time) - r * x[0] - x[1]) / ind, (x[0] - g * x[1] - cubic * x[1] ** 3) / c])

    x = solve_ivp(rhs, (0, t[-1]), np.zeros(2), t_eval=t, method="DOP853", rtol=1e-9, atol=1e-12).y
    return {"time": t, "source": source(t), "voltage": x[1] + 0.005 * rng.standard_normal(n)}


def tank_truth(seed: int, outflow: float, hours: float) -> dict[str, np.ndarray]:
    """A pump level held for 4 min at a time (2-8 V, 0.03 m/s per V), 5 mm noise."""
    dt, rng = 4.0, np.random.default_rng(seed)
    n = int(hours * 3600 / dt)
    t = np.arange(n) * dt
    pump = np.repeat(rng.uniform(2, 8, n // 60 + 1), 60)[:n]

    def rhs(time: float, h: np.ndarray) -> list[float]:
        return [-outflow * np.sqrt(max(h[0], 0.0)) + 0.03 * pump[min(int(time // dt), n - 1)]]

    level = solve_ivp(rhs, (0, t[-1]), [(0.15 / outflow) ** 2], t_eval=t, rtol=1e-9, atol=1e-11, max_step=dt).y[0]
    return {"time": t, "inflow": pump, "level": level + 0.005 * rng.standard_normal(n)}


def diagnose(folder: Path, system: str, magnitude: float):
    return name_causes(*setup(folder, system, magnitude), max_causes=1)


def setup(folder: Path, system: str, magnitude: float) -> tuple:
    """(the nominal model, the diagnosis problem) of a case."""
    if system == "roll":
        train, val = roll_truth(0, magnitude, 40.0), roll_truth(1, magnitude, 20.0)
        channels = {"moment": ("input", "N m"), "angle": ("output", "rad")}
        dt, block, values = 0.5, "ship_roll:ShipRoll", ROLL
    elif system == "tank":  # the nominal model: the tank linearised about the training record's mean level
        train, val = tank_truth(0, magnitude, 3.0), tank_truth(1, magnitude, 1.5)
        channels = {"inflow": ("input", "V"), "level": ("output", "m")}
        mean = float(np.mean(train["level"]))
        dt, block = 4.0, "tank_system:Tank"
        values = {"tau": 2 * np.sqrt(mean) / magnitude, "gain": 0.03, "drift": -magnitude * np.sqrt(mean) / 2}
    else:
        train, val = circuit_truth(0, magnitude, 0.25), circuit_truth(1, magnitude, 0.1)
        channels = {"source": ("input", "V"), "voltage": ("output", "V")}
        dt, block, values = 2.5e-5, "circuit_system:LinearCircuit", CIRCUIT
    _files(folder, {"train": train, "val": val})
    dm = _datamodule(folder, dt, {k: {"role": role, "unit": unit} for k, (role, unit) in channels.items()},
                     window=100, past=10)
    inputs, outputs = [k for k, (r, _) in channels.items() if r == "input"], [k for k, (r, _) in channels.items()
                                                                                if r == "output"]
    hold = "zoh" if system == "tank" else "foh"  # the pump is held; the others are smooth
    spec = parse_model_spec({"name": system, "hold": hold, "blocks": {"plant": {
        "kind": "physics", "system": block, "inputs": inputs, "outputs": outputs,
        "initial_state": "estimate"}}, "outputs": outputs})
    return spec, Problem(dm, values, hold=hold, horizon=100, workers=1)


CASES = [(system, seed) for system in ("roll", "circuit", "tank") for seed in range(3)]


@pytest.mark.parametrize("system, seed", [
    pytest.param(*case, marks=() if case[1] == 0 else pytest.mark.slow, id="-".join(map(str, case))) for case in CASES])
def test_a_hidden_nonlinearity_on_a_state_is_named_with_its_size(tmp_path: Path, user_systems: Path, system: str,
                                                          seed: int) -> None:
    rng = np.random.default_rng(100 + CASES.index((system, seed)))
    if system == "roll":  # stiffening or softening: 18-45 % of the righting moment at 0.3 rad
        magnitude = float(rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 5.0))
        state, row, linear = "angle", "rate", 1.0
    elif system == "circuit":  # the shunt's conductance grows by 50-200 % at 2 V
        magnitude = float(rng.uniform(1.25e-4, 5e-4))
        state, row, linear = "voltage", "voltage", CIRCUIT["conductance"]
    else:  # the orifice's K [m^0.5/s]: mean levels of about 3-14 m
        magnitude = float(rng.uniform(0.04, 0.08))
        state, row, linear = "level", "level", None
    search = diagnose(user_systems, system, magnitude)
    first = search.rounds[0][:4] if search.rounds else []
    cause = "square_state" if system == "tank" else "cubic_state"
    assert search.named and search.named[0].cause == cause, [f.describe() for f in first]
    named = search.named[0]
    assert named.target == f"plant/{state}", named.describe()
    block = search.spec.block("plant")
    level, spread = block.parameters[f"{state}_level"], block.parameters[f"{state}_spread"]
    weight = named.values[f"plant/curve_{state}_on_{row}"]
    if system == "tank":  # √h = √μ (1 + (h - μ) / 2μ - (h - μ)² / 8μ² ...): the coupling's w = -σ / 4μ
        assert "is (1 + w z) times the linear one" in named.describe()
        assert weight == pytest.approx(-spread / (4 * level), rel=0.15), (named.describe(), level, spread)
        assert named.gain > 0.5, named.describe()
        return
    assert f"each coupling from {state} is (1 + w z²) times the linear one, z = ({state} " in named.describe()
    assert abs(level) < 0.1 * spread  # the operating point: about 0
    estimate = linear * weight / spread**2
    assert estimate == pytest.approx(magnitude, rel=0.15), (named.describe(), magnitude, spread)
    assert named.gain > 0.5, named.describe()


def test_a_cause_the_later_ones_made_unnecessary_is_dropped(tmp_path: Path, user_systems: Path) -> None:
    """The search's last step (``search._prune``) on a final model of two causes: a parameter
    "mismatch" at its nominal value (inert: what a stand-in becomes once later causes carry its
    effect) is dropped, the cubic on the voltage that the data need is kept, and the model is
    rebuilt without the dropped one."""
    from hypa.diagnosis.catalogue import catalogue_candidates, load_catalogue
    from hypa.diagnosis.edits import applied, frozen
    from hypa.diagnosis.finding import Finding
    from hypa.diagnosis.search import _prune
    from hypa.diagnosis.states import state_scales

    _files(tmp_path, {"train": circuit_truth(0, 2.5e-4, 0.1), "val": circuit_truth(1, 2.5e-4, 0.05)})
    dm = _datamodule(tmp_path, 2.5e-5, {"source": {"role": "input", "unit": "V"},
                                        "voltage": {"role": "output", "unit": "V"}}, window=100, past=10)
    nominal = parse_model_spec({"name": "c", "hold": "foh", "blocks": {"plant": {
        "kind": "physics", "system": "circuit_system:LinearCircuit", "inputs": ["source"], "outputs": ["voltage"],
        "initial_state": "estimate", "trainable": ["resistance"]}}, "outputs": ["voltage"]})
    problem = Problem(dm, CIRCUIT, hold="foh", horizon=100, workers=1).scaled(frozen(nominal))
    folds = problem.folds()
    entries = [e for e in load_catalogue() if e.id in ("parameter_mismatch", "cubic_state")]
    states = state_scales(problem.build(frozen(nominal)))

    def candidates(spec):
        return catalogue_candidates(entries, spec, dm.input_names, dm.output_names, dm.scheduling_names, CIRCUIT,
                                    dm.dt, {"plant": ("resistance",)}, {}, states)

    def pick(spec, key):
        return next(c for c in candidates(spec) if c.key == key)

    inert = pick(frozen(nominal), "parameter_mismatch:resistance")
    base = applied(inert, {"resistance": CIRCUIT["resistance"]})
    spread = states["plant/voltage"][1]
    cubic = pick(base, "cubic_state:plant/voltage")
    final = applied(cubic, {"plant/curve_voltage_on_voltage": 2.5e-4 * spread**2 / CIRCUIT["conductance"],
                            "plant/curve_voltage_on_current": 0.0})
    named = [Finding(c.cause, c.target, {}, {}, 0.0, 0.5, 0.0, candidate=c) for c in (inert, cubic)]
    scores = [p.stretches("val").score(p.build(final)) for p in folds]
    dropped = []
    kept, bases, after = _prune(nominal, named, dropped, [final] * len(folds), scores, folds, candidates, 0.15, 1e-4,
                                "error", lambda _: None)
    assert [f.cause for f in kept] == ["cubic_state"] and [f.cause for f in dropped] == ["parameter_mismatch"]
    assert dropped[0].note.startswith("dropped: ")
    assert "plant" in bases[0].block_names and bases[0].block("plant").curved == {"voltage": 3}
    assert after == pytest.approx(scores, rel=1e-4)  # the same model: the resistance was at its nominal value


def test_a_users_replacement_system_at_a_guessed_start_is_fitted_and_named(tmp_path: Path, user_systems: Path
                                                                          ) -> None:
    """A user's catalogue entry that replaces the linear tank by their orifice class, its K guessed at
    0.01 m^0.5/s (a fourth to an eighth of the truth: the tank would fill to 16-64 times its level):
    the guess is far worse than the model it replaces, so a score test from it promises nothing (the
    real cascaded tanks' Torricelli entry was never fitted). A swapped system is fitted whatever it
    promises, and is named with K."""
    import yaml

    from hypa.diagnosis.catalogue import catalogue_candidates, load_catalogue
    from hypa.diagnosis.edits import frozen
    from hypa.diagnosis.fitting import GradientFit, base_model

    outflow = float(np.random.default_rng(7).uniform(0.04, 0.08))
    entry = tmp_path / "orifice.yaml"
    entry.write_text(yaml.safe_dump([{
        "id": "orifice", "name": "an outflow through an orifice, K sqrt(h)", "for_each": "block",
        "where": {"system": {"tank_system:Tank": "orifice_system:OrificeTank"}}, "fit": "gradient",
        "patch": {"blocks": {"{block}": {"system": "{system}", "trainable": ["outflow", "gain"]}}}}]))
    entries = [e for e in load_catalogue([entry]) if e.id in ("orifice", "output_offset")]

    spec, problem = setup(user_systems, "tank", outflow)
    search = name_causes(spec, problem, entries, max_causes=1)
    assert search.named and search.named[0].cause == "orifice", [f.describe() for f in search.rounds[0]]
    named = search.named[0]
    assert named.values["outflow"] == pytest.approx(outflow, rel=0.05), named.describe()
    assert named.gain > 0.5, named.describe()

    # its score test from the guess promises next to nothing: screened, it would not have been fitted
    spec = frozen(spec)
    problem = problem.scaled(spec)
    windows = problem.windows()
    orifice = next(c for c in catalogue_candidates(entries, spec, ["inflow"], ["level"], [], problem.physical_values,
                                                   problem.dm.dt, states={}) if c.cause == "orifice")
    assert orifice.replaces
    guessed = GradientFit(orifice, problem, windows)
    guessed.base = base_model(problem, windows, spec, ())
    assert guessed.promise() < 0.05
