"""hypa.core.metrics: the errors every report uses; the Table 1 metrics against hand-computed values and
the floored MAPE near zero crossings."""

import numpy as np
import pytest
import torch
from torchmetrics.functional import mean_absolute_percentage_error

from hypa.core.metrics import METRICS, MeanStd, floored_mape, mean_std, regression_metrics, state_metrics


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


def test_errors_are_the_hand_computed_rmse_r2_and_nrmse():
    """hypa.core.metrics.errors: the one RMSE / R² / NRMSE every report uses, against the definitions."""
    from hypa.core.metrics import errors

    rng = np.random.default_rng(3)
    y = rng.normal(2.0, 0.5, 400)
    p = y + rng.normal(0.1, 0.2, 400)
    e = errors(p, y)
    rmse = np.sqrt(np.mean((p - y) ** 2))
    assert e["rmse"] == pytest.approx(rmse, rel=1e-12)
    assert e["mse"] == pytest.approx(rmse**2, rel=1e-12)
    assert e["mean_error"] == pytest.approx(np.mean(p - y), rel=1e-12)
    assert e["r2"] == pytest.approx(1 - np.sum((p - y) ** 2) / np.sum((y - y.mean()) ** 2), rel=1e-12)
    assert e["r2"] == pytest.approx(1 - e["nrmse"] ** 2, rel=1e-12)
    assert e["r2"] == pytest.approx(regression_metrics(p, y)["r2"], rel=1e-9)  # the same R² as Table 1's


def test_errors_never_drop_a_bad_prediction():
    """A non-finite prediction makes the figures NaN (never a score over the finite rest); a
    constant target has no R²; mismatched or empty arrays are refused."""
    from hypa.core.metrics import errors

    y = np.linspace(0.0, 1.0, 50)
    p = y.copy()
    p[7] = np.nan
    assert all(np.isnan(errors(p, y)[k]) for k in ("rmse", "r2", "nrmse"))
    flat = errors(np.ones(5), np.full(5, 2.0))
    assert flat["rmse"] == pytest.approx(1.0) and np.isnan(flat["r2"]) and np.isnan(flat["nrmse"])
    with pytest.raises(ValueError, match="same, non-zero size"):
        errors(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="same, non-zero size"):
        errors(np.ones(0), np.ones(0))


def test_rms_and_correlation():
    from hypa.core.metrics import correlation, rms

    assert rms(np.array([3.0, -4.0])) == pytest.approx(np.sqrt(12.5))
    assert np.isnan(rms(np.array([])))
    t = np.linspace(0, 6, 200)
    a, b = np.sin(t), 3 * np.sin(t) + 1
    b[5] = np.nan  # left out, with its partner
    assert correlation(a, b) == pytest.approx(1.0)
    assert correlation(a, -a) == pytest.approx(-1.0)
    assert np.isnan(correlation(a, np.ones_like(a)))


def test_mean_std_is_the_hand_computed_sample_std():
    # values 1, 2, 4: mean 7/3; deviations -4/3, -1/3, 5/3; Σ squares = (16 + 1 + 25) / 9 = 42/9
    # sample std = sqrt(42/9 / (3 - 1)) = sqrt(7/3) = 1.5275...; the population std would be sqrt(14/9) = 1.247...
    s = mean_std([1.0, 2.0, 4.0])
    assert s == MeanStd(count=3, mean=pytest.approx(7 / 3, abs=1e-15), std=pytest.approx((7 / 3) ** 0.5, abs=1e-15),
                        min=1.0, max=4.0)
    assert mean_std(iter([3.0, 5.0])).std == pytest.approx(2**0.5, abs=1e-15)  # any iterable: (1 + 1) / 1


def test_mean_std_of_one_value_has_no_spread():
    assert mean_std([0.25]) == MeanStd(count=1, mean=0.25, std=0.0, min=0.25, max=0.25)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_mean_std_keeps_a_failed_seed(bad):
    # a NaN (or inf) among the seeds is not dropped: every figure becomes NaN, the count still counts it
    s = mean_std([0.9, bad, 0.8])
    assert s.count == 3
    assert all(np.isnan(v) for v in (s.mean, s.std, s.min, s.max))
    assert np.isnan(mean_std([bad]).std)


def test_mean_std_refuses_nothing_and_missing_values():
    with pytest.raises(ValueError, match="at least one value"):
        mean_std([])
    with pytest.raises(TypeError):
        mean_std([1.0, None])
