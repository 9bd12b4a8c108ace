"""The diagnosis at other time scales: effects hidden at random magnitudes in systems hypa never saw.

- **slow**: a user's two-mass thermal plant (heater power and ambient temperature in, both
  temperatures out; time constants of minutes to an hour), sampled every 5 s, records of 3 h;
- **fast**: a stiff positioning stage (the built-in mass-spring-damper, a 1 kHz resonance)
  sampled at 20 kHz, records of half a second.

The truth comes from scipy (``lsim``), not from hypa's engine; the nominal model is the user's
class (by import path) or the built-in one with its uncertain parameters declared. Per seed, one
effect at a random magnitude: an input dead time, one parameter off by 20-40 % either way, or a
sensor offset. The diagnosis must name it first (or list it among what the data cannot tell
it from), with its value, without a single time constant given to it: its scales come from
the model and the data (:mod:`hypa.diagnosis.scales`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from hypa.data import datamodule_from_config
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.scales import Scales, fold_windows
from hypa.diagnosis.search import name_causes
from hypa.models.spec import parse_model_spec

from data_helpers import importable

THERMAL = '''
"""A two-mass thermal plant: heater power into mass 1, mass 2 coupled to it, both losing heat to the ambient."""
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class TwoMassThermal(LTIModel):
    state_names = ("t1", "t2")
    input_names = ("power", "ambient")
    output_names = ("t1", "t2")
    parameters = (ParameterSpec("c1", 2.0e4, "J/K"), ParameterSpec("c2", 8.0e4, "J/K"),
                  ParameterSpec("g12", 30.0, "W/K"), ParameterSpec("g1a", 10.0, "W/K"),
                  ParameterSpec("g2a", 16.0, "W/K"))

    def matrices(self, p):
        c1, c2, g12, g1a, g2a = (p[k] for k in ("c1", "c2", "g12", "g1a", "g2a"))
        z = torch.zeros_like(c1)
        a = torch.stack([torch.stack([-(g12 + g1a) / c1, g12 / c1]), torch.stack([g12 / c2, -(g12 + g2a) / c2])])
        b = torch.stack([torch.stack([1 / c1, g1a / c1]), torch.stack([z, g2a / c2])])
        return StateSpace(a, b, torch.eye(2, dtype=c1.dtype), torch.zeros(2, 2, dtype=c1.dtype))
'''
THERMAL_TRUE = {"c1": 2.0e4, "c2": 8.0e4, "g12": 30.0, "g1a": 10.0, "g2a": 16.0}
STAGE_TRUE = {"mass": 1.0e-3, "stiffness": 4.0e4, "damping": 2.0, "offset_force": 0.0}


def _files(folder: Path, columns: dict[str, dict[str, np.ndarray]]) -> None:
    for split, cols in columns.items():
        np.savetxt(folder / f"{split}.csv", np.column_stack(list(cols.values())), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.12g")


def _datamodule(folder: Path, dt: float, channels: dict, window: int, past: int):
    data = {"source": "files", "dir": str(folder), "time": {"column": "time", "unit": "s"},
            "sample_rate_hz": 1.0 / dt, "rate_hz": None, "channels": channels, "splits": None, "select": [],
            "window": window, "past": past, "stride": 10, "eval_stride": 50, "batch_size": 32, "num_workers": 0,
            "seed": 0}
    dm = datamodule_from_config(data, folder)
    dm.setup()
    return dm


def thermal_truth(seed: int, delay_s: float = 0.0, g12: float = 30.0, offset: float = 0.0,
                  hours: float = 3.0) -> dict[str, np.ndarray]:
    """The plant by scipy (inputs held over each sample: the heater power is a staircase), 0.05 K noise."""
    dt, rng = 5.0, np.random.default_rng(seed)
    n = int(hours * 3600 / dt)
    t = np.arange(n) * dt
    power = np.repeat(rng.uniform(0, 2000, size=n // 120 + 1), 120)[:n]  # [W], a new level every 10 min
    ambient = 293.15 + 3 * np.sin(2 * np.pi * t / 7200 + rng.uniform(0, 6)) + 0.02 * rng.standard_normal(n)
    p = {**THERMAL_TRUE, "g12": g12}
    a = np.array([[-(p["g12"] + p["g1a"]) / p["c1"], p["g12"] / p["c1"]],
                  [p["g12"] / p["c2"], -(p["g12"] + p["g2a"]) / p["c2"]]])
    b = np.array([[1 / p["c1"], p["g1a"] / p["c1"]], [0, p["g2a"] / p["c2"]]])
    u = np.column_stack([np.interp(t - delay_s, t, power, left=power[0]), ambient])
    _, y, _ = signal.lsim(signal.lti(a, b, np.eye(2), np.zeros((2, 2))), u, t, X0=-np.linalg.solve(a, b @ u[0]),
                          interp=False)
    y = y + 0.05 * rng.standard_normal(y.shape)
    y[:, 1] += offset
    return {"time": t, "power": power, "ambient": ambient, "t1": y[:, 0], "t2": y[:, 1]}


def stage_truth(seed: int, delay_s: float = 0.0, stiffness: float = 4.0e4, offset: float = 0.0,
                seconds: float = 0.5) -> dict[str, np.ndarray]:
    """The stage by scipy (a smooth random force up to 2 kHz, linear between samples), 0.2 % noise."""
    rate, rng = 20_000.0, np.random.default_rng(seed)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    b, a = signal.butter(2, 2000.0 / (rate / 2))
    force = signal.lfilter(b, a, rng.standard_normal(n + 400))[400:] * 20.0  # [N]
    m, c = STAGE_TRUE["mass"], STAGE_TRUE["damping"]
    system = signal.lti([[0, 1], [-stiffness / m, -c / m]], [[0], [1 / m]], [[1, 0]], [[0]])
    _, position, _ = signal.lsim(system, np.interp(t - delay_s, t, force, left=force[0]), t, interp=True)
    position = position + offset + 0.002 * np.std(position) * rng.standard_normal(n)
    return {"time": t, "force": force, "position": position}


@pytest.fixture
def thermal_system(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    yield from importable(tmp_path, monkeypatch, {"thermal_plant": THERMAL})


def diagnose_thermal(folder: Path, **effect: float):
    (folder / "data").mkdir()
    _files(folder / "data", {"train": thermal_truth(0, **effect), "val": thermal_truth(1, **effect)})
    channels = {"power": {"role": "input", "unit": "W"}, "ambient": {"role": "input", "unit": "K"},
                "t1": {"role": "output", "unit": "K"}, "t2": {"role": "output", "unit": "K"}}
    dm = _datamodule(folder / "data", 5.0, channels, window=100, past=10)
    spec = parse_model_spec({"name": "thermal", "hold": "zoh", "blocks": {"plant": {
        "kind": "physics", "system": "thermal_plant:TwoMassThermal", "inputs": ["power", "ambient"],
        "outputs": ["t1", "t2"], "initial_state": "estimate", "trainable": ["g12", "g1a", "g2a"]}},
        "outputs": ["t1", "t2"]})
    return name_causes(spec, Problem(dm, {}, hold="zoh", horizon=100, workers=1), max_causes=2)


def diagnose_stage(folder: Path, **effect: float):
    _files(folder, {"train": stage_truth(0, **effect), "val": stage_truth(1, seconds=0.25, **effect)})
    channels = {"force": {"role": "input", "unit": "N"}, "position": {"role": "output", "unit": "m"}}
    dm = _datamodule(folder, 5e-5, channels, window=100, past=10)
    spec = parse_model_spec({"name": "stage", "blocks": {"stage": {
        "kind": "physics", "system": "mass_spring_damper", "inputs": ["force"], "outputs": ["position"],
        "initial_state": "estimate", "trainable": ["stiffness", "damping"]}}, "outputs": ["position"]})
    return name_causes(spec, Problem(dm, STAGE_TRUE, hold="foh", horizon=100, workers=1), max_causes=1)


def _effect(system: str, cause: str, rng: np.random.Generator) -> tuple[dict[str, float], str, float]:
    """(the truth's keyword, the knob the diagnosis reports, the true value) for one random effect."""
    sign = rng.choice([-1.0, 1.0])
    if system == "thermal":
        value = {"input_delay": rng.uniform(30.0, 90.0),
                 "parameter_mismatch": 30.0 * (1 + sign * rng.uniform(0.2, 0.4)),
                 "output_offset": sign * rng.uniform(0.3, 0.8)}[cause]
        key = {"input_delay": "delay_s", "parameter_mismatch": "g12", "output_offset": "offset"}[cause]
        knob = {"input_delay": "diagnosed_delay_power/delay_s", "parameter_mismatch": "g12",
                "output_offset": "t2"}[cause]
    else:
        value = {"input_delay": rng.uniform(1e-4, 3e-4),
                 "parameter_mismatch": 4.0e4 * (1 + sign * rng.uniform(0.2, 0.4)),
                 "output_offset": sign * rng.uniform(0.3, 0.8) * 5e-4}[cause]
        key = {"input_delay": "delay_s", "parameter_mismatch": "stiffness", "output_offset": "offset"}[cause]
        knob = {"input_delay": "diagnosed_delay_force/delay_s", "parameter_mismatch": "stiffness",
                "output_offset": "position"}[cause]
    return {key: float(value)}, knob, float(value)


CASES = [(system, cause, seed) for system in ("thermal", "stage")
         for cause in ("input_delay", "parameter_mismatch", "output_offset") for seed in range(3)]


@pytest.mark.parametrize("system, cause, seed", [
    pytest.param(*case, marks=() if case[2] == 0 else pytest.mark.slow, id="-".join(map(str, case))) for case in CASES])
def test_a_hidden_effect_is_named_at_any_time_scale(tmp_path: Path, thermal_system: Path, system: str, cause: str,
                                                    seed: int) -> None:
    rng = np.random.default_rng(1000 * seed + CASES.index((system, cause, seed)))
    effect, knob, value = _effect(system, cause, rng)
    search = (diagnose_thermal if system == "thermal" else diagnose_stage)(tmp_path, **effect)
    first = search.rounds[0][:3] if search.rounds else []
    assert search.named, [f.describe() for f in first]
    named = search.named[0]
    if named.cause != cause:  # named as something the data cannot tell it from: it must be listed beside
        assert any(a.startswith(f"{cause} on ") for a in named.alternatives), (named.describe(), named.alternatives)
        return
    assert named.values[knob] == pytest.approx(value, rel=0.2), (
        named.describe(), effect)
    assert named.gain > 0.5, named.describe()


def test_clean_slow_data_name_nothing_but_at_most_a_small_bias(tmp_path: Path, thermal_system: Path) -> None:
    search = diagnose_thermal(tmp_path)
    assert all(f.small for f in search.named), [f.describe() for f in search.named]


def test_the_scales_follow_the_model_and_the_data() -> None:
    """The rule of hypa.diagnosis.scales at three time scales, and its edges (an integrator, no modes)."""
    slow = Scales.of([-1e-3, -1.266e-4], 5.0, [2160, 2160], [2160], 100)
    assert slow.slowest_s == pytest.approx(1 / 1.266e-4) and slow.stretch == 2160  # 50 decay times > a record
    assert slow.fit_window == 2160 // 8 and slow.max_lag == 540 and slow.band_edges_hz[-1] == pytest.approx(0.1)
    fast = Scales.of([complex(-1000, 6245), complex(-1000, -6245)], 5e-5, [10000, 5000], [10000], 100)
    assert fast.slowest_s == pytest.approx(1e-3) and fast.stretch == 1000 and fast.fit_window == 100
    assert fast.period_s == pytest.approx(2 * np.pi / 6245) and fast.band_edges_hz[-1] == pytest.approx(1e4)
    assert all(a < b for a, b in zip(fast.band_edges_hz, fast.band_edges_hz[1:]))
    integrating = Scales.of([0.0, -2.0], 1e-3, [20000], [20000], 200)
    # 50 decay times (25000 samples) exceed the record: one stretch, its 13 fit windows enough
    assert integrating.integrating and integrating.slowest_s == pytest.approx(0.5) and integrating.stretch == 20000
    # short records of a slow system (1024 samples every 4 s, decay time 87 s): one block per record
    # would fit one fold on the 205 validation samples (2 fit windows): a quarter of the data each
    # (256 samples, 12 decay times), so each fold fits on 4 or 5 of data.window (100 samples); still
    # under 8, the fit windows are the model's own 3 decay times (66 samples): 6 or 7
    short = Scales.of([-1 / 87.3], 4.0, [819, 205], [819], 100)
    assert short.stretch == 256 and short.fit_window == 66
    assert (fold_windows([819, 205], 819, 100), fold_windows([819, 205], 256, 100)) == (2, 4)
    assert fold_windows([819, 205], 256, 66) == 6
    # where data.window leaves the folds enough windows, it stays (the data module's own windows)
    assert Scales.of([-1 / 87.3], 4.0, [8190, 2050], [8190], 100).fit_window == 100
    # EMPS' records (a long training record, a short validation one; decay time 0.47 s at 1 kHz):
    # 3 windows of 1.4 s in the short fold, 7 with blocks of 6.2 s
    emps = Scales.of([0.0, -1 / 0.467], 1e-3, [19852, 4990], [19852], 100)
    assert emps.stretch == 6211 and fold_windows([19852, 4990], 19852, emps.fit_window) == 3
    # never below 5 decay times: where a quarter of the data is less, the whole record, as before
    assert Scales.of([-1 / 87.3], 4.0, [300, 100], [300], 20).stretch == 300
    lightly_damped = Scales.of([complex(-0.1, 1.0), complex(-0.1, -1.0)], 0.01, [100000], [100000], 100)
    assert lightly_damped.stretch == 50000  # 50 decay times (500 s) beat 10 periods (62.8 s)
    resonant = Scales.of([complex(-10.0, 1.0), complex(-10.0, -1.0)], 0.01, [100000], [100000], 100)
    assert resonant.stretch == 6284  # 10 periods (62.8 s) beat 50 decay times (5 s)
    static = Scales.of([], 0.01, [1000], [1000], 100)
    assert static.slowest_s == 0.01 and static.stretch == 50 and not static.integrating


def test_validation_data_that_miss_the_training_range_are_reported(tmp_path: Path) -> None:
    """A validation record whose heater power column spans a third of the training's: reported, in
    W; the ambient temperature, alike in both, is not."""
    from hypa.diagnosis.coverage import coverage, short_lines

    train, val = thermal_truth(0), thermal_truth(1)
    _files(tmp_path, {"train": train, "val": {**thermal_truth(1), "power": val["power"] / 3}})
    channels = {"power": {"role": "input", "unit": "W"}, "ambient": {"role": "input", "unit": "K"},
                "t1": {"role": "output", "unit": "K"}, "t2": {"role": "output", "unit": "K"}}
    dm = _datamodule(tmp_path, 5.0, channels, window=100, past=10)
    found = {c.channel: c for c in coverage(dm)}
    assert found["power"].short and found["power"].covered < 0.5 and not found["ambient"].short
    lines = short_lines(dm, list(found.values()))
    assert any(line.startswith("power (input): the validation records span") and " W of the training's" in line
               for line in lines), lines
