"""Interpolation tables of a scheduled block's matrices: exact to round-off where verified, else not used.

A scheduled block discretizes its matrices at every sample (``scheduled.py``): a call on B windows
of S samples costs B·S matrix exponentials, even when the parameters have not changed since the
last call. Where the user allows it (``table: true`` on a block scheduled by one signal ρ), the
block tabulates its normalized rows on a uniform grid over the range of ρ it has seen and reads
every sample off the table (``ScheduleTable``), by the cubic through the ``ORDER`` = 4 nearest grid
points (one-sided at the ends of the range, so no point outside it is evaluated), held as each
interval's polynomial: a lookup is one gather and three steps of Horner's rule.

**Exact to round-off, verified, or not used.** ``build`` starts with ``FIRST_POINTS`` points and
halves the step until the interpolant, evaluated in the run's dtype, equals the exact rows
(computed in float64) at every interval's midpoint to ``TOLERANCE`` units of the dtype's epsilon,
relative to the table's largest entry. The step halves by adding the midpoints to the grid, so
every exact row computed is used. Without that at ``MAX_POINTS`` points, or with a non-finite
row, there is no table (``build`` returns None and says why): the block computes its rows per
sample as before.

**What it costs.** Building: the exact rows at 2G - 1 points (G the table's points), once for a
set of parameter values and a range of ρ; memory: G x (the rows' entries). The velocity-scheduled
single track over 5-31 m/s in float32 verifies at 129 points, 20 KiB (``hypa timing
physics`` prints its points, error, build time and memory). In float64 a cubic would need ~10^5
points for round-off, so a double-precision run keeps its per-sample rows.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

_LOG = logging.getLogger(__name__)
ORDER = 4  # grid points per interpolation: a local cubic
FIRST_POINTS = 33
MAX_POINTS = 4097
TOLERANCE = 8.0  # the largest midpoint deviation allowed, in epsilons of the run's dtype (relative)


@dataclass(frozen=True)
class ScheduleTable:
    """Rows at ρ = lo + i step (i = 0..G-1, step = (hi - lo) / (G - 1)) as polynomials over each interval.

    ``coefficients`` (G - 1, order, E): interval i's polynomial in s = (ρ - lo) / step - i ∈ [0, 1],
    lowest power first, in the run's dtype (``polynomials``); a one-point table holds (1, 1, E).
    """

    lo: float
    hi: float
    coefficients: Tensor
    error: float  # the largest deviation at the midpoints, relative to the largest entry

    @property
    def points(self) -> int:
        return self.coefficients.shape[0] + (self.coefficients.shape[1] > 1)

    @property
    def step(self) -> float:
        return (self.hi - self.lo) / (self.points - 1) if self.points > 1 else 1.0

    def covers(self, lo: float, hi: float) -> bool:
        return self.lo <= lo and hi <= self.hi

    def __call__(self, rho: Tensor) -> Tensor:
        """The rows (..., E) at ρ (...,) within [lo, hi]: one gather of the intervals' coefficients, Horner in s."""
        c = self.coefficients
        if c.shape[1] == 1:
            return c[0, 0].expand(*rho.shape, c.shape[2])
        pos = (rho.reshape(-1) - self.lo) / self.step
        interval = pos.floor().clamp_(0, c.shape[0] - 1)
        s = (pos - interval)[:, None]
        c = c.index_select(0, interval.long())  # (K, order, E)
        out = c[:, -1]
        for j in range(c.shape[1] - 2, -1, -1):
            out = torch.addcmul(c[:, j], out, s)
        return out.reshape(*rho.shape, c.shape[2])


def polynomials(values: Tensor) -> Tensor:
    """Each interval's interpolating polynomial (G - 1, order, E) through the ``ORDER`` nearest of ``values`` (G, E).

    Interval i (between points i and i + 1) takes the points j0..j0 + order - 1 with j0 = i - 3
    kept within the grid (one-sided at its ends), at s = j0 - i + m; its coefficients are the
    Vandermonde system's solution there, computed in float64 (8 distinct offsets at most).
    """
    points = values.shape[0]
    order = min(ORDER, points)
    interval = torch.arange(points - 1)
    first = (interval - (order // 2 - 1)).clamp(0, points - order)
    offset = first - interval  # the first point's s
    powers = torch.arange(order, dtype=torch.float64)
    shifts = torch.unique(offset)
    inverse = torch.linalg.inv((shifts[:, None, None] + powers[:, None]) ** powers)  # (shifts, order, order)
    stencil = values.to(torch.float64)[(first[:, None] + torch.arange(order)).to(values.device)]  # (G - 1, order, E)
    return inverse[torch.searchsorted(shifts, offset)].to(values.device) @ stencil


class Built(NamedTuple):
    """What :func:`build` made: the table (None: none), a line on it, and whether the dtype itself
    is refused (no table within ``MAX_POINTS`` meets its tolerance, whatever the call's values)."""

    table: ScheduleTable | None
    line: str
    refused: bool = False


def build(exact: Callable[[Tensor], Tensor], lo: float, hi: float, dtype: torch.dtype,
          device: torch.device | str = "cpu") -> Built:
    """A table of ``exact`` over [lo, hi] verified to ``TOLERANCE`` in ``dtype``, or None, and a line on it.

    ``exact`` maps ρ (K,) float64 to the rows (K, E) float64. The line says the points and the
    error found, or why there is no table.
    """
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        return Built(None, f"no table over [{lo:g}, {hi:g}]: the scheduling signal is not finite")
    if hi == lo:  # one value: the table is that value's rows, exact
        values = exact(torch.tensor([lo], dtype=torch.float64, device=device))
        ok = bool(torch.isfinite(values).all())
        return Built(ScheduleTable(lo, hi, values[:, None].to(dtype), 0.0) if ok else None,
                     f"one point at {lo:g}" if ok else f"no table: the rows at {lo:g} are not finite")
    tol = TOLERANCE * torch.finfo(dtype).eps
    points = FIRST_POINTS
    grid = torch.linspace(lo, hi, points, dtype=torch.float64, device=device)
    values = exact(grid)
    while True:
        mid = (grid[:-1] + grid[1:]) / 2
        reference = exact(mid)
        if not (bool(torch.isfinite(values).all()) and bool(torch.isfinite(reference).all())):
            return Built(None, f"no table over [{lo:g}, {hi:g}]: the rows are not finite there")
        table = ScheduleTable(lo, hi, polynomials(values).to(dtype), 0.0)
        got = table(mid.to(dtype)).to(torch.float64)
        scale = max(float(values.abs().max()), float(reference.abs().max()), torch.finfo(torch.float64).tiny)
        error = float((got - reference).abs().max()) / scale
        if error <= tol:
            return Built(dataclasses.replace(table, error=error),
                         f"{points} points over [{lo:g}, {hi:g}], largest deviation {error:.1e} of the largest entry")
        if 2 * points - 1 > MAX_POINTS:
            return Built(None, f"no table over [{lo:g}, {hi:g}]: {points} points still deviate {error:.1e} "
                               f"(allowed {tol:.1e}); the rows are computed per sample", refused=True)
        grid = torch.cat([torch.stack([grid[:-1], mid], 1).reshape(-1), grid[-1:]])
        values = torch.cat([torch.stack([values[:-1], reference], 1).reshape(-1, values.shape[1]), values[-1:]])
        points = 2 * points - 1


class ScheduleTables:
    """A block's table for its current parameters and the range of ρ seen (built on demand), or none.

    ``get`` returns the table when it was built for the same ``key`` (the block's parameters,
    scaling, dtype and device, as its lifted cache) and covers the call's ρ; else it builds one
    over the call's range joined with the last table's. A dtype whose table cannot be verified is
    not tried again (one warning says so); a non-finite ρ or row gives no table for that call only
    (the per-sample rows then show what the exact path gives).
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.last: tuple[tuple, ScheduleTable] | None = None
        self.refused: dict[torch.dtype, str] = {}
        self.lines: list[str] = []  # what each build said, the latest last (at most 16)

    def get(self, key: tuple, rho: Tensor, exact: Callable[[Tensor], Tensor]) -> ScheduleTable | None:
        if rho.dtype in self.refused or rho.numel() == 0:
            return None
        lo, hi = (float(v) for v in torch.aminmax(rho.detach()))
        if not (math.isfinite(lo) and math.isfinite(hi)):
            return None
        if self.last is not None and self.last[0] == key:
            if self.last[1].covers(lo, hi):
                return self.last[1]
            lo, hi = min(lo, self.last[1].lo), max(hi, self.last[1].hi)
        table, line, refused = build(exact, lo, hi, rho.dtype, rho.device)
        self.lines = [*self.lines[-15:], line]
        if table is None:
            if refused:  # the tolerance, not this call's values: the dtype keeps its per-sample rows
                self.refused[rho.dtype] = line
                _LOG.warning("%s (%s): %s", self.name, rho.dtype, line)
            return None
        (_LOG.debug if self.last else _LOG.info)("%s (%s): the matrices off a table of %s", self.name, rho.dtype,
                                                  line)  # the first one said, later rebuilds (new parameters) logged
        self.last = (key, table)
        return table
