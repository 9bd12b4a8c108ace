"""Running a nonlinear (Lur'e) ``LTIBlock``: its discrete parts and its steps, in a loop or for every
sample at once (the nonlinear half of ``simulation``).

The linear part is exact under the block's hold; the nonlinearity's output w is taken linear over
each sample (its own first-order hold) with Heun's predictor-corrector, second order in dt.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, NamedTuple

import torch
from torch import Tensor

from hypa.physics.discretization import discretize
from hypa.physics.parallel import solve_recursion
from hypa.physics.scan import affine_scan

if TYPE_CHECKING:
    from hypa.physics.parameters import PhysicalParameters
    from hypa.physics.statespace import LTIModel

PARALLEL_STEPS = 256  # a nonlinear float64 run this long, without a graph, is solved for every sample at once
PARALLEL_WIDTH = 16  # ... when it is this narrow (batch x states): the loop's steps are then all call overhead
# (wider, the loop pays each operation's flops once per sample, Newton a few hundred times per iteration:
# at 64 records of 2 states the loop is 2-3x faster, at 8 Newton is 1.7-2.5x faster, at 1 it is 3-8x)
PARALLEL_BYTES = 2**30  # ... when its per-sample Jacobians and states take at most this memory (else the loop)
HALVINGS = 3  # a span Newton does not solve is halved this many times at most (spans of an eighth; then the loop)


class LureParts(NamedTuple):
    """A nonlinear block's discrete parts [SI]: Φᵀ, the input taps Γ_t and drift γ under its hold,
    the feedback's first-order-hold taps (Γ^w_0, Γ^w_1, their sum), transposed, and ``prepare``'s values."""

    phi_t: Tensor
    taps: tuple[Tensor, ...]
    drift: Tensor | None
    now_t: Tensor
    next_t: Tensor
    held_t: Tensor
    prepared: Mapping[str, Tensor]


class LureSimulation:
    """The nonlinear steps of ``LTIBlock`` (a mixin of ``BlockSimulation``, whose ``tap_inputs`` it reads)."""

    model: LTIModel
    parameters_: PhysicalParameters
    dt: float
    hold: str
    state_mean: Tensor
    state_std: Tensor
    input_mean: Tensor
    input_std: Tensor

    def _simulate_nonlinear(self, x0: Tensor, u: Tensor, steps: int, before: Tensor | None = None) -> Tensor:
        """States x̂_{k+1..k+S} of a Lur'e system, step by step in physical units.

        The linear part is exact under the block's hold; the nonlinearity's output w is taken
        linear over each sample (its own first-order hold, Γ^w_0 w_k + Γ^w_1 w_{k+1}) with
        w_{k+1} = φ(x̃_{k+1}, u_{k+1}) at a predicted state x̃_{k+1} (w held): Heun's
        predictor-corrector, second order in dt. A long, narrow run in double precision without a
        graph (an identification's record) solves the same steps for every sample at once
        (``_solve_nonlinear``: their own fixed point, or the loop where Newton does not reach it).
        """
        dtype = u.dtype
        lure = self.lure_parts(dtype)
        mean_x, std_x = self.state_mean.to(dtype), self.state_std.to(dtype)
        mean_u, std_u = self.input_mean.to(dtype), self.input_std.to(dtype)
        u_phys = u[:, : steps + 1] * std_u + mean_u  # (B, S or S + 1, m): the feedback reads u_k and u_{k+1}
        held = self.tap_inputs(u, steps, before) * std_u + mean_u  # (B, S + T - 1, m)
        forced = sum(held[:, t : t + steps] @ g.T for t, g in enumerate(lure.taps))  # (B, S, n)
        if lure.drift is not None:
            forced = forced + lure.drift
        x = x0 * std_x + mean_x
        # a long run in double precision, not trained through (an identification's, a diagnosis'), is
        # solved for every sample at once: in single precision the loop's round-off (3e-5 of the spread
        # over EMPS's 5 s validation record) is the free run's, and what an exported model's own steps reproduce
        parallel = (steps >= PARALLEL_STEPS and x.numel() <= PARALLEL_WIDTH and dtype == torch.float64
                    and not torch.is_grad_enabled())
        return (self._run_span(lure, x, u_phys, forced, std_x, 0, steps, parallel, HALVINGS) - mean_x) / std_x

    def _run_span(self, lure: LureParts, x: Tensor, u_phys: Tensor, forced: Tensor, scale: Tensor, start: int,
                  end: int, parallel: bool, halvings: int) -> Tensor:
        """The states [SI] after samples ``start``..``end`` - 1 (B, end - start, n) from ``x``, the state at
        ``start``: every sample at once where ``parallel`` and Newton solves the span (``_solve_nonlinear``);
        where it does not (a first iterate that strays far over a long span: a position-dependent force
        over a drifting axis), each half on its own, ``halvings`` times at most and down to
        ``PARALLEL_STEPS`` samples; else step by step."""
        if parallel and end - start >= PARALLEL_STEPS:
            solved = self._solve_nonlinear(lure, x, u_phys, forced, scale, start, end)
            if solved is not None:
                return solved
            if halvings and end - start >= 2 * PARALLEL_STEPS:
                middle, more = (start + end) // 2, halvings - 1
                first = self._run_span(lure, x, u_phys, forced, scale, start, middle, parallel, more)
                return torch.cat([first, self._run_span(lure, first[:, -1], u_phys, forced, scale, middle, end,
                                                        parallel, more)], 1)
        states = []
        samples, pushes = u_phys.unbind(1), forced.unbind(1)  # views made at once: no indexing op per step
        for k in range(start, end):
            x = self.lure_step(lure, x, samples[k], samples[min(k + 1, len(samples) - 1)], pushes[k])
            states.append(x)
        return torch.stack(states, 1)

    def _solve_nonlinear(self, lure: LureParts, x0: Tensor, u_phys: Tensor, forced: Tensor, scale: Tensor,
                         start: int, end: int) -> Tensor | None:
        """``_run_span``'s states [SI] (B, end - start, n), every sample at once (``solve_recursion``:
        Newton over the sequence, the same fixed point as the loop), or ``None`` where it does not
        converge. The first iterate is the linear part's run with the feedback held at ``start``."""
        batch, steps, n = forced.shape[0], end - start, forced.shape[2]
        if batch * steps * n * (n + 4) * forced.element_size() > PARALLEL_BYTES:
            return None  # the Jacobians of every sample would not fit: the loop's memory is one state
        later = torch.arange(start + 1, end + 1, device=u_phys.device).clamp_max(u_phys.shape[1] - 1)
        now, after = u_phys[:, start:end], u_phys[:, later]  # u_k and u_{k+1} (the last one held, as the loop)
        forced = forced[:, start:end]

        def step(x: Tensor) -> Tensor:
            rows = self.lure_step(lure, x.reshape(-1, n), now.reshape(-1, now.shape[-1]),
                                  after.reshape(-1, after.shape[-1]), forced.reshape(-1, n))
            return rows.reshape(batch, steps, n)

        held = forced + self.model.nonlinearity(x0, now[:, 0], lure.prepared)[:, None] @ lure.held_t
        held[:, 0] += x0 @ lure.phi_t
        guess = affine_scan(lure.phi_t.T.expand(1, steps, n, n), held, prefix=False)[1]
        if not bool(torch.isfinite(guess).all()):
            guess = x0[:, None].expand(batch, steps, n)
        return solve_recursion(step, x0, guess, scale)

    def lure_parts(self, dtype: torch.dtype) -> LureParts:
        """The discrete Lur'e system of a nonlinear block at the current parameters, in ``dtype``."""
        p = self.parameters_.values(self.model.parameter_names, dtype)
        ss, f = self.model.matrices(p), self.model.feedback(p)
        disc = discretize(ss.a, ss.b, self.dt, self.hold, ss.e)
        w_now, w_next = discretize(ss.a, f, self.dt, "foh").taps
        return LureParts(disc.phi.T, disc.taps, disc.drift, w_now.T, w_next.T, (w_now + w_next).T,
                         self.model.prepare(p))

    def lure_step(self, lure: LureParts, x: Tensor, u_now: Tensor, u_next: Tensor, forced: Tensor) -> Tensor:
        """x_{k+1} (B, n) [SI] of ``_simulate_nonlinear`` from x_k, u_k, u_{k+1} [SI] and the forced
        term Σ_t Γ_t u_{k+t} + γ (B, n): Heun's predictor-corrector for the feedback w."""
        w = self.model.nonlinearity(x, u_now, lure.prepared)
        linear = torch.addmm(forced, x, lure.phi_t)
        predicted = torch.addmm(linear, w, lure.held_t)
        w_after = self.model.nonlinearity(predicted, u_next, lure.prepared)
        return torch.addmm(torch.addmm(linear, w, lure.now_t), w_after, lure.next_t)
