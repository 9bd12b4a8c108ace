"""End to end: test bench -> files -> DataModule -> nominal physics, in the library and the CLI."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hypa.data import HypaDataModule
from hypa.vehicle import VehicleParameters
from hypa.vehicle.simulation import fit_metrics, simulate_vehicle
from hypa.testbench import TestbenchConfig, ensure_dataset

ROOT = Path(__file__).resolve().parents[1]
SHORT = {"records": {
    "train_1": {"seed": 1, "stochastic_duration_s": 40.0, "break_frequency_hz": 1.0, "maneuvers": []},
    "train_2": {"seed": 2, "stochastic_duration_s": 40.0, "break_frequency_hz": 1.0, "maneuvers": []},
    "val": {"seed": 3, "stochastic_duration_s": 40.0, "break_frequency_hz": 0.8, "maneuvers": []},
}}


@pytest.fixture(scope="module")
def clean_data(tmp_path_factory) -> HypaDataModule:
    """Truth = the linear single-track model with fixed front steering and no rear steering."""
    config = TestbenchConfig.linear(noise=False).merged(SHORT)
    dm = HypaDataModule(ensure_dataset(config, tmp_path_factory.mktemp("cache")), batch_size=64)
    dm.setup()
    return dm


def test_nominal_physics_reproduces_clean_data_with_foh(clean_data: HypaDataModule) -> None:
    """With exact physics only the sampling assumption is left (the truth at 1024 Hz equals the
    linear model to 1e-11). At 32 Hz a first-order hold still misses the curvature of the input
    between samples (the excitation runs to 5 Hz): < 1.5 % NRMSE; ZOH's half-sample lag: ~10 %."""
    record = clean_data.records("val")[0]
    y = record.stack(("yaw_rate", "side_slip"))
    nrmse = {}
    for hold in ("zoh", "foh"):
        sim = simulate_vehicle(VehicleParameters(), record["steering_wheel_angle"][None], y[None, 0],
                               clean_data.dt, hold=hold, rear_steering="none")[0]
        nrmse[hold] = max(fit_metrics(y[:, i], sim[:, i])["nrmse"] for i in range(2))
    assert nrmse["foh"] < 0.015
    assert nrmse["zoh"] > 5 * nrmse["foh"]


def test_wrong_cornering_stiffness_is_visible(clean_data: HypaDataModule) -> None:
    record = clean_data.records("val")[0]
    y = record.stack(("yaw_rate", "side_slip"))
    wrong = VehicleParameters(cf=100000.0)
    sim = simulate_vehicle(wrong, record["steering_wheel_angle"][None], y[None, 0], clean_data.dt,
                           hold="foh", rear_steering="none")[0]
    assert fit_metrics(y[:, 0], sim[:, 0])["nrmse"] > 0.05


def test_windowed_and_free_run_agree_on_window_length() -> None:
    """A 100-step window from a state on the free-run trajectory continues that trajectory."""
    rng = np.random.default_rng(0)
    swa = np.cumsum(rng.normal(size=(1, 400)), axis=1) * 0.002
    free = simulate_vehicle(VehicleParameters(), swa, np.zeros((1, 2)), 1 / 32)
    window = simulate_vehicle(VehicleParameters(), swa[:, 150:251], free[:, 150], 1 / 32)
    np.testing.assert_allclose(window[0], free[0, 150:251], atol=1e-12)


def test_simulate_cli_on_short_testbench_data(tmp_path: Path) -> None:
    overrides = [f"testbench.records.{name}.stochastic_duration_s=30" for name in ("train_1", "train_2", "val")]
    env = {**os.environ, "HYPA_CACHE_DIR": str(tmp_path / "cache")}
    result = subprocess.run(
        [sys.executable, "-m", "hypa.simulate", f"hydra.run.dir={tmp_path / 'run'}", *overrides],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "free-run val" in result.stdout and "windowed (100 steps)" in result.stdout
    metrics = json.loads((tmp_path / "run" / "simulation.json").read_text())
    r2 = metrics["free-run val.parquet"]["yaw_rate"]["r2"]
    assert 0.5 < r2 < 1.0  # the default truth has effects the nominal physics lacks
    assert (tmp_path / "run" / "free_run_val.png").stat().st_size > 10_000


def test_simulate_cli_rejects_unstable_parameters(tmp_path: Path) -> None:
    overrides = [f"testbench.records.{name}.stochastic_duration_s=30" for name in ("train_1", "train_2", "val")]
    env = {**os.environ, "HYPA_CACHE_DIR": str(tmp_path / "cache")}
    result = subprocess.run(
        [sys.executable, "-m", "hypa.simulate", f"hydra.run.dir={tmp_path / 'run'}", "vehicle.cr=20000",
         "vehicle.velocity=60", *overrides],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )
    assert result.returncode != 0
    assert "unstable" in result.stderr
