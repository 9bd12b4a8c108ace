"""Metrics, once for all of hypa: the errors of a prediction against a measurement, and the paper's
Table 1 metrics.

Every command scores through these functions (the free runs, the benchmark, the simulation of a
physics model, the explanation, the diagnosis's recovered signals), so an R² or an RMSE means
the same thing in every report:

    RMSE = sqrt(mean (ŷ - y)²)                       [unit of y]
    R²   = 1 - Σ(ŷ - y)² / Σ(y - ȳ)²                 [-]  (1: perfect; 0: as good as ȳ)
    NRMSE = RMSE / σ(y)                              [-]  (so R² = 1 - NRMSE²)

``errors`` gives them (with the mean error) for one channel; ``rms`` and ``correlation`` are the
two plain statistics the reports also print. The arrays are in the channel's SI unit.

A figure over several seeds (the benchmark, the paper's Table 1) or logs (a fleet diagnosis) is
reported as ``mean_std``: mean ± the *sample* standard deviation (ddof = 1), the same everywhere.

The Table 1 metrics (``regression_metrics``, ``state_metrics``): all inputs are numpy arrays
in SI units (rad/s for the yaw rate, rad for the side slip), computed in float64 with the same
MSE and R² as ``errors`` (one formula for each in hypa; training logs its windows' R² with
torchmetrics' ``R2Score``, the same formula accumulated over the batches on the device).

MAPE is *floored* here, because the plain definition is useless for vehicle states:

    plain:    MAPE   = 100 % · mean_k |ŷ_k - y_k| / |y_k|
    floored:  MAPE_δ = 100 % · mean_k |ŷ_k - y_k| / max(|y_k|, δ),   δ = 0.1 · RMS(y)

The yaw rate and the side slip change sign at every steering reversal, so some samples sit
arbitrarily close to y = 0 and one of them can dominate the plain mean (|e| / 1e-9 ~ 1e7 %).
Flooring the denominator at 10 % of the channel's RMS keeps the familiar "percent of the
value" reading wherever the signal is large, while near a zero crossing the error is measured
against a typical signal level instead. It is bounded by MAPE_δ ≤ 100 % · MAE / δ. δ comes from
the target only, so every model on a record is divided by the same numbers.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

METRICS = ("mae", "mse", "mape", "r2")

# δ as a fraction of the target's RMS: small enough that MAPE_δ equals the plain MAPE on most
# samples of a sine-like signal (|sin| < 0.1·RMS on only ~4.5 % of a period).
MAPE_FLOOR_FRACTION = 0.1


def _checked(pred: np.ndarray, target: np.ndarray, ndim: int) -> tuple[np.ndarray, np.ndarray]:
    """Both arrays as float64, after checking shape, length and finiteness."""
    pred, target = np.asarray(pred, dtype=np.float64), np.asarray(target, dtype=np.float64)
    if pred.shape != target.shape:
        raise ValueError(f"pred and target shapes differ: {pred.shape} vs {target.shape}")
    if target.ndim != ndim:
        raise ValueError(f"expected {ndim}-D arrays (time first), got shape {target.shape}")
    if target.shape[0] < 2:
        raise ValueError(f"need at least 2 samples along time, got {target.shape[0]}")
    for name, array in (("pred", pred), ("target", target)):
        if not np.all(np.isfinite(array)):
            bad = int(np.size(array) - np.count_nonzero(np.isfinite(array)))
            raise ValueError(f"{name} has {bad} non-finite values (NaN or inf)")
    return pred, target


def rms(x: np.ndarray) -> float:
    """Root mean square of ``x`` (any shape) [unit of x]; NaN for an empty array."""
    x = np.asarray(x, dtype=np.float64)
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def errors(pred: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """``rmse``, ``mse``, ``mean_error`` (ŷ - y, mean) [SI], ``r2`` and ``nrmse`` of one channel.

    Over every sample: a non-finite prediction makes them NaN (a caller that scores a signal
    defined on part of the record masks it first, and says so). R² and NRMSE are NaN for a
    target without spread.
    """
    p, y = np.asarray(pred, dtype=np.float64).ravel(), np.asarray(target, dtype=np.float64).ravel()
    if p.shape != y.shape or not p.size:
        raise ValueError(f"pred and target need the same, non-zero size: {p.size} vs {y.size}")
    error = p - y
    mse, spread = float(np.mean(error**2)), float(np.var(y))
    return {"rmse": mse**0.5, "mse": mse, "mean_error": float(error.mean()),
            "r2": 1.0 - mse / spread if spread > 0 else float("nan"),
            "nrmse": (mse / spread) ** 0.5 if spread > 0 else float("nan")}


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's r of two signals over the samples where both are finite; NaN where either is constant."""
    a, b = np.asarray(a, dtype=np.float64).ravel(), np.asarray(b, dtype=np.float64).ravel()
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size < 2 or np.std(a) == 0 or np.std(b) == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


@dataclass(frozen=True)
class MeanStd:
    """One figure over ``count`` seeds (or logs, runs), in the figure's unit."""

    count: int
    mean: float
    std: float  # sample standard deviation (ddof = 1); 0.0 for one value
    min: float
    max: float


def mean_std(values: Iterable[float]) -> MeanStd:
    """Mean, sample standard deviation and range of one figure over seeds or logs.

        mean = Σ x_i / n        std = sqrt(Σ (x_i - mean)² / (n - 1))   (0.0 for n = 1)

    The sample standard deviation (ddof = 1) estimates the spread of the figure from seed to
    seed; the population one (ddof = 0) would understate it for the few seeds a report has
    (by sqrt((n-1)/n): 18 % for 3 seeds). A caller that reports something else for one value
    (``None``: no spread known) checks ``count``.

    A NaN (or inf) among the values is kept, never dropped: it makes mean, std, min and max NaN
    (``count`` still counts it), so a seed that failed shows in the report instead of vanishing
    from it. A value that is missing (``None``) is the caller's to drop, saying so; ``None`` here,
    or no values at all, raises (TypeError, ValueError).
    """
    x = np.array([float(v) for v in values], dtype=np.float64)
    if not x.size:
        raise ValueError("mean_std needs at least one value")
    if not np.all(np.isfinite(x)):
        return MeanStd(int(x.size), *[float("nan")] * 4)
    return MeanStd(int(x.size), float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else 0.0,
                   float(x.min()), float(x.max()))


def floored_mape(pred: np.ndarray, target: np.ndarray) -> float:
    """MAPE_δ in percent, δ = ``MAPE_FLOOR_FRACTION`` · RMS(target) (see the module docstring)."""
    pred, target = np.asarray(pred, dtype=np.float64), np.asarray(target, dtype=np.float64)
    delta = MAPE_FLOOR_FRACTION * rms(target)
    return float(100.0 * np.mean(np.abs(pred - target) / np.maximum(np.abs(target), delta)))


def regression_metrics(pred: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """MAE, MSE, floored MAPE [%] and R² of one channel, shape (T,), in the channel's SI unit.

        MAE = mean |ŷ - y|          [unit]
        MSE = mean (ŷ - y)²         [unit²]
        MAPE = MAPE_δ               [%]   (floored, see the module docstring)
        R²  = 1 - Σ(ŷ - y)² / Σ(y - ȳ)²   [-]   (1: perfect; 0: as good as predicting ȳ)

    MSE and R² are ``errors``'s. Raises ValueError for mismatched shapes, non-finite values, or a
    constant target (for which R² is undefined and δ can be 0).
    """
    p, y = _checked(pred, target, ndim=1)
    if np.all(y == y[0]):
        raise ValueError("target is constant: R² (and the MAPE floor) are undefined")
    scored = errors(p, y)
    return {"mae": float(np.mean(np.abs(p - y))), "mse": scored["mse"], "mape": floored_mape(p, y), "r2": scored["r2"]}


def state_metrics(pred: np.ndarray, target: np.ndarray, names: Sequence[str]) -> dict[str, dict[str, float]]:
    """Metrics per state of (T, p) arrays, plus ``"overall"``: each metric's mean over the states.

    Both vehicle states are in rad-based SI units (yaw rate rad/s, side slip rad) of similar
    size, so a plain mean over states is meaningful; the paper reports a single Table 1 row
    per model, which we read as this mean. (MAPE and R² are scale-free anyway.)
    """
    names = tuple(names)
    pred, target = np.asarray(pred), np.asarray(target)
    _checked(pred, target, ndim=2)
    if len(names) != target.shape[1] or len(set(names)) != len(names):
        raise ValueError(f"need {target.shape[1]} distinct state names for shape {target.shape}, got {names}")
    if "overall" in names:
        raise ValueError("'overall' is reserved for the mean over states")
    result = {name: regression_metrics(pred[:, i], target[:, i]) for i, name in enumerate(names)}
    result["overall"] = {m: float(np.mean([result[n][m] for n in names])) for m in METRICS}
    return result
