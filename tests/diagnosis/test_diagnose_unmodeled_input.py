"""A measured channel the model does not read, hidden at random strengths: named by the generic
``unread_channel`` entry on a system hypa never saw, not absorbed into a bias.

A heated zone (a user's linear class, C dT/dt = -g T + P, every 5 minutes for 40 days): the
nominal model has no outside temperature, the truth loses heat to it, C dT/dt = -g (T - T_out) + P,
and the data declare the outside temperature with role ``auxiliary``. The outside temperature
has a mean (a bias in the zone temperature the model cannot reach: what an offset would stand in
for) and a daily cycle and weather on top (what only the channel explains). The truth is the
exact recursion under the inputs held over each sample, 0.05 K noise. The search must name
``unread_channel`` on the outside temperature with its weight in the zone's derivative, g / C,
near the truth; with an outside temperature that does not reach the zone, it must not name it.

The diagnosed model reads the auxiliary channel: :func:`hypa.data.from_config.read_as_inputs`
names it, and the data built for the model hold it as an input, so ``hypa train`` with the written
model builds on the same data.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from hypa.data.from_config import datamodule_from_config, read_as_inputs
from hypa.diagnosis.catalogue import load_catalogue
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.search import name_causes
from hypa.models import ComposedModel
from hypa.models.spec import parse_model_spec, spec_config

from data_helpers import importable
from test_diagnose_time_scales import _files

ZONE_SYSTEM = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class Zone(LTIModel):
    """C dT/dt = -g T + P: a heated zone's temperature above a reference, T measured."""
    state_names = ("temperature",)
    input_names = ("heat",)
    output_names = ("temperature",)
    parameters = (ParameterSpec("capacity", 1e7, "J/K"), ParameterSpec("conductance", 500.0, "W/K"))

    def matrices(self, p):
        c, g = p["capacity"], p["conductance"]
        return StateSpace((-g / c).reshape(1, 1), (1 / c).reshape(1, 1), torch.ones(1, 1, dtype=c.dtype),
                          c.new_zeros(1, 1))
'''
TRUE = {"capacity": 1e7, "conductance": 500.0}  # [J/K], [W/K]: a time constant of 5.6 h
DT = 300.0  # [s]


@pytest.fixture
def user_systems(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    yield from importable(tmp_path, monkeypatch, {"zone": ZONE_SYSTEM})


def zone_truth(seed: int, days: float, reach: float, offset: float = 0.0) -> dict[str, np.ndarray]:
    """Heater power a new level every 1-8 h; the outside temperature a daily cycle and weather about a
    mean of 5 K; ``reach``: the share of the conductance that leads outside (0: none); ``offset``: the
    zone's sensor bias [K]."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400 / DT)
    t = np.arange(n) * DT
    power = np.repeat(rng.uniform(0, 15000, n), rng.integers(12, 96, n))[:n]
    weather = np.cumsum(rng.standard_normal(n)) * 0.15
    weather -= np.convolve(weather, np.ones(288) / 288, mode="same")  # a few days' drift removed
    outside = 5.0 + 6.0 * np.sin(2 * np.pi * t / 86400 + rng.uniform(0, 2 * np.pi)) + weather
    decay = np.exp(-TRUE["conductance"] / TRUE["capacity"] * DT)
    gain = (1 - decay) / TRUE["conductance"]
    temperature, state = np.empty(n), 20.0
    for k in range(n):
        temperature[k] = state
        state = decay * state + gain * (power[k] + reach * TRUE["conductance"] * outside[k])
    return {"time": t, "heat": power, "temperature": temperature + offset + 0.05 * rng.standard_normal(n),
            "outside": outside}


def data_config(folder: Path) -> dict:
    return {"source": "files", "dir": str(folder), "time": {"column": "time", "unit": "s"},
            "sample_rate_hz": 1.0 / DT, "rate_hz": None,
            "channels": {"heat": {"role": "input", "unit": "W"}, "temperature": {"role": "output", "unit": "K"},
                         "outside": {"role": "auxiliary", "unit": "K"}},
            "splits": None, "select": [], "window": 100, "past": 4, "stride": 10, "eval_stride": 50,
            "batch_size": 32, "num_workers": 0, "seed": 0}


NOMINAL = parse_model_spec({"name": "zone", "hold": "zoh", "blocks": {"zone": {
    "kind": "physics", "system": "zone:Zone", "inputs": ["heat"], "outputs": ["temperature"],
    "initial_state": "estimate", "trainable": ["conductance"]}}, "outputs": ["temperature"]})


def diagnose(folder: Path, seed: int, reach: float, g_off: float = 1.0, quick: bool = False, offset: float = 0.0):
    """``quick``: the catalogue without its nonlinear entries for any system (a curved, limited or
    dependent state or parameter: seven fits step by step), to keep a case under 20 s."""
    _files(folder, {"train": zone_truth(seed, 24.0, reach, offset), "val": zone_truth(seed + 1, 8.0, reach, offset)})
    dm = datamodule_from_config(data_config(folder), folder, auxiliary_inputs=True)
    dm.setup()
    assert dm.auxiliary_names == ("outside",) and "outside" in dm.input_names
    values = {**TRUE, "conductance": g_off * TRUE["conductance"]}
    catalogue = [e for e in load_catalogue() if e.for_each != "state" and not e.on] if quick else None
    return name_causes(NOMINAL, Problem(dm, values, hold="zoh", horizon=100, workers=1), catalogue=catalogue,
                       max_causes=3)


CASES = [0, 1]


@pytest.mark.parametrize("seed", [pytest.param(s, marks=() if s == 0 else pytest.mark.slow) for s in CASES])
def test_an_unread_outside_temperature_is_named_where_it_acts(tmp_path: Path, user_systems: Path, seed: int) -> None:
    rng = np.random.default_rng(500 + seed)
    reach = float(rng.uniform(0.3, 1.0))
    started = time.perf_counter()
    search = diagnose(user_systems, int(rng.integers(1000)), reach, quick=seed == 0)
    named = {f.cause: f for f in search.named}
    assert "unread_channel" in named, (reach, [f.describe() for f in search.named],
                                        [f.describe() for f in (search.rounds[0][:5] if search.rounds else [])])
    found = named["unread_channel"]
    assert found.target == "outside", found.describe()
    assert search.named[0].cause == "unread_channel" or all(f.cause != "output_offset" for f in search.named), \
        [f.describe() for f in search.named]
    block = found.candidate.spec.block("zone")
    rate = found.values["zone/drive_outside_on_temperature"] * block.parameters["drive_outside_scale_on_temperature"]
    truth = reach * TRUE["conductance"] / TRUE["capacity"]  # [K/s per K]
    assert rate == pytest.approx(truth, rel=0.15), (truth, rate, found.describe())
    assert search.final_score < 0.1 * search.nominal_score, (search.final_score, search.nominal_score)
    print(f"seed {seed}: {truth:.4g} -> {rate:.4g} 1/s, {time.perf_counter() - started:.1f} s")

    # the diagnosed model reads the auxiliary channel: the data built for it hold the channel as an input (the
    # data config itself is only read)
    config = data_config(user_systems)
    assert read_as_inputs(config, spec_config(search.spec)) == ["outside"]
    assert config["channels"]["outside"]["role"] == "auxiliary"
    dm = datamodule_from_config(config, user_systems, as_inputs=["outside"])
    dm.setup()
    assert dm.input_names == ("heat", "outside")
    model = ComposedModel.from_data(dm, search.spec, TRUE)
    assert model.input_names == ("heat", "outside")


def test_an_outside_temperature_that_does_not_reach_the_zone_is_not_named(tmp_path: Path,
                                                                         user_systems: Path) -> None:
    # the conductance 30 % off and a sensor bias of 0.5 K: something to name, and a bias the outside
    # temperature's mean could stand in for
    search = diagnose(user_systems, 21, 0.0, g_off=1.3, quick=True, offset=0.5)
    causes = [f.cause for f in search.named]
    assert {"output_offset", "input_offset"} & set(causes), [f.describe() for f in search.named]  # a bias, as such
    assert "unread_channel" not in causes, [f.describe() for f in search.named]
