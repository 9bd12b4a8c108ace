"""The past a network's start needs, read from the data (``hypa.data.memory.linear_memory``): the
order of the linear predictor of the next output, chosen by BIC, on systems whose order is known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hypa.data.memory import linear_memory
from hypa.data.records import Record


def record(u: np.ndarray, y: np.ndarray) -> Record:
    return Record(Path("memory.csv"), np.arange(len(u)) / 100.0, {"u": u, "y": y}, 100.0)


def simulate(a: list[float], b: dict[int, float], samples: int, seed: int, noise: float = 0.05) -> Record:
    """y_k = Σ a_j y_{k-j} + Σ b_d u_{k-d} + e_k, u and e white."""
    rng = np.random.default_rng(seed)
    u, e, y = rng.normal(size=samples), noise * rng.normal(size=samples), np.zeros(samples)
    for k in range(samples):
        y[k] = e[k] + sum(c * y[k - j] for j, c in enumerate(a, 1) if k >= j) + \
            sum(c * u[k - d] for d, c in b.items() if k >= d)
    return record(u, y)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_order_the_data_support_is_found(seed: int) -> None:
    first = linear_memory([simulate([0.9], {1: 1.0}, 4000, seed)], ["u"], ["y"], 64)
    assert first.samples == 1, first.criterion
    resonance = linear_memory([simulate([1.6, -0.8], {1: 0.5}, 4000, seed)], ["u"], ["y"], 64)  # a damped oscillator
    assert resonance.samples == 2, resonance.criterion
    dead_time = linear_memory([simulate([0.5], {11: 1.0}, 4000, seed)], ["u"], ["y"], 64)  # the input 11 samples late
    assert dead_time.samples == 16, dead_time.criterion  # the first tried order (1, 2, 4, ...) that reaches it
    assert linear_memory([simulate([0.5], {11: 1.0}, 4000, seed)], ["u"], ["y"], 8).samples <= 8  # never past max_lag


def test_records_too_short_are_one_line() -> None:
    with pytest.raises(ValueError, match="no training record holds 3 samples"):
        linear_memory([record(np.zeros(2), np.zeros(2))], ["u"], ["y"], 8)
    with pytest.raises(ValueError, match="max_lag must be at least 1"):
        linear_memory([record(np.zeros(9), np.zeros(9))], ["u"], ["y"], 0)
