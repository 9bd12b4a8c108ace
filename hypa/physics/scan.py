"""The parallel-prefix scan of affine steps x_{j+1} = Φ_j x_j + c_j, and its adjoint.

Composition of affine maps is associative, (f_j ∘ f_i)(x) = Φ_j Φ_i x + (Φ_j c_i + c_j), so all
prefix compositions come from a Hillis-Steele scan in ⌈log2 K⌉ batched levels instead of K
dependent steps (``affine_scan``). The scheduled block's states (``scheduled.simulate_scheduled``),
the nonlinear state estimate (``estimation``) and Newton over a sequence (``parallel``) run on it.
Its gradient is the same scan run backwards with the transposed products (``_AffineStates``).
"""

from __future__ import annotations

import torch
from torch import Tensor


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
    powers, c = _hillis_steele(phi.movedim((-2, -1), (0, 1)), c.movedim(-1, 0), prefix,  # (n, n, ..., K), (n, ..., K)
                               keep=torch.is_grad_enabled())  # without a graph, only the level in use is kept
    return powers[-1].movedim((0, 1), (-2, -1)), c.movedim(0, -1)


def _hillis_steele(phi: Tensor, c: Tensor, prefix: bool, keep: bool = True) -> tuple[list[Tensor], Tensor]:
    """The scan of ``affine_scan`` with the sample index laid out last: phi (n, n, ..., K), c (n, ..., K).

    Level l (offset d = 2^l) composes element j with element j - d: c_j <- P_l[j] c_{j-d} + c_j and
    P_{l+1}[j] = P_l[j] P_l[j-d], where P_l[j] = Φ_j ⋯ Φ_{max(0, j-d+1)} is the product over
    element j's span before the level. Both are one product, P_l[j] [c | P_l]_{j-d}, of the
    stacked columns [c | P_l] (n, 1 + n, ..., K) (``_level``); the last level, whose product
    only ``prefix`` wants, carries c alone. After ⌈log2 K⌉ levels c_j = g_j. Returns
    [P_0 = Φ, P_1, ...] (the last one F_j when ``prefix``) and g; with ``keep`` False only the
    last of them (a long scan without a graph holds one level, not log2 K).
    """
    if phi.shape[2:] != c.shape[1:]:  # one Φ sequence may serve a batch of c
        lead = torch.broadcast_shapes(phi.shape[2:], c.shape[1:])
        phi, c = phi.expand(*phi.shape[:2], *lead), c.expand(c.shape[0], *lead)
    return _scan(torch.cat([c[:, None], phi], 1), prefix, keep)


def _scan(z: Tensor, prefix: bool, keep: bool) -> tuple[list[Tensor], Tensor]:
    """``_hillis_steele``'s levels on its first columns z = [c | Φ] (n, 1 + n, ..., K)."""
    steps, offset = z.shape[-1], 1
    powers = [z[:, 1:]]
    while offset < steps:
        full = prefix or 2 * offset < steps  # is P_{l+1} needed?
        z = _level(z if full else z[:, :1], z[:, 1:, ..., offset:], offset)
        if full:
            powers.append(z[:, 1:])
            if not keep:
                del powers[0]
        offset *= 2
    return powers, z[:, 0]


def _level(src: Tensor, later: Tensor, offset: int) -> Tensor:
    """One scan level: z_j = P_l[j] src_{j-d} + [c_j, 0] for j >= d, src_j below (d = ``offset``).

    src (n, r, ..., K) are the stacked columns [c | P_l] (r = 1 + n) or [c] (r = 1), later
    (n, n, ..., K - d) the products P_l[j] of the elements j >= d. Taped: ``_compose`` and two
    cats; untaped: written into one new tensor by an ``addcmul`` chain, nothing else allocated.
    """
    tail = src[..., :-offset]
    if torch.is_grad_enabled():
        out = _compose(later, tail)
        return torch.cat([src[..., :offset], torch.cat([out[:, :1] + src[:, :1, ..., offset:], out[:, 1:]], 1)], -1)
    new = torch.empty_like(src)
    new[..., :offset] = src[..., :offset]
    out = new[..., offset:]
    torch.mul(later[:, 0, None], tail[0, None], out=out)
    for i in range(1, later.shape[1]):
        out.addcmul_(later[:, i, None], tail[i, None])
    out[:, 0].add_(src[:, 0, ..., offset:])  # (not +=, which would copy the result back through __setitem__)
    return new


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
