"""Running an ``LTIBlock``: its outputs, states, steady and estimated states (the block's simulation half).

Output convention, with k the window start, S predicted samples and T input taps (1 ZOH, 2 FOH,
4 cubic, P = 1 of them before the step's own sample): ``forward(x̂_k, û)`` with û (B, S +
extra_inputs, m) holding samples k, k+1, ... returns ŷ (B, S, p) at samples k+1..k+S,

    x̂_{j+1} = Â x̂_j + Σ_t B̂_t û_{j+t-P} + Ĥ               (eq. 5)
    ŷ_j = Ĉ x̂_j + D̂ û_j + Ĝ                                  (D pairs with its own sample's input)

The states use û_{k-P}..û_{k+S+T-2-P}; the output at k+S also reads û_{k+S} when D ≠ 0, hence
``extra_inputs`` = 1 for a hold that reads the next sample (FOH, cubic) or with feedthrough (D ≠ 0
at the parameters the block is built with), else 0. A cubic hold's tap before û_k is the input
given before the window (``before``: a composed model's past) or, as its tap after û_{k+S}, the
line through the two nearest samples (``tap_inputs``): an error of the order of a first-order
hold's on the first and last step of a window. A block without
states is a gain, ŷ_j = D̂ û_j + Ĝ at every given sample (S = L). Constant blocks simulate in the
lifted form (eq. 9-11): cached while frozen, one fused graph node for a horizon-long window of
trainable physics, horizon-long windows chained otherwise. Scheduled blocks rebuild their
matrices per sample (``scheduled``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from hypa.physics.discretization import HoldForm
from hypa.physics.estimation import (
    GAUSS_NEWTON_STEPS,
    NONLINEAR_OUTPUT_STEPS,
    OUTPUT_HALVINGS,
    estimate_last_state,
    refine_first_state,
)
from hypa.physics.exponential import squarings_for
from hypa.physics.lifted import simulate_chunked, simulate_from_rows
from hypa.physics.lure import LureSimulation
from hypa.physics.normalized import NormalizedLTI, NormalizingMaps
from hypa.physics.scheduled import (
    SchedulingError,
    forced_terms,
    per_sample_matrices,
    simulate_scheduled,
)

if TYPE_CHECKING:
    from hypa.physics.statespace import LTIModel, StateSpace

Output = tuple[Tensor, Tensor, Tensor]  # Ĉ, D̂, Ĝ: (p, n), (p, m), (p,) or per sample (B, S, p, ...)


def apply_output(c: Tensor, d: Tensor, g: Tensor, x: Tensor, u: Tensor | None) -> Tensor:
    """ŷ = Ĉ x̂ + D̂ û + Ĝ (..., p) for x (..., n), u (..., m) (None: no feedthrough), constant or per-sample matrices."""
    if c.dim() == 2:
        y = x @ c.T + g
        return y if u is None else y + u @ d.T
    y = (c @ x[..., None]).squeeze(-1) + g
    return y if u is None else y + (d @ u[..., None]).squeeze(-1)


class BlockSimulation(LureSimulation):
    """The simulation methods of ``LTIBlock`` (a mixin: it reads the block's model, scaling and matrices;
    a nonlinear block's steps are ``LureSimulation``'s)."""

    model: LTIModel
    scheduled: tuple[str, ...]
    feedthrough: bool
    form: HoldForm
    n_taps: int
    horizon: int

    @property
    def extra_inputs(self) -> int:
        """Input samples beyond the S outputs that ``forward`` needs: 1 for a hold that reads the next
        sample or with D ≠ 0, else 0."""
        if not self.model.n_states:
            return 0
        return max(min(self.form.lead, 1), int(self.feedthrough))

    def tap_inputs(self, u: Tensor, steps: int, before: Tensor | None = None) -> Tensor:
        """What the hold's taps read over ``steps`` steps from û_k: û_{k-P}..û_{k+steps+T-2-P}
        (B, steps + T - 1, m), from u (B, >= 1, m) holding samples k, k+1, ... and ``before``
        (B, >= P, m), the samples before û_k where known. A tap outside the given samples is
        extrapolated by the line through the two nearest ones (held where only one is given)."""
        form = self.form
        u = u[:, : steps + form.lead]
        after = steps + form.lead - u.shape[1]
        if not form.past and not after:
            return u
        first = u[:, :1] - u[:, 1:2] if u.shape[1] > 1 else torch.zeros_like(u[:, :1])  # û_k - û_{k+1}
        last = u[:, -1:] - u[:, -2:-1] if u.shape[1] > 1 else torch.zeros_like(u[:, :1])
        steps_back = torch.arange(form.past, 0, -1, dtype=u.dtype, device=u.device)[None, :, None]
        steps_on = torch.arange(1, after + 1, dtype=u.dtype, device=u.device)[None, :, None]
        known = before is not None and form.past and before.shape[1] >= form.past
        head = before[:, before.shape[1] - form.past :].to(u.dtype) if known else u[:, :1] + steps_back * first
        return torch.cat([head, u, u[:, -1:] + steps_on * last], 1)

    def forward(self, x0: Tensor | None, u: Tensor, scheduling: Tensor | None = None,
                before: Tensor | None = None) -> Tensor:
        """Normalized outputs ŷ (B, S, p) at samples k+1..k+S from x̂_k (B, n) and û (B, S + extra_inputs, m).

        scheduling: (B, L, q) physical values of the scheduled parameters, aligned with u (a
        scheduled block only). A block without states takes x0 None and returns (B, L, p).
        before: (B, >= P, m) the normalized inputs before û_k, read by a hold with taps before
        its step's sample (``cubic``; extrapolated where not given, ``tap_inputs``).
        """
        if not self.model.n_states:
            rho = None if scheduling is None else scheduling[:, : u.shape[1]]
            return self.output(u.new_zeros(*u.shape[:-1], 0), u, rho)
        return self.run(x0, u, scheduling, before)[0]

    def run(self, x0: Tensor, u: Tensor, scheduling: Tensor | None = None,
            before: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """``forward``'s outputs ŷ (B, S, p) and the states x̂_{k+1..k+S} (B, S, n) behind them, from one simulation."""
        steps = self._steps(u)
        states, out = self._simulate(x0, u, scheduling, steps, before)
        if out is None:  # y = x: the outputs share the states' names and scaling
            return states, states
        now = u[:, 1 : steps + 1] if self.feedthrough else None  # an h(x, u)'s block always has them
        y = apply_output(*out, states, now)
        return (y + self.nonlinear_output(states, now) if self.model.has_nonlinear_output else y), states

    def states(self, x0: Tensor | None, u: Tensor, scheduling: Tensor | None = None) -> Tensor:
        """Normalized states x̂_{k+1..k+S} (B, S, n), the samples of ``forward``'s outputs."""
        if not self.model.n_states:
            return u.new_zeros(*u.shape[:-1], 0)
        return self._simulate(x0, u, scheduling, self._steps(u))[0]

    def output(self, states: Tensor, u: Tensor, scheduling: Tensor | None = None) -> Tensor:
        """ŷ = Ĉ x̂ + D̂ û + Ĝ (..., p) from states (..., n) and the inputs of the same samples (..., m).

        scheduling: (..., q) physical values at those samples (a scheduled block only).
        """
        if scheduling is not None and scheduling.shape[:-1] != u.shape[:-1]:
            raise SchedulingError(f"{self.model.display_name}: scheduling {tuple(scheduling.shape)} must match "
                                  f"the inputs {tuple(u.shape)} but for its last dim")
        rho = self._check_scheduling(scheduling, u)
        if rho is None:
            norm = self._norm(u.dtype)
            y = apply_output(norm.c, norm.d, norm.g, states, u)
            return y + self.nonlinear_output(states, u) if self.model.has_nonlinear_output else y
        return apply_output(*self._output_rows(self._per_sample(rho)), states, u)

    def nonlinear_output(self, states: Tensor, u: Tensor | None) -> Tensor:
        """The nonlinear part of the outputs, ĥ = h(x, u) / σ_y (..., p), from normalized states (..., n)
        and inputs of the same samples (..., m; ``None`` for an h that reads none, ``output_reads_inputs``):
        what ``output`` adds to Ĉ x̂ + D̂ û + Ĝ for a system with ``output_nonlinearity`` (the output's
        mean is in Ĝ already). Differentiable in the states, the inputs and the trainable parameters."""
        dtype = states.dtype
        p = self.parameters_.values(self.model.parameter_names, dtype)
        x = states * self.state_std.to(dtype) + self.state_mean.to(dtype)
        u_phys = self.input_mean.to(dtype).expand(*states.shape[:-1], -1) if u is None else \
            u.to(dtype) * self.input_std.to(dtype) + self.input_mean.to(dtype)
        return self.model.output_nonlinearity(x, u_phys, p) / self.output_std.to(dtype)

    def _linearised_output(self, norm: NormalizedLTI, dtype: torch.dtype) -> Output:
        """Ĉ, D̂, Ĝ of the outputs linearised about the operating point (x̂ = 0, û = 0: the scaling's
        means): the linear part plus ĥ's slopes, its value there in Ĝ. What a nonlinear output's
        initial-state estimate starts from (``estimate_state``)."""
        n, m = self.model.n_states, len(self.model.input_names)
        x0, u0 = norm.c.new_zeros(n, dtype=dtype), norm.c.new_zeros(m, dtype=dtype)
        with torch.enable_grad():  # the slopes' values only: the estimate's start, refined afterwards
            jx, ju = torch.func.jacrev(self.nonlinear_output, argnums=(0, 1))(x0, u0)  # (p, n), (p, m)
        level = self.nonlinear_output(x0, u0)
        return norm.c + jx.detach(), norm.d + ju.detach(), norm.g + level.detach()

    def steady_state(self, u0: Tensor, scheduling: Tensor | None = None) -> Tensor:
        """Normalized equilibrium x̂ (B, n) for the constant normalized input û0 (B, m).

        0 = A x + B u + e gives x = -A⁻¹ (B u + e) in physical units (the same for either hold,
        which is exact for a constant input). A scheduled block takes ρ (B, q) to hold.
        """
        dtype = u0.dtype
        rho = self._check_scheduling(scheduling, u0)
        ss = self.state_space(dtype) if rho is None else self._per_sample(rho)
        u_phys = u0 * self.input_std.to(dtype) + self.input_mean.to(dtype)  # (B, m)
        force = (ss.b @ u_phys[..., None]).squeeze(-1)  # (B, n)
        if ss.e is not None:
            force = force + ss.e
        try:
            x = -torch.linalg.solve(ss.a, force[..., None]).squeeze(-1)  # (B, n)
        except RuntimeError as error:  # torch's singular-matrix error: name the block instead
            raise ValueError(f"{self.model.display_name} has no unique equilibrium (A is singular, e.g. an "
                             "integrator): start it from a measured or estimated state") from error
        return (x - self.state_mean.to(dtype)) / self.state_std.to(dtype)

    def estimate_state(self, u: Tensor, y: Tensor, observed: Tensor, scheduling: Tensor | None = None,
                       ridge: float = 1e-8) -> Tensor:
        """Least-squares state x̂_P (B, n) at the last sample P of a past window (``estimation``); a
        nonlinear block's refined on its own steps (``estimation.refine_first_state``).

        u: (B, >= P+1, m) normalized inputs from sample 0; y: (B, P+1, p) normalized outputs at
        samples 0..P (its length sets P; unobserved channels are never read); observed: (p,)
        bool; scheduling: (B, >= P+1, q) (a scheduled block). Only samples 0..P are read, and
        under a cubic hold û_{P+1} where given (else extrapolated, ``tap_inputs``).
        Differentiable in u, y and the trainable parameters.
        """
        past, (batch, n, p) = y.shape[1] - 1, (y.shape[0], self.model.n_states, len(self.model.output_names))
        given = u  # a cubic hold's x̂_P also reads û_{P+1}: taken where given
        observed = torch.as_tensor(observed, dtype=torch.bool, device=y.device)
        if past < 0 or u.shape[1] <= past or y.shape[-1] != p or observed.shape != (p,):
            raise ValueError(f"{self.model.display_name}.estimate_state needs y (B, P+1, {p}), u (B, >= P+1, m) "
                             f"and observed ({p},); got y {tuple(y.shape)}, u {tuple(u.shape)}, observed "
                             f"{tuple(observed.shape)}")
        if not n:
            return y.new_zeros(batch, 0)
        u = u[:, : past + 1]
        taps = self.tap_inputs(given, past) if past else u
        rho = self._check_scheduling(scheduling, u, past + 1)
        if rho is not None and self.model.is_nonlinear:
            raise SchedulingError(f"{self.model.display_name}: a nonlinear system cannot be scheduled yet")
        curved = self.model.has_nonlinear_output
        if rho is None:
            norm = self._norm(u.dtype)
            phi = norm.a.expand(1, past, n, n)
            forced = forced_terms(torch.cat([*norm.b_taps, norm.h[:, None]], -1), self.n_taps, taps, past)
            c, d, g = self._linearised_output(norm, u.dtype) if curved else (norm.c, norm.d, norm.g)
            c, offset = c[None, None], u @ d.T + g  # (1, 1, p, n), (B, P+1, p)
        else:
            ss = self._per_sample(rho[:, : past + 1])  # (B, P+1, ...)
            rows = self._state_rows(ss, past)  # (B, P, n, n + T m + 1)
            phi, forced = rows[..., :n], forced_terms(rows[..., n:], self.n_taps, taps, past)
            c, d, g = self._output_rows(ss)
            offset = (d @ u[..., None]).squeeze(-1) + g
        if not (self.model.is_nonlinear and past) and not curved:
            return estimate_last_state(phi, forced, c, offset, y, observed, ridge)
        # a Lur'e block or a nonlinear output: the linear(ised) part's x̂_0, refined on the block's own
        # steps and outputs over the past

        ahead = given[:, : past + 1 + self.form.lead]

        rows = None if self.model.is_nonlinear else torch.cat([norm.a, *norm.b_taps, norm.h[:, None]], -1)

        def outputs(states: Tensor, inputs: Tensor) -> Tensor:
            y = apply_output(norm.c, norm.d, norm.g, states, inputs)
            return y + self.nonlinear_output(states, inputs) if curved else y

        def run(starts: Tensor) -> tuple[Tensor, Tensor]:  # (K, n), K windows' starts -> ŷ_0..ŷ_P, x̂_P
            inputs = ahead.repeat_interleave(starts.shape[0] // u.shape[0], 0)  # each window's starts are adjacent
            if not past:
                return outputs(starts[:, None], inputs[:, :1]), starts
            later = simulate_from_rows(rows, self.n_taps, starts, self.tap_inputs(inputs, past)) if rows is not None \
                else self._simulate_nonlinear(starts, inputs, past)
            states = torch.cat([starts[:, None], later], 1)
            return outputs(states, inputs[:, : past + 1]), states[:, -1]

        start = estimate_last_state(phi, forced, c, offset, y, observed, ridge, first=True)
        if curved:
            return refine_first_state(run, start, y, observed, ridge, NONLINEAR_OUTPUT_STEPS, OUTPUT_HALVINGS)
        return refine_first_state(run, start, y, observed, ridge, GAUSS_NEWTON_STEPS)

    def simulate_physical(self, x0: Tensor | None, u: Tensor, scheduling: Tensor | None = None) -> Tensor:
        """``forward`` in physical units: normalize, simulate, de-normalize (x0 (B, n), u (B, L, m))."""
        dtype = u.dtype
        x0n = None if x0 is None else (x0 - self.state_mean.to(dtype)) / self.state_std.to(dtype)
        un = (u - self.input_mean.to(dtype)) / self.input_std.to(dtype)
        return self(x0n, un, scheduling) * self.output_std.to(dtype) + self.output_mean.to(dtype)

    def normalized_rows(self, scheduling: Tensor) -> Tensor:
        """[Â_j, B̂_{0,j}, ..., B̂_{T-1,j}, Ĥ_j] (B, K, n, n + T m + 1) at every sample of scheduling (B, K, q).

        What a scheduled block's step j uses (``scheduled.simulate_scheduled``); all samples are
        discretized in one batched matrix exponential.
        """
        rho = self._check_scheduling(scheduling, scheduling[..., :0])  # refuses an unscheduled block
        return self._state_rows(self._per_sample(rho), rho.shape[1])

    def sample_matrices(self, rho: Tensor, squarings: int) -> NormalizedLTI:
        """Â, B̂_t, Ĥ, Ĉ, D̂, Ĝ of a scheduled block at one sample of its scheduling signals ρ (q,) [SI].

        What step j of ``forward`` uses at ρ_j: the system's scalar ``matrices`` (the vmap path of
        ``per_sample_matrices``) and the free run's batched hold with its number of squarings
        given (``NormalizingMaps.state_rows``): no value of ρ is read on the host, so a traced
        one-step model (``hypa.export``) is the same graph for every ρ, accurate where
        ``sample_squarings(ρ) <= squarings`` and equal to the free run's where that run chose them.
        """
        ss, maps = self._sample_system(rho)
        n, m = ss.b.shape[-2:]
        out = maps.output_rows(ss.c, ss.d)
        if n:
            e = ss.a.new_zeros(n) if ss.e is None else ss.e  # a zero drift adds exact zeros; no traced `+ False`
            rows = maps.state_rows(ss.a[None], ss.b[None], e[None], squarings)[0]
        else:
            rows = rho.new_zeros(0, self.n_taps * m + 1)
        taps = tuple(rows[:, n + t * m : n + (t + 1) * m] for t in range(self.n_taps))
        return NormalizedLTI(a=rows[:, :n], b_taps=taps, h=rows[:, -1], c=out[:, :n], d=out[:, n:-1], g=out[:, -1])

    def sample_squarings(self, rho: Tensor) -> int:
        """The squarings the free run's hold takes for the sample ρ (q,) [SI] alone (a run shares its largest)."""
        ss, maps = self._sample_system(rho)
        n = ss.a.shape[-1]
        if not n:
            return 0
        f = maps.state_left @ ss.a @ maps.state_right[:n, :n]  # F = A dt, normalized
        return squarings_for(float(f.abs().sum(0).max()))

    def _sample_system(self, rho: Tensor) -> tuple[StateSpace, NormalizingMaps]:
        """A, B, C, D, e at ρ (q,) and the scaling's maps."""
        rho = self._check_scheduling(rho[None], rho[None, :0])[0]
        fixed = self.parameters_.values(self._fixed_names, rho.dtype) if self._fixed_names else {}
        ss = self.model.matrices({**fixed, **dict(zip(self.scheduled, rho.unbind(-1)))})
        return ss, self._normalizing_maps(rho.dtype, rho.device)

    # -- the two engines -------------------------------------------------------------------
    def _simulate(self, x0: Tensor | None, u: Tensor, scheduling: Tensor | None, steps: int,
                  before: Tensor | None = None) -> tuple[Tensor, Output | None]:
        """States x̂_{k+1..k+S} and the output matrices of those samples (None when y = x)."""
        n = self.model.n_states
        if x0 is None or x0.shape[-1] != n or x0.shape[0] != u.shape[0]:
            raise ValueError(f"{self.model.display_name} has {n} states: give an initial state (B, {n}), "
                             f"got {None if x0 is None else tuple(x0.shape)} for u {tuple(u.shape)}")
        rho = self._check_scheduling(scheduling, u, steps)
        same = self.model.outputs_are_states
        if self.model.is_nonlinear:
            if rho is not None:
                raise SchedulingError(f"{self.model.display_name}: a nonlinear system cannot be scheduled yet")
            norm = self._norm(u.dtype)
            return self._simulate_nonlinear(x0, u, steps, before), None if same else (norm.c, norm.d, norm.g)
        u_states = self.tap_inputs(u, steps, before)
        if rho is None:
            rebuild = self._rebuilds()
            if rebuild and steps == self.horizon:  # a training window of trainable physics: one graph node
                rows, norm = self._normalized(u.dtype)
                states = simulate_from_rows(rows, self.n_taps, x0, u_states)
            else:
                lifted, norm = self._lifted(u.dtype, rebuild)
                states = simulate_chunked(lifted, x0, u_states)
            return states, None if same else (norm.c, norm.d, norm.g)
        # step j reads ρ_j, the output at sample j too: ρ_0..ρ_S, the last held if not given (ZOH)
        rho = rho[:, : steps + (not same)]
        if rho.shape[1] == steps and not same:
            rho = torch.cat([rho, rho[:, -1:]], 1)
        rows, output = self._scheduled_rows(rho, steps)
        return simulate_scheduled(rows, self.n_taps, x0, u_states), output

    def _steps(self, u: Tensor) -> int:
        steps = u.shape[1] - self.extra_inputs
        if u.dim() != 3 or steps < 1:
            raise ValueError(f"{self.model.display_name} needs inputs (B, S + {self.extra_inputs}, m) with S >= 1, "
                             f"got {tuple(u.shape)}")
        return steps

    def _norm(self, dtype: torch.dtype) -> NormalizedLTI:
        """Â, B̂, Ĥ, Ĉ, D̂, Ĝ: rebuilt for trainable physics, else the cached ones."""
        rebuild = self._rebuilds()
        return self._normalized(dtype)[1] if rebuild else self._lifted(dtype, False)[1]

    def _check_scheduling(self, scheduling: Tensor | None, like: Tensor, samples: int = 0) -> Tensor | None:
        """``scheduling`` in ``like``'s dtype, checked against the block (None for an unscheduled block)."""
        name = self.model.display_name
        if not self.scheduled:
            if scheduling is not None:
                raise SchedulingError(f"{name} has no scheduled parameters but got scheduling signals")
            return None
        q = len(self.scheduled)
        if scheduling is None:
            raise SchedulingError(f"{name} schedules {list(self.scheduled)}: give scheduling (..., {q}) in SI units")
        if scheduling.shape[:-1] != like.shape[:-1] and (scheduling.dim() != 3 or scheduling.shape[0] != like.shape[0]):
            raise SchedulingError(f"{name}: scheduling {tuple(scheduling.shape)} does not fit inputs "
                                  f"{tuple(like.shape)}")
        if scheduling.shape[-1] != q or (samples and scheduling.shape[1] < samples):
            raise SchedulingError(f"{name}: scheduling must be (B, >= {samples or 'L'}, {q}) "
                                  f"for {list(self.scheduled)}, got {tuple(scheduling.shape)}")
        return scheduling.to(like.dtype)

    def _per_sample(self, rho: Tensor) -> StateSpace:
        fixed = self.parameters_.values(self._fixed_names, rho.dtype) if self._fixed_names else {}
        return per_sample_matrices(self.model, fixed, self.scheduled, rho)

    def _scheduled_rows(self, rho: Tensor, steps: int) -> tuple[Tensor, Output | None]:
        """The state rows of samples 0..steps-1 (B, steps, n, k) and, unless the outputs are the states, the
        output matrices of samples 1..steps: off the block's table where it has one (``_table``), else per sample."""
        same, n = self.model.outputs_are_states, self.model.n_states
        table = self._table(rho)
        if table is None:
            ss = self._per_sample(rho)
            if same:
                return self._state_rows(ss, steps), None
            c, d, g = self._output_rows(ss)
            return self._state_rows(ss, steps), (c[:, 1:], d[:, 1:], g[:, 1:])
        entries, m = table(rho[..., 0]), len(self.model.input_names)  # (B, L, E): the state rows, then the output rows
        width = n + self.n_taps * m + 1
        rows = entries[:, :steps, : n * width].reshape(rho.shape[0], steps, n, width)
        if same:
            return rows, None
        out = entries[:, 1 : steps + 1, n * width :].reshape(rho.shape[0], steps, -1, n + m + 1)
        return rows, (out[..., :n], out[..., n:-1], out[..., -1])

    def _state_rows(self, ss: StateSpace, steps: int) -> Tensor:
        """[Â_j, B̂_{t,j}, Ĥ_j] (B, steps, n, n + T m + 1) of samples 0..steps-1: one batched exponential
        (``NormalizingMaps.state_rows``: a view of its (n, k, B steps) layout, what ``simulate_scheduled`` reads)."""
        maps = self._normalizing_maps(ss.a.dtype, ss.a.device)
        if ss.a.shape[1] == steps:  # no slices: their backward would copy each gradient once more
            return maps.state_rows(ss.a, ss.b, ss.e)
        return maps.state_rows(ss.a[:, :steps], ss.b[:, :steps], ss.e[:, :steps])

    def _output_rows(self, ss: StateSpace) -> Output:
        n = self.model.n_states
        out = self._normalizing_maps(ss.c.dtype, ss.c.device).output_rows(ss.c, ss.d)
        return out[..., :n], out[..., n:-1], out[..., -1]
