"""Table 1 metrics against hand-computed values, and the floored MAPE near zero crossings."""

import numpy as np
import pytest
import torch
from torchmetrics.functional import mean_absolute_percentage_error

from hypa.evaluation.metrics import METRICS, floored_mape, regression_metrics, state_metrics


def test_regression_metrics_hand_computed():
    target = np.array([3.0, -4.0, 0.0, 0.0])
    pred = np.array([2.0, -4.0, 0.5, -0.25])
    # errors e = pred - target = [-1, 0, 0.5, -0.25]
    # MAE = (1 + 0 + 0.5 + 0.25) / 4 = 0.4375
    # MSE = (1 + 0 + 0.25 + 0.0625) / 4 = 0.328125
    # RMS(target) = sqrt((9 + 16) / 4) = 2.5, so δ = 0.25 and the denominators are [3, 4, 0.25, 0.25]
    # MAPE = 100 (1/3 + 0 + 0.5/0.25 + 0.25/0.25) / 4 = 100 (10/3) / 4 = 83.333... %
    # mean(target) = -0.25; SS_tot = 3.25² + 3.75² + 2 · 0.25² = 24.75; SS_res = 4 · MSE = 1.3125
    # R² = 1 - 1.3125 / 24.75 = 0.946969...
    m = regression_metrics(pred, target)
    assert tuple(m) == METRICS
    assert m["mae"] == pytest.approx(0.4375, abs=1e-12)
    assert m["mse"] == pytest.approx(0.328125, abs=1e-12)
    assert m["mape"] == pytest.approx(250.0 / 3.0, abs=1e-10)
    assert m["r2"] == pytest.approx(1.0 - 1.3125 / 24.75, abs=1e-12)


def test_r2_of_perfect_and_of_mean_prediction():
    target = np.sin(np.linspace(0.0, 7.0, 50)) + 0.3
    assert regression_metrics(target.copy(), target)["r2"] == pytest.approx(1.0, abs=1e-12)
    perfect = regression_metrics(target.copy(), target)
    assert perfect["mae"] == perfect["mse"] == perfect["mape"] == 0.0
    assert regression_metrics(np.full_like(target, target.mean()), target)["r2"] == pytest.approx(0.0, abs=1e-12)


def test_floored_mape_stays_bounded_at_a_zero_crossing():
    """A yaw rate crossing zero at a sample: plain MAPE explodes, the floored one does not."""
    t = np.linspace(-1.0, 1.0, 201)  # t = 0 is a sample: target exactly 0 there
    target = 0.2 * np.sin(np.pi * t) + 1e-9  # rad/s; the 1e-9 keeps plain MAPE finite
    pred = target + 0.004  # a constant 4 mrad/s offset: a good model
    plain = 100.0 * np.mean(np.abs(pred - target) / np.abs(target))
    # torchmetrics clamps |y| at 1.17e-6 only, which still lets the one sample dominate
    library = 100.0 * float(mean_absolute_percentage_error(torch.from_numpy(pred), torch.from_numpy(target)))
    floored = regression_metrics(pred, target)["mape"]
    delta = 0.1 * np.sqrt(np.mean(target**2))  # 0.1 · 0.2 / sqrt(2) ≈ 0.0141
    assert plain > 1e6  # the sample at y = 1e-9: 100 · 0.004 / 1e-9 / 201 ≈ 2e6 %
    assert library > 1e3
    assert floored <= 100.0 * 0.004 / delta + 1e-9  # MAPE_δ ≤ 100 · MAE / δ ≈ 28 %
    # away from the crossing it is the plain MAPE
    far = np.abs(target) > delta
    assert float(floored_mape(torch.from_numpy(pred[far]), torch.from_numpy(target[far]))) == pytest.approx(
        100.0 * np.mean(0.004 / np.abs(target[far])), rel=1e-12)


def test_state_metrics_overall_is_mean_over_states():
    rng = np.random.default_rng(0)
    target = np.stack([0.3 * np.sin(np.linspace(0, 9, 300)), 0.02 * np.cos(np.linspace(0, 5, 300))], axis=1)
    pred = target + rng.normal(scale=[0.01, 0.002], size=target.shape)
    result = state_metrics(pred, target, ["yaw_rate", "side_slip"])
    assert set(result) == {"yaw_rate", "side_slip", "overall"}
    assert result["side_slip"] == regression_metrics(pred[:, 1], target[:, 1])
    for m in METRICS:
        assert result["overall"][m] == pytest.approx((result["yaw_rate"][m] + result["side_slip"][m]) / 2)


@pytest.mark.parametrize(
    ("pred", "target", "match"),
    [
        (np.zeros(5), np.ones(4), "shapes differ"),
        (np.array([1.0, np.nan, 2.0]), np.array([1.0, 2.0, 3.0]), "pred has 1 non-finite"),
        (np.array([1.0, 2.0, 3.0]), np.array([1.0, np.inf, 3.0]), "target has 1 non-finite"),
        (np.zeros((3, 2)), np.zeros((3, 2)), "1-D"),
        (np.array([1.0, 2.0]), np.array([1.0, 1.0]), "constant"),
    ],
)
def test_regression_metrics_rejects_bad_inputs(pred, target, match):
    with pytest.raises(ValueError, match=match):
        regression_metrics(pred, target)


def test_state_metrics_rejects_bad_names():
    x = np.random.default_rng(1).normal(size=(10, 2))
    with pytest.raises(ValueError, match="state names"):
        state_metrics(x, x, ["yaw_rate"])
    with pytest.raises(ValueError, match="reserved"):
        state_metrics(x, x, ["yaw_rate", "overall"])
    with pytest.raises(ValueError, match="2-D"):
        state_metrics(x[:, 0], x[:, 0], ["yaw_rate"])
