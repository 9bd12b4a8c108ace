"""A lithium-ion cell, a domain of its own: a state of charge read through a nonlinear OCV curve.

The true cell: SOC integrator (capacity in Ah), one RC pair, a series resistance R0, terminal
voltage v = OCV(SOC) − v₁ − R0 I, driven at 1 Hz by a random drive cycle (charge and discharge
pulses, rests). The user's class puts the OCV in ``output_nonlinearity`` (a nonlinear output) and
writes its parameters in Ah, mOhm and kF. The reference is the exact recursion of the sampled
system (the current held over each second), itself checked against scipy's ODE solver.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_helpers import hypa_run
from data_helpers import user_dataset, user_project

OCV = (3.1, 0.9, 0.12, 7.0, 0.15)  # OCV(s) = a + b s + c tanh(k (s - s0)) [V]
TRUE = {"capacity_ah": 2.3, "r0": 0.045, "r1": 0.02, "c1": 1500.0}

CELL = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace

OCV = {ocv}


class Cell(LTIModel):
    """SOC and an RC pair; v = OCV(SOC) - v1 - R0 I, the OCV a nonlinear output."""

    state_names = ("soc", "v1")
    input_names = ("current",)
    output_names = ("voltage",)
    parameters = (ParameterSpec("capacity", "2.0 Ah", "C"), ParameterSpec("r0", "30 mOhm", "ohm"),
                  ParameterSpec("r1", 0.02, "ohm"), ParameterSpec("c1", "1.5 kF", "F"))

    def matrices(self, p):
        q, r0, r1, c1 = p["capacity"], p["r0"], p["r1"], p["c1"]
        z, one = torch.zeros_like(q), torch.ones_like(q)
        a = torch.stack([torch.stack([z, z]), torch.stack([z, -1 / (r1 * c1)])])
        b = torch.stack([-1 / q, 1 / c1]).reshape(2, 1)
        return StateSpace(a, b, torch.stack([z, -one]).reshape(1, 2), (-r0).reshape(1, 1))

    def output_nonlinearity(self, x, u, p):
        a, b, c, k, s0 = OCV
        s = x[..., 0:1]
        return a + b * s + c * torch.tanh(k * (s - s0))


class OcvLeak(LTIModel):
    """The OCV a state that leaks (self-discharge over a day), started steady: where nothing says its level."""

    state_names = ("ocv", "v1")
    input_names = ("current",)
    output_names = ("voltage",)
    parameters = (ParameterSpec("slope_capacitance", "10 kF", "F"), ParameterSpec("r0", "30 mOhm", "ohm"),
                  ParameterSpec("r1", 0.02, "ohm"), ParameterSpec("c1", "1.5 kF", "F"),
                  ParameterSpec("leak_s", "1 day", "s"))

    def matrices(self, p):
        cb, r0, r1, c1, leak = p["slope_capacitance"], p["r0"], p["r1"], p["c1"], p["leak_s"]
        z, one = torch.zeros_like(cb), torch.ones_like(cb)
        a = torch.stack([torch.stack([-1 / leak, z]), torch.stack([z, -1 / (r1 * c1)])])
        b = torch.stack([-1 / cb, 1 / c1]).reshape(2, 1)
        return StateSpace(a, b, torch.stack([one, -one]).reshape(1, 2), (-r0).reshape(1, 1))


class OcvState(LTIModel):
    """The natural linear model: the OCV a state (its slope a capacitance), read through y = C x + D u."""

    state_names = ("ocv", "v1")
    input_names = ("current",)
    output_names = ("voltage",)
    parameters = (ParameterSpec("slope_capacitance", "10 kF", "F"), ParameterSpec("r0", "30 mOhm", "ohm"),
                  ParameterSpec("r1", 0.02, "ohm"), ParameterSpec("c1", "1.5 kF", "F"))

    def matrices(self, p):
        cb, r0, r1, c1 = p["slope_capacitance"], p["r0"], p["r1"], p["c1"]
        z, one = torch.zeros_like(cb), torch.ones_like(cb)
        a = torch.stack([torch.stack([z, z]), torch.stack([z, -1 / (r1 * c1)])])
        b = torch.stack([-1 / cb, 1 / c1]).reshape(2, 1)
        return StateSpace(a, b, torch.stack([one, -one]).reshape(1, 2), (-r0).reshape(1, 1))
'''.replace("{ocv}", repr(OCV))

MODEL = """# @package model
name: {name}
blocks:
  cell:
    kind: physics
    system: cellmodel:{system}
    inputs: [current]
    outputs: [voltage]
    initial_state: {start}
    trainable: [capacity, r0, r1]
outputs: [voltage]
parameters: {{capacity: 2.0 Ah, r0: 30 mOhm, r1: {{value: 25, unit: mOhm}}, c1: 1.5 kF}}
stages: []
"""


def ocv(s: np.ndarray) -> np.ndarray:
    a, b, c, k, s0 = OCV
    return a + b * s + c * np.tanh(k * (s - s0))


def drive_cycle(samples: int, rng: np.random.Generator) -> np.ndarray:
    """1 Hz current [A], positive discharging: a rest of 30 s, then pulses of 5-40 s at -3..5 A, rests between."""
    current, k = np.zeros(samples), 30
    while k < samples:
        length = int(rng.integers(5, 40))
        current[k : k + length] = 0.0 if rng.random() < 0.3 else rng.uniform(-3.0, 5.0)
        k += length
    return current


def cell_truth(current: np.ndarray, soc0: float, v10: float, capacity_ah: float, r0: float, r1: float, c1: float,
               dt: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The exact sampled cell under a held current: voltage (T,) and states (T, 2)."""
    q, decay = capacity_ah * 3600.0, math.exp(-dt / (r1 * c1))
    x = np.empty((len(current), 2))
    x[0] = soc0, v10
    for k in range(len(current) - 1):
        x[k + 1, 0] = x[k, 0] - current[k] * dt / q
        x[k + 1, 1] = decay * x[k, 1] + r1 * (1 - decay) * current[k]
    return ocv(x[:, 0]) - x[:, 1] - r0 * current, x


@pytest.fixture
def cell_module(tmp_path, monkeypatch):
    (tmp_path / "cellmodel.py").write_text(CELL)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield __import__("cellmodel")
    sys.modules.pop("cellmodel", None)


def test_the_reference_recursion_is_the_ode() -> None:
    """The recursion the tests compare with is the cell's ODE under a held current (scipy, rtol 1e-11)."""
    from scipy.integrate import solve_ivp

    current = drive_cycle(300, np.random.default_rng(3))
    q, r1, c1 = TRUE["capacity_ah"] * 3600, TRUE["r1"], TRUE["c1"]
    _, x = cell_truth(current, 0.7, 0.01, TRUE["capacity_ah"], TRUE["r0"], r1, c1)
    state = np.array([0.7, 0.01])
    for k in range(len(current) - 1):
        i = float(current[k])
        state = solve_ivp(lambda t, s, i=i: [-i / q, -s[1] / (r1 * c1) + i / c1], (0, 1), state,
                          rtol=1e-11, atol=1e-13).y[:, -1]
        assert np.allclose(state, x[k + 1], rtol=0, atol=1e-10)


def test_the_cell_with_its_ocv_in_the_output_simulates_exactly(cell_module) -> None:
    """(a) The block's free run from the true state and a composed model's from an estimated one
    (through the nonlinear output's Gauss-Newton refinement) against the exact sampled cell."""
    from hypa.models.composed import ComposedModel
    from hypa.models.spec import parse_model_spec
    from hypa.physics import LTIBlock, PhysicalParameters, Scaling, check_system

    cell = cell_module.Cell()
    check_system(cell)
    assert cell.has_nonlinear_output and not cell.is_nonlinear
    assert cell.nominal_values()["capacity"] == pytest.approx(7200.0)  # 2.0 Ah in C
    assert cell.nominal_values()["r0"] == pytest.approx(0.03) and cell.nominal_values()["c1"] == 1500.0
    values = {"capacity": TRUE["capacity_ah"] * 3600, "r0": TRUE["r0"], "r1": TRUE["r1"], "c1": TRUE["c1"]}
    current = drive_cycle(1500, np.random.default_rng(0))
    voltage, _ = cell_truth(current, 0.85, 0.01, **TRUE)
    scaling = Scaling(torch.tensor([0.5, 0.0]), torch.tensor([0.1, 0.05]), torch.tensor([1.0]),
                      torch.tensor([2.0]), torch.tensor([3.5]), torch.tensor([0.2]))
    for hold in ("zoh",):
        block = LTIBlock(cell, PhysicalParameters(cell.parameter_specs(values)), dt=1.0, horizon=64, hold=hold,
                         scaling=scaling)
        assert block.feedthrough and block.extra_inputs == 1
        x0 = torch.tensor([[0.85, 0.01]], dtype=torch.float64)
        simulated = block.simulate_physical(x0, torch.tensor(current)[None, :, None])[0, :, 0].numpy()
        np.testing.assert_allclose(simulated, voltage[1:], rtol=0, atol=1e-11)
    spec = parse_model_spec({"name": "cell", "parameters": {k: float(v) for k, v in values.items()},
                             "blocks": {"cell": {"kind": "physics", "system": "cellmodel:Cell", "inputs": ["current"],
                                                 "outputs": ["voltage"], "initial_state": "estimate"}},
                             "outputs": ["voltage"]})
    scale_u, scale_y = (float(current.mean()), float(current.std())), (float(voltage.mean()), float(voltage.std()))
    model = ComposedModel(spec, None, ["current"], ["voltage"], {"current": scale_u}, {"voltage": scale_y}, 1.0, 64)
    states = model.blocks["cell"]
    assert 0.3 < float(states.state_mean[0]) < 1.0  # the SOC's operating point is where the OCV meets the data
    past = model.suggested_past()
    u = torch.tensor((current - scale_u[0]) / scale_u[1])[None, :, None]
    y = torch.tensor((voltage - scale_y[0]) / scale_y[1])[None, : past + 1, None]
    with torch.no_grad():
        for dtype, atol in ((torch.float64, 1e-4), (torch.float32, 2e-4)):
            predicted = model.to(dtype)(u.to(dtype), y.to(dtype))[0, :, 0].double().numpy() * scale_y[1] + scale_y[0]
            np.testing.assert_allclose(predicted, voltage[past + 1 :], rtol=0, atol=atol)


def test_a_nonlinear_output_is_checked_and_exported(cell_module) -> None:
    """The contract checks the output hook (shape, batch, finiteness); the linear state-space export
    refuses a nonlinear output in one line; the one-step form adds h."""
    from hypa.export import ModelStep
    from hypa.export.statespace import refusal
    from hypa.physics import LTIModel, SystemContractError, check_system
    from hypa.physics.curved import Curved

    class Bad(cell_module.Cell):
        def output_nonlinearity(self, x, u, p):
            return x[..., :2]  # two outputs for one

    class NotBatched(cell_module.Cell):
        def output_nonlinearity(self, x, u, p):
            return torch.stack([x[0]])  # x[0] is the first sample of a batch, not the SOC

    with pytest.raises(SystemContractError, match=r"must return h of shape \(1,\) \(outputs\), got \(2,\)"):
        check_system(Bad())
    with pytest.raises(SystemContractError, match="elementwise in the leading dims"):
        check_system(NotBatched())
    assert not LTIModel.has_nonlinear_output.fget(cell_module.OcvState())
    curved = Curved(cell_module.Cell(), {"v1": 3}, "cell")  # a wrapper measures through its base's h
    check_system(curved)
    assert curved.has_nonlinear_output and curved.is_nonlinear
    x, u = torch.tensor([0.5, 0.0], dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
    assert torch.equal(curved.output_nonlinearity(x, u, {}), cell_module.Cell().output_nonlinearity(x, u, {}))
    model, current, voltage, past = _composed_cell()
    why = refusal(model)
    assert why is not None and "block 'cell' has a nonlinear output" in why and "\n" not in why
    step = ModelStep(model.float())
    u = torch.tensor((current - current.mean()) / current.std(), dtype=torch.float32)[None, :, None]
    y = torch.tensor((voltage - voltage.mean()) / voltage.std(), dtype=torch.float32)[None, : past + 1, None]
    state = step.initial_state(u, y, u[..., :0])
    with torch.no_grad():
        free = model(u, y)[0, :, 0].double().numpy() * voltage.std() + voltage.mean()
        stepped = []
        for k in range(past + 1, past + 200):
            state, out = step(state, torch.tensor([current[k]], dtype=torch.float32))
            stepped.append(float(out[0]))
    np.testing.assert_allclose(stepped, free[: len(stepped)], rtol=0, atol=2e-4)  # float32 steps vs the free run


def _composed_cell() -> tuple:
    """A composed model of the true cell (estimated start) on a drive cycle: model, current, voltage, past."""
    from hypa.models.composed import ComposedModel
    from hypa.models.spec import parse_model_spec

    values = {"capacity": TRUE["capacity_ah"] * 3600, "r0": TRUE["r0"], "r1": TRUE["r1"], "c1": TRUE["c1"]}
    current = drive_cycle(600, np.random.default_rng(5))
    voltage, _ = cell_truth(current, 0.8, 0.0, **TRUE)
    spec = parse_model_spec({"name": "cell", "parameters": values, "outputs": ["voltage"],
                             "blocks": {"cell": {"kind": "physics", "system": "cellmodel:Cell", "inputs": ["current"],
                                                 "outputs": ["voltage"], "initial_state": "estimate"}}})
    model = ComposedModel(spec, None, ["current"], ["voltage"], {"current": (current.mean(), current.std())},
                          {"voltage": (voltage.mean(), voltage.std())}, 1.0, 64)
    return model, current, voltage, model.suggested_past()


def _write_cell_project(folder: Path, seed: int, offset: float = 0.0, records: tuple[int, ...] = (2400, 1200),
                        soc: tuple[float, float] = (0.8, 0.95)) -> Path:
    """A user's project: cellmodel.py, conf/dataset/cell.yaml, conf/model/{cell,ocv_state}.yaml and
    train/val records of the true cell (1 mV noise, ``offset`` added by the voltage sensor)."""
    dataset = user_dataset({"time": {"column": "time", "unit": "s"}, "sample_rate_hz": 1.0, "rate_hz": None,
                            "channels": {"current": {"role": "input", "unit": "A"},
                                         "voltage": {"role": "output", "unit": "V"}},
                            "splits": None, "select": [], "window": 60, "past": None, "stride": 20,
                            "eval_stride": 60, "batch_size": 16, "num_workers": 0, "seed": 0})
    models = {"cell": MODEL.format(name="cell", system="Cell", start="estimate"),
              "ocv_state": MODEL.format(name="ocv_state", system="OcvState", start="estimate")
              .replace("capacity, r0, r1", "r0, r1").replace("capacity: 2.0 Ah", "slope_capacitance: 10 kF")}
    folder.mkdir(parents=True, exist_ok=True)
    models["cell_true"] = models["cell"].replace("name: cell", "name: cell_true").replace(
        "{capacity: 2.0 Ah, r0: 30 mOhm, r1: {value: 25, unit: mOhm}, c1: 1.5 kF}",
        f"{{capacity: {TRUE['capacity_ah']} Ah, r0: {TRUE['r0'] * 1e3} mOhm, r1: {TRUE['r1']}, c1: {TRUE['c1']}}}")
    steady = "steady\n    scale_as: [voltage]"
    models["ocv_leak"] = models["ocv_state"].replace("OcvState", "OcvLeak").replace("estimate", steady) \
        .replace("name: ocv_state", "name: ocv_leak")
    user = user_project(folder, "cellmodel", CELL, "cell", dataset, models)
    rng = np.random.default_rng(seed)
    for name, samples in zip(("train", "val"), records):
        current = drive_cycle(samples, rng)
        voltage, _ = cell_truth(current, rng.uniform(*soc), 0.0, **TRUE)
        voltage = voltage + offset + 1e-3 * rng.standard_normal(samples)
        table = np.column_stack([np.arange(samples, dtype=float), current, voltage])
        np.savetxt(user / "data" / f"{name}.csv", table, delimiter=",", header="time,current,voltage", comments="")
    return user


def _run(args: list[str], user: Path, timeout: int = 600) -> subprocess.CompletedProcess:
    return hypa_run([*args[0].split()[1:], "--config-dir", str(user / "conf"), "dataset=cell",
                     f"data.dir={user / 'data'}", *args[1:]], env={**os.environ, "PYTHONPATH": str(user)})


@pytest.mark.slow
def test_train_identifies_capacity_and_resistance_written_in_ah_and_mohm(tmp_path: Path) -> None:
    """(b) hypa train through the CLI: the identification finds the capacity (2.3 Ah, nominal 2.0 Ah)
    and R0 (45 mOhm, nominal 30 mOhm) through the nonlinear output; hypa evaluate scores the run."""
    user = _write_cell_project(tmp_path / "user", seed=1)
    run = tmp_path / "run"
    result = _run(["hypa train", "model=cell", "trainer.max_epochs=1", "trainer.enable_progress_bar=false",
                   f"hydra.run.dir={run}"], user)
    assert result.returncode == 0, result.stderr[-3000:]
    sys.path.insert(0, str(user))
    try:
        from hypa.evaluation.runs import load_run

        fitted = load_run(run, trust=["cellmodel"]).module.model.parameters_.as_floats()
    finally:
        sys.path.remove(str(user))
        sys.modules.pop("cellmodel", None)
    assert fitted["capacity"] / 3600 == pytest.approx(TRUE["capacity_ah"], rel=0.01)
    assert fitted["r0"] == pytest.approx(TRUE["r0"], rel=0.02)
    evaluated = hypa_run(["evaluate", f"run={run}", f"out={tmp_path / 'eval'}", "trust=[cellmodel]",
                          "tensorboard=false", f"hydra.run.dir={tmp_path / 'hydra'}"],
                         env={**os.environ, "PYTHONPATH": str(user)})
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert metrics["splits"]["val"]["free_run"]["all"]["voltage"]["r2"] > 0.99


def test_a_unit_of_another_kind_is_refused_in_one_line(tmp_path: Path) -> None:
    from hypa.models.building import collect_parameters
    from hypa.models.spec import ModelSpecError, parse_model_spec, spec_config

    (tmp_path / "cellmodel.py").write_text(CELL)
    sys.path.insert(0, str(tmp_path))
    try:
        config = {"name": "cell", "outputs": ["voltage"], "parameters": {"capacity": "2.5 V"},
                  "blocks": {"cell": {"kind": "physics", "system": "cellmodel:Cell", "inputs": ["current"],
                                      "outputs": ["voltage"]}}}
        with pytest.raises(ModelSpecError, match=r"capacity: 2.5 V is not a charge \(the class declares C\)$"):
            collect_parameters(parse_model_spec(config), {})
        config["parameters"] = {"capacity": "2.5 foo"}
        with pytest.raises(ModelSpecError, match=r"parameters\.capacity: unknown unit 'foo'"):
            parse_model_spec(config)
        config["parameters"] = {"capacity": "2.5 Ah", "r0": {"value": 45, "unit": "mOhm"}, "r1": 0.03}
        spec = parse_model_spec(config)
        params, *_ = collect_parameters(spec, {})
        assert params.as_floats()["capacity"] == pytest.approx(9000.0)
        assert params.as_floats()["r0"] == pytest.approx(0.045) and params.as_floats()["r1"] == pytest.approx(0.03)
        assert spec_config(spec)["parameters"] == {"capacity": "2.5 Ah", "r0": "45 mOhm", "r1": 0.03}  # as given
        assert parse_model_spec(spec_config(spec)).parameters == spec.parameters
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("cellmodel", None)


def test_a_free_run_at_zero_volts_is_flagged_in_one_line(tmp_path: Path) -> None:
    """(c) The OCV as a leaking state started steady sits at 0 V while the cell sits near 3.9 V: hypa simulate
    says so in one line naming the output and the state (the cell with its OCV read through the nonlinear
    output, started from the estimate, simulates at the data's level: test (a))."""
    user = _write_cell_project(tmp_path / "user", seed=2, records=(300, 900))
    flagged = _run(["hypa simulate", "model=ocv_leak", "plot=false", f"hydra.run.dir={tmp_path / 'leak'}"], user)
    assert flagged.returncode == 0, flagged.stderr[-3000:]
    lines = [line for line in flagged.stdout.splitlines() if line.startswith("warning: the free run")]
    assert len(lines) == 1, flagged.stdout[-2000:]
    level = re.search(r"'voltage' sits at (\S+) V while the data sit at (\S+) V", lines[0])
    assert level and abs(float(level[1])) < 0.5 and 3.5 < float(level[2]) < 4.2, lines[0]
    assert lines[0].endswith("a state that no data initialize (ocv?) or an output offset")
    # the diagnosis says the same before it names anything
    diagnosed = _run(["hypa diagnose", "model=ocv_leak", "plot=false", "diagnosis.max_causes=0",
                      f"hydra.run.dir={tmp_path / 'diagnosis'}"], user)
    assert diagnosed.returncode == 0, diagnosed.stderr[-3000:]
    warned = [line.strip() for line in diagnosed.stdout.splitlines() if "warning: the free run" in line]
    assert warned == [lines[0]], diagnosed.stdout[-2000:]
    # ... and so does hypa evaluate of a run trained from it (one epoch: its values stay where they are)
    trained = _run(["hypa train", "model=ocv_leak", "trainer.max_epochs=1",
                    f"hydra.run.dir={tmp_path / 'run'}"], user)
    assert trained.returncode == 0, trained.stderr[-3000:]
    evaluated = hypa_run(["evaluate", f"run={tmp_path / 'run'}", f"hydra.run.dir={tmp_path / 'hydra'}",
                          "tensorboard=false", "trust=[cellmodel:OcvLeak]"],
                         env={**os.environ, "PYTHONPATH": str(user)})
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    flags = [line for line in evaluated.stdout.splitlines() if line.startswith("warning: the free run of 'voltage'")]
    assert len(flags) == 1 and flags[0].endswith("or an output offset"), evaluated.stdout[-2000:]
    assert "**Warning:** the free run of 'voltage'" in (tmp_path / "run" / "evaluation" / "summary.md").read_text()


def test_the_level_check_reads_the_datas_own_spread() -> None:
    """The threshold is the data's (or the run's) spread times LEVEL_SPREADS, whatever the signal's size."""
    from hypa.models.rollout import LEVEL_SPREADS, Prediction, free_run_levels

    rng = np.random.default_rng(0)
    for level, spread in ((3.7, 0.1), (1e-3, 1e-5), (5e4, 2e3)):
        data = level + spread * rng.standard_normal(500)
        for shift, flagged in ((0.5 * LEVEL_SPREADS, False), (2 * LEVEL_SPREADS, True)):
            run = Prediction("r", np.arange(500.0), {"y": data}, {"y": data + shift * spread}, {}, first=1)
            assert bool(free_run_levels([run], ["y"], units={"y": "V"})) is flagged
    off = Prediction("r", np.arange(500.0), {"y": data}, {"y": 0 * data}, {}, first=1)
    line = free_run_levels([off], ["y"], units={"y": "V"})[0]
    assert line.startswith("the free run of 'y' sits at 0 V while the data sit at 5") and "(25 spreads away)" in line


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12])
def test_the_diagnosis_runs_on_the_nonlinear_output_and_tries_an_output_offset(tmp_path: Path, seed: int) -> None:
    """(d) hypa diagnose through the CLI on the cell with its OCV in the output and a voltage sensor
    offset it does not know (20-60 mV, either sign): the search runs end to end through the nonlinear
    output (every candidate keeps h: the wrappers read it through ``base``) and fits the output offset.

    Naming it is expected to fail for now: the initial state estimated from the past absorbs a
    constant offset into the state of charge (OCV(s) + b ≈ OCV(s + b / OCV'(s)) over a fit window), so
    the fitted offset stays near 0; only the OCV's curvature over a long free run tells them apart."""
    rng = np.random.default_rng(seed)
    offset = float(rng.uniform(0.02, 0.06) * rng.choice([-1.0, 1.0]))
    user = _write_cell_project(tmp_path / "user", seed=seed, offset=offset, records=(1500, 900), soc=(0.15, 0.35))
    result = _run(["hypa diagnose", "model=cell_true", f"hydra.run.dir={tmp_path / 'diag'}"], user, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    diagnosis = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    tried = {(c["cause"], c["target"]): c for c in diagnosis["candidates"]}
    assert ("output_offset", "voltage") in tried and tried["output_offset", "voltage"]["score"] is not None
    named = {(c["cause"], c["target"]): c for c in diagnosis["named"]}
    if ("output_offset", "voltage") not in named:
        pytest.xfail(f"an output offset of {offset * 1e3:.0f} mV is absorbed by the estimated state of charge")
    assert named["output_offset", "voltage"]["values"]["voltage"] == pytest.approx(offset, rel=0.2)
