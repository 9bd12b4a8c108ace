"""The residuals of the output-error fit, by single or multiple shooting, and their Jacobian.

Each stretch s runs free from its own initial state ξ_s: the normalized state at its start of
every block that starts from the measurements (:meth:`ComposedModel.started_blocks`). The ξ_s are
decision variables of the fit beside the parameters θ, started from the data's state (the
measured state, or the least-squares estimate from the stretch's first samples), as MATLAB's
grey-box fits estimate initial states: an initial state taken from a few noisy samples would
otherwise bend the parameters, most of all for a system that integrates (a start velocity off
by δv moves an integrated position by δv times the velocity's time constant, for the whole run).

**Single shooting** (one stretch per record): the residuals are the weighted output errors of
the records' free runs.

**Multiple shooting** (a record cut into several stretches, ``identification.stretch_s``): a
continuity term ties consecutive stretches of a record: the state x_s(t_{s+1}) that stretch s
reaches at the next one's start must equal ξ_{s+1}. The fit minimizes

    V(θ, ξ) = V_out(θ, ξ) + μ Σ_junctions ‖x_s(t_{s+1}; θ, ξ_s) - ξ_{s+1}‖² / (J n)

(J junctions, n states, states in their normalized scale), with the continuity weight μ raised
in steps (:data:`CONTINUITY`): at first the stretches fit nearly on their own, so a free run that
would drift or diverge over a whole record (an integrating or unstable system) cannot carry the
parameters away; at the end the defects are negligible, and the result is one free run per
record, reached from a better-conditioned start.

The Jacobian is by forward differences of float64 model runs. A parameter's column needs one
run over every stretch; the stretches' states need one run per state component, since a
stretch's states move only its own outputs and its own junctions (all stretches are probed at
once). In multiple shooting it is sparse; it is handed to scipy as a dense matrix (solved
exactly) up to 256 MiB, as a sparse one (solved by LSMR) beyond.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence

import numpy as np
import torch
from scipy import sparse

from hypa.core.metrics import rms
from hypa.identification.stretches import Stretches
from hypa.models import ComposedModel
from hypa.physics import SchedulingError, UnstablePhysicsError

PROBE = 1e-7  # forward-difference step in the fit's coordinates (relative for positive parameters)
CONTINUITY = (1.0, 1e2, 1e4)  # μ, raised in these steps (multiple shooting)
_DENSE_BYTES = 2**28  # a Jacobian up to this size is dense (scipy's exact solver); larger ones sparse (LSMR)

REFUSED_ERRORS = (UnstablePhysicsError, SchedulingError, ValueError, ArithmeticError, torch.linalg.LinAlgError)


def correlation_time(errors: Sequence[np.ndarray]) -> float:
    """τ = 1 + 2 Σ_k ρ_k [samples]: how many consecutive terms carry one independent one.

    ``errors``: arrays (stretches, samples, outputs). ρ_k is their autocorrelation at lag k,
    pooled over stretches and outputs, summed while it stays positive (a free run's errors are
    smooth, so τ is often tens or hundreds of samples; white errors give 1): N correlated terms
    weigh as N / τ independent ones.
    """
    acf = np.zeros(max(x.shape[1] for x in errors))
    for x in errors:  # Σ_t e_t e_{t+k} by FFT, zero-padded (no wrap-around)
        spectrum = np.fft.rfft(x, n=2 * x.shape[1], axis=1)
        acf[: x.shape[1]] += np.fft.irfft(np.abs(spectrum) ** 2, axis=1)[:, : x.shape[1]].sum((0, 2))
    if acf[0] <= 0:
        return 1.0
    rho = acf[1:] / acf[0]
    ends = np.flatnonzero(rho <= 0)
    return float(1 + 2 * rho[: ends[0] if ends.size else rho.size].sum())


class Refused(Exception):
    """A trial point where the physics refuses to run or its free run is not finite."""


class Shooting:
    """The fit's residual vector r(v) and its Jacobian, v = (z, ξ): the parameters in the fit's
    coordinates, then (multiple shooting) the stretches' initial states.

    ``set_parameters(z)`` puts z into the model. The output rows are scaled so that their sum of
    squares is the mean over outputs of 1 - R² (:meth:`output_cost`); the continuity rows by
    √(μ / (J n)).
    """

    def __init__(self, model: ComposedModel, stretches: Stretches, set_parameters: Callable[[np.ndarray], None],
                 parameters: int) -> None:
        self.model, self.data = model, stretches.to(torch.float64)
        self.set_parameters, self.p = set_parameters, parameters
        self.first = self.data.first
        weights = self.data.weights()
        self.outputs = int(weights.numel())
        lengths = [int(b["y"].shape[1]) - self.first for b in self.data.batches]
        sizes = [int(b["y"].shape[0]) for b in self.data.batches]
        self.samples = sum(n * length for n, length in zip(sizes, lengths))
        self.scale = torch.sqrt(weights / (self.samples * self.outputs))
        # output rows of each stretch: batch g's rows follow the earlier batches', stretch by stretch
        self.rows: dict[tuple[int, int], slice] = {}
        offset = 0
        for g, (n, length) in enumerate(zip(sizes, lengths)):
            for r in range(n):
                self.rows[(g, r)] = slice(offset, offset + length * self.outputs)
                offset += length * self.outputs
        self.junctions = self._junctions()
        self.blocks = model.started_blocks()
        self.n = sum(self.blocks.values())
        self.order = list(self.rows)  # stretch k's states are ξ[k]
        self.mu = CONTINUITY[0]
        self._last: tuple[np.ndarray, np.ndarray, list[np.ndarray]] | None = None  # simulate's latest point
        self.xi0 = self._data_states() if self.n else np.zeros((0, 0))

    # -- layout ------------------------------------------------------------------------
    def _junctions(self) -> list[tuple[tuple[int, int], tuple[int, int], int]]:
        """(stretch a, stretch b, i): a's state i samples after its start is b's start."""
        by_record: dict[int, list[tuple[int, tuple[int, int]]]] = {}
        for g, positions in enumerate(self.data.positions):
            for r, (record, start) in enumerate(positions):
                by_record.setdefault(record, []).append((start, (g, r)))
        out = []
        for items in by_record.values():
            items.sort()
            for (start_a, a), (start_b, b) in itertools.pairwise(items):
                out.append((a, b, start_b - start_a))
        return out

    @property
    def size(self) -> int:
        """Decision variables: parameters, then n initial states per stretch."""
        return self.p + self.n * len(self.order)

    @property
    def stretches(self) -> int:
        return len(self.order)

    def start(self, z0: np.ndarray) -> np.ndarray:
        return np.concatenate([z0, self.xi0.reshape(-1)])

    def _data_states(self) -> np.ndarray:
        """ξ from the data: each stretch's measured or estimated state at its start, (stretches, n)."""
        states: list[dict[str, torch.Tensor]] = []
        self.data.predict(self.model, states=states)
        return np.concatenate([torch.cat([ran[name][:, 0] for name in self.blocks], -1).numpy() for ran in states])

    def _initial(self, xi: np.ndarray) -> list[dict[str, torch.Tensor]]:
        """Per batch, block name -> (B, n_block) initial states from ξ (stretches, n)."""
        out, first = [], 0
        for b in self.data.batches:
            rows = xi[first : first + b["y"].shape[0]]  # self.order is batch by batch
            first += b["y"].shape[0]
            blocks, col = {}, 0
            for name, n in self.blocks.items():
                blocks[name] = torch.as_tensor(rows[:, col : col + n], dtype=torch.float64)
                col += n
            out.append(blocks)
        return out

    # -- evaluation --------------------------------------------------------------------
    def simulate(self, v: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Scaled output residuals (all rows) and, in multiple shooting, each stretch's states
        (S + 1, n) from its start. Raises :class:`Refused` at a point the physics cannot run.
        The model is left at v's parameters; the latest point's run is reused (scipy, the
        progress line and the report ask for the same point several times)."""
        self.set_parameters(v[: self.p])
        if self._last is not None and np.array_equal(self._last[0], v):
            return self._last[1], self._last[2]
        xi = v[self.p :].reshape(len(self.order), self.n)
        states: list[dict[str, torch.Tensor]] | None = [] if self.n else None
        try:
            pairs = self.data.predict(self.model, self._initial(xi) if self.n else None, states)
        except REFUSED_ERRORS as error:  # a trial the physics refuses or cannot compute (an overflowing exponential)
            raise Refused(str(error)) from error
        r = torch.cat([((p - y) * self.scale).reshape(-1) for p, y in pairs]).numpy()
        if not np.all(np.isfinite(r)):
            raise Refused("the free run is not finite")
        trajectories: list[np.ndarray] = []  # in the order of self.order: batch by batch, stretch by stretch
        for ran in states or ():
            trajectories.extend(torch.cat([ran[name] for name in self.blocks], -1).numpy())  # (B, S + 1, n) each
        self._last = (v.copy(), r, trajectories)
        return r, trajectories

    def correlation_times(self, v: np.ndarray, jacobian) -> np.ndarray:
        """Each parameter's τ_j [samples] (:func:`correlation_time`) of g_j = e ∂e/∂θ_j, the output
        errors weighted by their sensitivity to it: the terms its gradient sums. Errors that are
        smooth where the sensitivity is too (a slow drift, a slow parameter) give a large τ_j;
        a bias met by a fast-changing sensitivity averages out and gives a small one."""
        e, _ = self.simulate(v)
        columns = jacobian[: e.size, : self.p]
        columns = columns.toarray() if sparse.issparse(columns) else columns
        return np.array([correlation_time(self._by_stretch(e * columns[:, j])) for j in range(self.p)])

    def output_correlation_time(self, rows: np.ndarray) -> float:
        """τ [samples] (:func:`correlation_time`) of the output rows of a residual."""
        return correlation_time(self._by_stretch(rows))

    def _by_stretch(self, rows: np.ndarray) -> list[np.ndarray]:
        """Output rows as arrays (stretches, samples, outputs), one per batch."""
        out, offset = [], 0
        for b in self.data.batches:
            shape = (int(b["y"].shape[0]), int(b["y"].shape[1]) - self.first, self.outputs)
            out.append(rows[offset : offset + int(np.prod(shape))].reshape(shape))
            offset += out[-1].size
        return out

    def defects(self, v: np.ndarray, trajectories: Sequence[np.ndarray]) -> np.ndarray:
        """x_a(t_b) - ξ_b for every junction (J, n), normalized states."""
        xi = v[self.p :].reshape(len(self.order), self.n)
        index = {key: k for k, key in enumerate(self.order)}
        return np.array([trajectories[index[a]][i] - xi[index[b]] for a, b, i in self.junctions]).reshape(-1, self.n)

    def _weight(self) -> float:
        return math.sqrt(self.mu / max(len(self.junctions) * self.n, 1))

    def residual(self, v: np.ndarray) -> np.ndarray:
        r, trajectories = self.simulate(v)
        if not self.junctions:
            return r
        return np.concatenate([r, self._weight() * self.defects(v, trajectories).reshape(-1)])

    def output_cost(self, v: np.ndarray) -> float:
        """V_out: the mean over outputs of 1 - R² on the stretches."""
        r, _ = self.simulate(v)
        return float(r @ r)

    def defect_rms(self, v: np.ndarray) -> float:
        """RMS of the continuity defects, in state standard deviations (0 in single shooting)."""
        if not self.junctions:
            return 0.0
        return rms(self.defects(v, self.simulate(v)[1]))

    def jacobian(self, v: np.ndarray, base: np.ndarray, upper: Sequence[float]):
        """dr/dv at v (``base`` = r(v)): dense, or sparse CSR for a large multiple-shooting problem."""
        at_v = self.simulate(v)  # before the probes move the latest point away
        columns = []
        for j in range(self.p):
            step = PROBE * max(1.0, abs(v[j]))
            if v[j] + step > upper[j]:
                step = -step
            probe = v.copy()
            probe[j] += step
            columns.append((self.residual(probe) - base) / step)
        dense = np.stack(columns, axis=1) if columns else np.zeros((base.size, 0))
        if not self.n:
            return dense
        states = self._state_columns(v, base, *at_v)
        if base.size * self.size * 8 <= _DENSE_BYTES:  # small enough: the exact trust-region solver
            return np.hstack([dense, states.toarray()])
        return sparse.hstack([sparse.csr_matrix(dense), states], format="csr")

    def _state_columns(self, v: np.ndarray, base: np.ndarray, r0: np.ndarray,
                       x0: Sequence[np.ndarray]) -> sparse.csr_matrix:
        """The columns of the stretches' states (``r0``, ``x0``: the run at v): one probe per state
        component, every stretch at once."""
        w, count, n = self._weight(), len(self.order), self.n
        index = {key: k for k, key in enumerate(self.order)}
        defect_row0 = r0.size
        rows, cols, vals = [], [], []
        for c in range(n):
            probe = v.copy()
            probe[self.p + c :: n] += PROBE
            r1, x1 = self.simulate(probe)
            for key, k in index.items():
                part = self.rows[key]
                d = (r1[part] - r0[part]) / PROBE
                nz = np.nonzero(d)[0]
                rows.append(part.start + nz)
                cols.append(np.full(nz.size, k * n + c))
                vals.append(d[nz])
            for jn, (a, b, i) in enumerate(self.junctions):
                ka, kb = index[a], index[b]
                d = w * (x1[ka][i] - x0[ka][i]) / PROBE  # a's trajectory moved by its own start
                rows.append(defect_row0 + jn * n + np.arange(n))
                cols.append(np.full(n, ka * n + c))
                vals.append(d)
                rows.append(np.array([defect_row0 + jn * n + c]))  # -ξ_b
                cols.append(np.array([kb * n + c]))
                vals.append(np.array([-w]))
        return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                 shape=(base.size, count * n))
