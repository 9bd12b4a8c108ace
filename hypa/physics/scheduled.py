"""Scheduled (linear parameter-varying) physics: matrices that change every sample with a measured signal.

A scheduled parameter (a vehicle's velocity) follows a measured signal ρ instead of staying
constant. The block holds ρ like a zero-order hold: over sample j (t_j <= t < t_{j+1}) the
continuous matrices are those at ρ_j, so step j -> j+1 is the exact discretization, with the
block's input hold, of A(ρ_j), B(ρ_j), e(ρ_j), and eq. 5 gets per-sample matrices:

    x̂_{j+1} = Â_j x̂_j + Σ_t B̂_{t,j} û_{j+t} + Ĥ_j,        ŷ_j = Ĉ_j x̂_j + D̂_j û_j + Ĝ_j

(the output matrices at ρ_j, the sample they belong to). Freezing the matrices over a sample is
the only approximation: a ρ that moves within a sample is seen as a staircase, a first-order
error in dt dρ/dt. Measured for the velocity-scheduled single track (dt = 1/32 s, v ramping
5 -> 30 m/s in 4 s, i.e. 6.25 m/s², random steering) against a reference of 64 exact substeps
per sample with v interpolated linearly: 0.45 % (ZOH) / 0.49 % (FOH) of the states' RMS
(``test_physics_scheduled``); it shrinks in proportion to dt dρ/dt, and at a constant ρ the
scheduled block is exact.

The lifted form (eq. 9-11) needs one Â; here every step has its own. The steps are the affine
maps f_j(x) = Φ_j x + c_j (c_j = Σ_t B̂_{t,j} û_{j+t} + Ĥ_j), and composition is associative,

    (f_j ∘ f_i)(x) = Φ_j Φ_i x + (Φ_j c_i + c_j),

so all prefix compositions F_j = f_j ∘ ... ∘ f_0 come from a parallel-prefix scan in ⌈log2 N⌉
batched steps (``affine_scan``) instead of N dependent ones, and x̂_{j+1} = F_j(x̂_0): exact.
Its gradient is the adjoint recursion run as the same scan backwards, reusing the forward's
products (``_AffineStates``). Cost at N = 100, batch 32 (``python -m hypa.bench``): the vmap
of the system's code (``per_sample_matrices``), the batched hold (``NormalizingMaps.state_rows``,
φ-functions of the n x n A dt) and the scan take about a third of the forward each; the scan
is about 4x faster than a python loop over the samples forward, and its hand-written adjoint
over 10x faster than differentiating that loop.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import torch
from torch import Tensor

if TYPE_CHECKING:
    from hypa.physics.lti import LTIModel, StateSpace


class SchedulingError(ValueError):
    """Scheduling signals that do not fit a block, or matrices that cannot be evaluated per sample."""


def per_sample_matrices(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str],
                        rho: Tensor) -> StateSpace:
    """A, B, C, D, e of ``model`` at every sample of ``rho`` (..., q): each (..., rows, cols), e (..., n).

    ``matrices`` is the user's scalar code; ``torch.func.vmap`` evaluates it for all samples at
    once, with the scheduled parameters taken from ``rho`` (in the order of ``scheduled``) and the
    others from ``fixed`` (scalars, trainable ones with their graph). e is zeros where None.
    """
    from hypa.physics.lti import StateSpace

    lead, flat = rho.shape[:-1], rho.reshape(-1, rho.shape[-1])  # (K, q)

    def one(r: Tensor) -> tuple[Tensor, ...]:
        ss = model.matrices({**fixed, **dict(zip(scheduled, r.unbind()))})
        e = ss.e if ss.e is not None else ss.a.new_zeros(ss.a.shape[-1])
        return ss.a, ss.b, ss.c, ss.d, e

    try:
        mats = torch.func.vmap(one)(flat)
    except Exception as error:  # a user's code: say which call failed, in one line
        raise SchedulingError(f"{type(model).__name__}.matrices cannot be evaluated per sample with "
                              f"torch.func.vmap for scheduled {list(scheduled)}: {type(error).__name__}: "
                              f"{str(error).splitlines()[0] if str(error) else ''}") from error
    return StateSpace(*(m.reshape(*lead, *m.shape[1:]) for m in mats))


def affine_scan(phi: Tensor, c: Tensor, prefix: bool = True) -> tuple[Tensor, Tensor]:
    """All prefix compositions of the affine maps x -> Φ_j x + c_j, j = 0..K-1.

    phi: (..., K, n, n), c: (..., K, n); leading dims broadcast (one Φ sequence may serve a
    batch of c). Returns F_j = Φ_j ⋯ Φ_0 (..., K, n, n) and g_j (..., K, n) with
    f_j ∘ ... ∘ f_0 (x) = F_j x + g_j, so g_j is the state after step j started from 0.

    Hillis-Steele scan (``_hillis_steele``), differentiated by autograd. ``prefix=False`` skips
    the last level's Φ product (F_j is then not the full prefix: use g only).
    """
    if phi.dim() != c.dim() + 1:
        raise ValueError(f"affine_scan needs phi (..., K, n, n) and c (..., K, n) with the same leading dims, "
                         f"got {tuple(phi.shape)} and {tuple(c.shape)}")
    powers, c = _hillis_steele(phi.movedim((-2, -1), (0, 1)), c.movedim(-1, 0), prefix)  # (n, n, ..., K), (n, ..., K)
    return powers[-1].movedim((0, 1), (-2, -1)), c.movedim(0, -1)


def _hillis_steele(phi: Tensor, c: Tensor, prefix: bool) -> tuple[list[Tensor], Tensor]:
    """The scan of ``affine_scan`` with the sample index laid out last: phi (n, n, ..., K), c (n, ..., K).

    Level l (offset d = 2^l) composes element j with element j - d: c_j <- P_l[j] c_{j-d} + c_j and
    P_{l+1}[j] = P_l[j] P_l[j-d], where P_l[j] = Φ_j ⋯ Φ_{max(0, j-d+1)} is the product over
    element j's span before the level. After ⌈log2 K⌉ levels c_j = g_j. The matrices are tiny,
    so the products are ``addcmul`` chains over the sample index laid out last, not per-matrix
    ``bmm`` calls. Returns [P_0 = Φ, P_1, ...] (the last one F_j when ``prefix``) and g.
    """
    steps, offset, powers = phi.shape[-1], 1, [phi]
    while offset < steps:
        later = powers[-1][..., offset:]
        c = torch.cat([c[..., :offset], _apply(later, c[..., :-offset], c[..., offset:])], -1)
        if prefix or 2 * offset < steps:
            powers.append(torch.cat([powers[-1][..., :offset], _compose(later, powers[-1][..., :-offset])], -1))
        offset *= 2
    return powers, c


def _apply(a: Tensor, x: Tensor, plus: Tensor | None = None) -> Tensor:
    """a x (+ plus) for matrices a (n, l, ...) and vectors x (l, ...): the same trailing (sample) dims.

    Taped (autograd on): one broadcast multiply and sum, two graph nodes with a cheap backward;
    untaped (inside ``_AffineStates``): an ``addcmul`` chain over l, faster for tiny l.
    """
    if torch.is_grad_enabled():
        out = (a * x[None]).sum(1)
        return out if plus is None else out + plus
    out = plus
    for i in range(a.shape[1]):
        out = a[:, i] * x[i] if out is None else torch.addcmul(out, a[:, i], x[i])
    return out


def _compose(a: Tensor, b: Tensor) -> Tensor:
    """a b for matrices a (n, l, ...), b (l, k, ...), the same trailing dims (taped or not as ``_apply``)."""
    if torch.is_grad_enabled():
        return (a[:, :, None] * b[None]).sum(1)
    out = None
    for i in range(a.shape[1]):
        out = a[:, i, None] * b[i, None] if out is None else torch.addcmul(out, a[:, i, None], b[i, None])
    return out


class _AffineStates(torch.autograd.Function):
    """g_j = Φ_j g_{j-1} + c_j (g_{-1} = 0) for phi (n, n, ..., S), c (n, ..., S): the scan's states, with its adjoint.

    The forward is ``_hillis_steele``. The adjoint of the recursion is the same recursion run
    backwards with the transposed matrices,

        λ_j = γ_j + Φ_{j+1}ᵀ λ_{j+1},    dL/dc_j = λ_j,    dL/dΦ_j = λ_j g_{j-1}ᵀ    (γ = dL/dg)

    and its Hillis-Steele scan needs, at the level with offset d, (Φ_{j+d} ⋯ Φ_{j+1})ᵀ: the
    forward's P_l[j + d], transposed. So the backward reuses the forward's products and adds
    only matrix-vector steps, λ_j <- λ_j + P_l[j+d]ᵀ λ_{j+d} for l = 0, 1, ..., and one outer
    product: several times cheaper than differentiating the taped forward, product by product.
    """

    @staticmethod
    def forward(ctx, phi: Tensor, c: Tensor) -> Tensor:  # type: ignore[override]
        powers, states = _hillis_steele(phi, c, prefix=False)
        ctx.save_for_backward(states, *powers)
        return states

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> tuple[Tensor, Tensor]:  # type: ignore[override]
        states, *powers = ctx.saved_tensors
        adjoint, steps = grad.clone(memory_format=torch.contiguous_format), grad.shape[-1]
        for level, power in enumerate(powers):
            offset = 2**level
            if offset >= steps:
                break
            adjoint[..., :-offset] += _apply(power[..., offset:].transpose(0, 1), adjoint[..., offset:])
        grad_phi = torch.zeros_like(powers[0])
        grad_phi[..., 1:] = adjoint[:, None, ..., 1:] * states[None, :, ..., :-1]
        return grad_phi, adjoint


def forced_terms(v: Tensor, n_taps: int, u: Tensor, steps: int) -> Tensor:
    """c_j = Σ_t B̂_{t,j} û_{j+t} + Ĥ_j (B, steps, n), j = 0..steps-1.

    v: [B̂_0, ..., B̂_{T-1}, Ĥ] as (n, T m + 1) (constant) or (B, steps, n, T m + 1) (per step);
    u: (B, >= steps + T - 1, m). Per step, the sum runs with the sample index laid out last (a
    (B, steps, n) view of an (n, B, steps) tensor comes back): ``NormalizingMaps.state_rows``
    lays its stacks out that way, so no copy is made.
    """
    if v.dim() == 2:
        window = torch.cat([*(u[:, t : t + steps] for t in range(n_taps)), u.new_ones(u.shape[0], steps, 1)], -1)
        return window @ v.T  # (B, steps, n)
    last = u.permute(2, 0, 1)  # (m, B, L)
    window = torch.cat([*(last[..., t : t + steps] for t in range(n_taps)), u.new_ones(1, u.shape[0], steps)])
    return _apply(v.movedim((-2, -1), (0, 1)), window).movedim(0, -1)  # (n, B, steps) -> (B, steps, n)


def simulate_scheduled(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """States x̂_{1..S} (B, S, n) of x̂_{j+1} = Â_j x̂_j + Σ_t B̂_{t,j} û_{j+t} + Ĥ_j by a parallel-prefix scan.

    rows: (B, S, n, n + T m + 1) per-step [Â_j, B̂_{0,j}, ..., B̂_{T-1,j}, Ĥ_j]; x0: (B, n);
    u: (B, >= S + T - 1, m). x̂_0 is folded into the first step's forced term, then the states
    are ``_AffineStates`` (the scan of ``affine_scan`` with a hand-written adjoint).
    """
    n, steps = x0.shape[-1], rows.shape[-3]
    phi, v = rows.split([n, rows.shape[-1] - n], -1)  # one graph node (its backward one cat), not two slices
    phi = phi.movedim((-2, -1), (0, 1))  # (n, n, B, S)
    c = forced_terms(v, n_taps, u, steps).movedim(-1, 0)  # (n, B, S)
    start = _apply(phi[..., 0], x0.T, c[..., 0])  # x̂_0 folded into the first map
    c = torch.cat([start[..., None], c[..., 1:]], -1)
    return _AffineStates.apply(phi.expand(n, n, *c.shape[1:]), c).movedim(0, -1)


def simulate_scheduled_recursive(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """The reference for ``simulate_scheduled``: one step after another (a python loop over samples)."""
    n, steps = x0.shape[-1], rows.shape[-3]
    c = forced_terms(rows[..., n:], n_taps, u, steps)
    x, out = x0, []
    for j in range(steps):
        x = (rows[:, j, :, :n] @ x[..., None]).squeeze(-1) + c[:, j]
        out.append(x)
    return torch.stack(out, 1)
