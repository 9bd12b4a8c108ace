"""How many past samples the measured outputs depend on, read from the data alone.

A network that starts from the measured outputs over the past (an ``ann`` block's
``initial_state``, the end-to-end LSTM's) has to see enough of them to tell the system's state;
with no physics beside it, only the data can say how many. The measure: the order L of the
linear predictor (ARX) of the next output,

    y_k ≈ Σ_{j=1..L} A_j y_{k-j} + Σ_{j=0..L} B_j u_{k-j} + c,

fitted by least squares on the training records (every channel scaled by its spread) for L = 1,
2, 4, ... and chosen by the Bayesian information criterion N ln σ² + k ln N (σ² the residual
variance of the N predicted values, k the coefficients): the past beyond which more samples
explain less than their number costs. A lightly damped 2-state circuit sampled at 40 kHz with
0.3 % noise gives 8; Silverbox (a weakly nonlinear 2-state oscillator at 610 Hz) 32.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hypa.data.records import Record

MAX_ROWS = 50_000  # predicted samples the fits use at most (evenly spread over the records)


@dataclass(frozen=True)
class Memory:
    """The chosen order ``samples`` and each tried order's criterion and residual variance (scaled units)."""

    samples: int
    criterion: dict[int, float]
    variance: dict[int, float]


def linear_memory(records: Sequence[Record], inputs: Sequence[str], outputs: Sequence[str], max_lag: int) -> Memory:
    """The ARX order (1, 2, 4, ... up to ``max_lag``) that the training ``records`` support (see the module).

    ``ValueError`` (one line) where the records are too short for even the first order."""
    if max_lag < 1:
        raise ValueError(f"max_lag must be at least 1, got {max_lag}")
    data = [(r.stack(inputs), r.stack(outputs)) for r in records if len(r) > 2]
    if not data:
        raise ValueError("no training record holds 3 samples: nothing tells how many past samples matter")
    u_all, y_all = np.concatenate([u for u, _ in data]), np.concatenate([y for _, y in data])
    u_mean, u_std = u_all.mean(0), _spread(u_all)
    y_mean, y_std = y_all.mean(0), _spread(y_all)
    scaled = [((u - u_mean) / u_std, (y - y_mean) / y_std) for u, y in data]
    criterion, variance = {}, {}
    lag = 1
    while lag <= max_lag:
        fit = _fit(scaled, lag)
        if fit is None:
            break
        variance[lag], rows, coefficients = fit
        criterion[lag] = rows * math.log(max(variance[lag], 1e-300)) + coefficients * math.log(rows)
        lag *= 2
    if not criterion:
        raise ValueError("the training records are too short for a predictor of the next output from one past sample")
    return Memory(min(criterion, key=criterion.get), criterion, variance)


def _spread(x: np.ndarray) -> np.ndarray:
    std = x.std(0)
    return np.where(std > 0, std, 1.0)  # a constant channel stays as it is (its coefficients are then 0)


def _fit(scaled: list[tuple[np.ndarray, np.ndarray]], lag: int) -> tuple[float, int, int] | None:
    """The residual variance of the order-``lag`` predictor, the values it predicts and its coefficients,
    or None where no record is long enough."""
    regressors, targets = [], []
    for u, y in scaled:
        n = len(y)
        if n <= lag + 1:
            continue
        past_y = [y[lag - j : n - j] for j in range(1, lag + 1)]
        past_u = [u[lag - j : n - j] for j in range(lag + 1)]
        regressors.append(np.concatenate([*past_y, *past_u, np.ones((n - lag, 1))], 1))
        targets.append(y[lag:])
    if not regressors:
        return None
    x, t = np.concatenate(regressors), np.concatenate(targets)
    if len(t) > MAX_ROWS:
        keep = np.linspace(0, len(t) - 1, MAX_ROWS).astype(int)
        x, t = x[keep], t[keep]
    if len(t) <= x.shape[1]:
        return None
    weights, *_ = np.linalg.lstsq(x, t, rcond=None)
    residual = t - x @ weights
    return float((residual**2).mean()), t.size, weights.size
