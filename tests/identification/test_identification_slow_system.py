"""Identification at another time scale, on a system hypa has never seen: a user's heated body
sampled every 5 s (time constant about 80 min, records of 3 h), with a nonlinear (quadratic) heat
loss. Its data come from scipy's ODE solver, not from hypa's engine. Through the commands a user
types: the nonlinear model, started 30 % off, recovers the truth; its linearisation, identified the
same way, is clearly worse on the validation record."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from conftest import ROOT
from data_helpers import user_dataset, user_project

DT = 5.0  # [s]
AMBIENT = 293.15  # [K]
TRUE = {"capacity": 6.0e4, "conductance": 12.0, "quadratic_loss": 0.08}  # J/K, W/K, W/K^2

SYSTEM = f'''
"""A heated body: C dT/dt = P - G (T - Ta) - h (T - Ta)^2, T the measured temperature [K]."""
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace

AMBIENT = {AMBIENT}


class HeatedBody(LTIModel):
    state_names = ("temperature",)
    input_names = ("power",)
    output_names = ("temperature",)
    parameters = (ParameterSpec("capacity", 6.0e4, "J/K"), ParameterSpec("conductance", 12.0, "W/K"),
                  ParameterSpec("quadratic_loss", 0.08, "W/K^2"))

    def matrices(self, p):
        c, g = p["capacity"], p["conductance"]
        return StateSpace((-g / c).reshape(1, 1), (1.0 / c).reshape(1, 1), torch.ones_like(c).reshape(1, 1),
                          torch.zeros_like(c).reshape(1, 1), (g * AMBIENT / c).reshape(1))


class HeatedBodyNonlinear(HeatedBody):
    def feedback(self, p):
        return (1.0 / p["capacity"]).reshape(1, 1)

    def nonlinearity(self, x, u, p):
        return -p["quadratic_loss"] * (x - AMBIENT) ** 2
'''

DATASET = user_dataset({
    "time": {"column": "time", "unit": "s"}, "sample_rate_hz": 0.2, "rate_hz": None,
    "channels": {"power": {"role": "input", "unit": "W"}, "temperature": {"role": "output", "unit": "K"}},
    "splits": None, "select": [], "window": 60, "past": 0, "stride": 10, "eval_stride": 30, "batch_size": 16,
    "num_workers": 0, "seed": 0})

MODEL = """# @package model
name: {name}
blocks:
  body:
    kind: physics
    system: heated_body:{system}
    inputs: [power]
    outputs: [temperature]
    initial_state: estimate
    trainable: {trainable}
parameters: {parameters}
outputs: [temperature]
stages: []
"""


def simulate(hours: float, seed: int) -> dict[str, np.ndarray]:
    """The truth by scipy's solver, the heater power held over each sample; 0.05 K sensor noise."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 / DT)
    power = np.repeat(rng.uniform(0, 1500, size=n // 120 + 1), 120)[:n]  # a new power every 10 min
    c, g, h = TRUE["capacity"], TRUE["conductance"], TRUE["quadratic_loss"]
    temperature = np.empty(n)
    temperature[0] = AMBIENT
    for k in range(n - 1):
        step = solve_ivp(lambda t, x: [(power[k] - g * (x[0] - AMBIENT) - h * (x[0] - AMBIENT) ** 2) / c],  # noqa: B023 -- solve_ivp calls it now
                         (0.0, DT), [temperature[k]], rtol=1e-10, atol=1e-10)
        temperature[k + 1] = step.y[0, -1]
    return {"time": np.arange(n) * DT, "power": power, "temperature": temperature + 0.05 * rng.standard_normal(n)}


@pytest.fixture(scope="module")
def user(tmp_path_factory) -> Path:
    off = {name: 0.7 * value for name, value in TRUE.items()}
    models = {"heated_nonlinear": ("HeatedBodyNonlinear", list(TRUE), off),
              "heated_linear": ("HeatedBody", ["capacity", "conductance"],
                                {"capacity": off["capacity"], "conductance": off["conductance"]})}
    texts = {name: MODEL.format(name=name, system=system, trainable=trainable, parameters=json.dumps(parameters))
             for name, (system, trainable, parameters) in models.items()}
    folder = user_project(tmp_path_factory.mktemp("slow"), "heated_body", SYSTEM, "heated", DATASET, texts)
    data = folder / "data"
    for split, seed in (("train", 0), ("val", 1)):
        columns = simulate(3.0, seed)
        rows = np.column_stack([columns[k] for k in ("time", "power", "temperature")])
        np.savetxt(data / f"{split}.csv", rows, fmt="%.17g", delimiter=",", header="time,power,temperature",
                   comments="")
    return folder


def train(user: Path, model: str, run: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(user)}
    command = [sys.executable, "-m", "hypa", "train", "--config-dir", str(user / "conf"), "dataset=heated",
               f"model={model}", f"data.dir={user / 'data'}", "trainer.enable_progress_bar=false",
               "figures.enabled=false", f"hydra.run.dir={run}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600, env=env, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "after identification" in result.stdout
    evaluated = subprocess.run([sys.executable, "-m", "hypa", "evaluate", f"run={run}", f"out={run / 'eval'}",
                                "trust=[heated_body]",
                                "tensorboard=false", f"hydra.run.dir={run / 'hydra-eval'}"],
                               cwd=ROOT, capture_output=True, text=True, timeout=300, env=env, check=False)
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    return {"run": json.loads((run / "run.json").read_text()),
            "metrics": json.loads((run / "eval" / "metrics.json").read_text())}


@pytest.mark.slow  # 40 s; nonlinear identification through hypa train: test_identification's in make test
def test_a_slow_nonlinear_system_is_identified_and_beats_its_linearisation(user: Path, tmp_path: Path) -> None:
    nonlinear = train(user, "heated_nonlinear", tmp_path / "nonlinear")
    identified = nonlinear["run"]["identification"]
    assert identified["converged"], identified["message"]
    for name, value in TRUE.items():
        assert identified["parameters"][name]["value"] == pytest.approx(value, rel=0.03), (name, identified)
        assert identified["parameters"][name]["std"] < 0.05 * value
    linear = train(user, "heated_linear", tmp_path / "linear")
    rmse = {name: r["metrics"]["splits"]["val"]["free_run"]["all"]["temperature"]["mse"] ** 0.5
            for name, r in (("nonlinear", nonlinear), ("linear", linear))}
    assert rmse["nonlinear"] < 0.1  # [K]: the sensor noise is 0.05 K
    assert rmse["linear"] > 5 * rmse["nonlinear"], rmse
