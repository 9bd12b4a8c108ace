"""Step 1 numbers (residual analysis) and the diagnosis' fast model against hypa's physics."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hypa.data import HypaDataModule
from hypa.diagnosis.model import ModelSpec, ay_threshold, magic_formula, simulate_batch
from hypa.diagnosis.residuals import analyze_residuals, correlation
from hypa.vehicle import VehicleParameters
from hypa.simulate import simulate_vehicle
from hypa.testbench import TestbenchConfig, ensure_dataset

NOMINAL = VehicleParameters()
RECORDS = {"train_1": {"seed": 1, "stochastic_duration_s": 40.0},
           "train_2": {"seed": 2, "stochastic_duration_s": 40.0},
           "val": {"seed": 3, "stochastic_duration_s": 45.0, "break_frequency_hz": 0.8, "maneuvers": []}}


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("diagnosis-residuals")


def val_records(overrides: dict, cache: Path) -> tuple[list, float]:
    config = TestbenchConfig.linear(noise=True).merged({"records": RECORDS, **overrides})
    dm = HypaDataModule(ensure_dataset(config, cache))
    dm.setup()
    return dm.records("val"), dm.dt


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("rear", ["none", "fixed"])
def test_fast_linear_model_equals_hypa_physics(hold: str, rear: str) -> None:
    """The IIR-filter free run of the diagnosis is the LTIBlock free run of hypa.simulate."""
    rng = np.random.default_rng(0)
    swa = np.cumsum(rng.normal(0, 0.01, 300))
    x0 = np.array([0.05, -0.01])
    reference = simulate_vehicle(NOMINAL, swa[None], x0[None], 1 / 32, hold, rear)[0]
    spec = ModelSpec(NOMINAL, hold=hold, rear_ratio=NOMINAL.rws_ratio if rear == "fixed" else 0.0)
    np.testing.assert_allclose(simulate_batch([spec], swa, x0, 1 / 32)[0], reference, atol=1e-12)


def test_saturating_model_tends_to_the_linear_one() -> None:
    rng = np.random.default_rng(1)
    swa = np.cumsum(rng.normal(0, 0.01, 300))
    linear, huge, low = simulate_batch([ModelSpec(NOMINAL, hold="foh", mu=m) for m in (math.inf, 1e4, 0.5)],
                                       swa, np.zeros(2), 1 / 32)
    np.testing.assert_allclose(huge, linear, atol=1e-9)
    assert np.abs(low[:, 0]).max() < np.abs(linear[:, 0]).max()  # saturation lowers the peak yaw rate


def test_ay_threshold_is_where_the_axle_force_drops_five_percent() -> None:
    mu, load, stiffness = 0.9, 9000.0, 150000.0
    slip = np.linspace(1e-4, 0.2, 20001)
    ratio = magic_formula(slip, np.array(stiffness), np.array(mu * load)) / (stiffness * slip)
    first = slip[np.argmax(ratio < 0.95)]
    force_per_load = magic_formula(first, np.array(stiffness), np.array(mu * load)) / load
    assert ay_threshold(mu) == pytest.approx(9.81 * force_per_load, rel=1e-3)


def test_correlation_of_white_noise_stays_inside_the_band() -> None:
    rng = np.random.default_rng(2)
    x, lags = rng.normal(size=20000), np.arange(1, 65)
    rho = correlation(x, x, lags)
    assert np.mean(np.abs(rho) > 2.58 / np.sqrt(x.size)) < 0.05
    assert correlation(x, np.roll(x, 3), np.array([3]))[0] == pytest.approx(1.0, abs=1e-2)


def test_residuals_separate_clean_data_from_a_delay_and_from_saturation(cache: Path) -> None:
    records, dt = val_records({}, cache)
    clean = analyze_residuals(records, NOMINAL, dt, "foh")
    records, dt = val_records({"steering": {"delay_s": 0.08}}, cache)
    delayed = analyze_residuals(records, NOMINAL, dt, "foh")
    records, dt = val_records({"tires": {"enabled": True, "mu": 0.75}}, cache)
    saturated = analyze_residuals(records, NOMINAL, dt, "foh")

    assert clean.channels["yaw_rate"]["nrmse"] < 0.03
    assert delayed.channels["yaw_rate"]["nrmse"] > 10 * clean.channels["yaw_rate"]["nrmse"]
    # a dead time is phase, not gain: ~ -360° f d at the coherent frequencies
    assert abs(clean.phase_difference_deg) < 1.0 and abs(clean.gain_ratio - 1) < 0.02
    assert delayed.phase_difference_deg < -10.0 and abs(delayed.gain_ratio - 1) < 0.05
    assert delayed.cross_correlation["yaw_rate"].outside > clean.cross_correlation["yaw_rate"].outside
    # saturation: the error grows with |a_y|, a delay's does not (compare the low and high bins)
    low, high = saturated.ay_rmse["yaw_rate"][0], np.nanmax(saturated.ay_rmse["yaw_rate"][4:])
    assert high > 3 * low
    assert saturated.gain_ratio < 0.98
    assert clean.autocorrelation["yaw_rate"].bound == pytest.approx(2.58 / np.sqrt(sum(len(r) for r in records)))
