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
batched steps (``affine_scan``) instead of N dependent ones, and x̂_{j+1} = F_j(x̂_0): exact,
with gradients taped through the few batched products.
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

    Hillis-Steele scan: after the level with offset d, element j holds the composition of
    elements max(0, j - 2d + 1)..j; composing it with element j - d's doubles the span, so
    ⌈log2 K⌉ levels of batched products do it. The matrices are tiny, so the products are
    broadcast multiply-and-sums over the sample index laid out last (n, n, ..., K), not
    per-matrix ``bmm`` calls. ``prefix=False`` skips the last level's Φ product.
    """
    if phi.dim() != c.dim() + 1:
        raise ValueError(f"affine_scan needs phi (..., K, n, n) and c (..., K, n) with the same leading dims, "
                         f"got {tuple(phi.shape)} and {tuple(c.shape)}")
    phi, c = phi.movedim((-2, -1), (0, 1)), c.movedim(-1, 0)  # (n, n, ..., K), (n, ..., K)
    steps, offset = phi.shape[-1], 1
    while offset < steps:
        later = phi[..., offset:]
        c = torch.cat([c[..., :offset], (later * c[None, ..., :-offset]).sum(1) + c[..., offset:]], -1)
        if prefix or 2 * offset < steps:
            phi = torch.cat([phi[..., :offset], (later[:, :, None] * phi[None, ..., :-offset]).sum(1)], -1)
        offset *= 2
    return phi.movedim((0, 1), (-2, -1)), c.movedim(0, -1)


def forced_terms(v: Tensor, n_taps: int, u: Tensor, steps: int) -> Tensor:
    """c_j = Σ_t B̂_{t,j} û_{j+t} + Ĥ_j (B, steps, n), j = 0..steps-1.

    v: [B̂_0, ..., B̂_{T-1}, Ĥ] as (n, T m + 1) (constant) or (B, steps, n, T m + 1) (per step);
    u: (B, >= steps + T - 1, m).
    """
    window = torch.cat([*(u[:, t : t + steps] for t in range(n_taps)), u.new_ones(u.shape[0], steps, 1)], -1)
    if v.dim() == 2:
        return window @ v.T  # (B, steps, n)
    return (v @ window[..., None]).squeeze(-1)


def simulate_scheduled(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """States x̂_{1..S} (B, S, n) of x̂_{j+1} = Â_j x̂_j + Σ_t B̂_{t,j} û_{j+t} + Ĥ_j by ``affine_scan``.

    rows: (B, S, n, n + T m + 1) per-step [Â_j, B̂_{0,j}, ..., B̂_{T-1,j}, Ĥ_j]; x0: (B, n);
    u: (B, >= S + T - 1, m).
    """
    n, steps = x0.shape[-1], rows.shape[-3]
    phi = rows[..., :n]  # (B, S, n, n)
    c = forced_terms(rows[..., n:], n_taps, u, steps)  # (B, S, n)
    start = (phi[:, 0] @ x0[..., None]).squeeze(-1)  # x̂_0 folded into the first map
    c = torch.cat([(c[:, 0] + start)[:, None], c[:, 1:]], 1)
    return affine_scan(phi, c, prefix=False)[1]


def simulate_scheduled_recursive(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """The reference for ``simulate_scheduled``: one step after another (a python loop over samples)."""
    n, steps = x0.shape[-1], rows.shape[-3]
    c = forced_terms(rows[..., n:], n_taps, u, steps)
    x, out = x0, []
    for j in range(steps):
        x = (rows[:, j, :, :n] @ x[..., None]).squeeze(-1) + c[:, j]
        out.append(x)
    return torch.stack(out, 1)
