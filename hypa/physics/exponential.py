"""The matrix exponential and the φ-functions of small matrices and stacks of them, differentiable:
what every hold's discretization computes (``discretization``).

``hold_exponential`` takes the top rows of an augmented matrix [[A dt, G], [0, N]] and the hold's
constant bottom rows and returns e^M's top rows: ``expm`` of M for one system, the φ-functions
of A dt for a stack of them (one per sample of a scheduled block).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import torch
from torch import Tensor


def hold_exponential(generator: Tensor, bottom: Tensor) -> Tensor:
    """The top n rows [Φ, Ψ] (n, n + r) of e^M, M = [[F, G], [0, N]] = [generator; bottom] (k = n + r).

    generator [F, G] (n, k): F = A dt (n, n) and G (n, r), the system's and its held inputs'
    generator (rates times dt, dimensionless); bottom [0, N] (r, k): N the hold's input
    dynamics, a nilpotent constant. For a zero- or first-order hold N² = 0 (a ramp's value
    moves with its slope, the slope is constant; N = 0 when every input is held), so M^j =
    [[F^j, F^{j-1} G + F^{j-2} G N], [0, N^j]] and

        Φ = e^F = φ_0(F),        Ψ = Σ_{j>=1} (F^{j-1} G + F^{j-2} G N) / j! = φ_1(F) G + φ_2(F) G N

    with φ_k(F) = Σ_j F^j / (j + k)! (``phi_functions``). The one place every hold is computed,
    choosing between two exact ways (the same truncated series, equal to round-off):

    * one system (n, k): ``expm`` of M itself. A handful of k x k products, each a single tiny
      ``mm`` call whose cost is the call, not the flops: fewer calls than the φ-functions'
      three per squaring (the constant block rebuilds this every training step).
    * a stack (n, k, K), one system per sample of a scheduled block, the sample index last (the
      result too): the φ-functions of F and the two products above (``_HoldExponential``).
      n x n products only, where every op runs over all K samples so flops do count: for 2
      states and 2 inputs under a first-order hold (k = 7) about 40x fewer than exponentiating
      the stack of M, and the scaling reads ‖F‖ only. A hold with N² ≠ 0 (``cubic``) takes the
      stack of M itself (``_stacked``).
    """
    n, k = generator.shape[:2]
    if generator.dim() not in (2, 3) or k < n or bottom.shape != (k - n, k):
        raise ValueError(f"hold_exponential takes M's top rows (n, k) or a stack (n, k, K) and its bottom rows "
                         f"(k - n, k), got {tuple(generator.shape)} and {tuple(bottom.shape)}")
    if generator.dim() == 2:
        return expm(torch.cat([generator, bottom]))[:n]
    ramp = bottom[:, n:]
    if bool((ramp @ ramp).any()):
        return _PhiFunctions.apply(_stacked(generator, bottom), 0)[0][:n]
    return _HoldExponential.apply(generator, ramp if bool(ramp.any()) else None)  # N = 0: no φ_2 to compute


def _stacked(generator: Tensor, bottom: Tensor) -> Tensor:
    """The stack of M (k, k, K) from its top rows (n, k, K) and its constant bottom rows (k - n, k)."""
    rows = bottom.to(generator.dtype)[..., None].expand(*bottom.shape, generator.shape[-1])
    return torch.cat([generator, rows]).contiguous()


def hold_exponential_steps(generator: Tensor, bottom: Tensor, squarings: int) -> Tensor:
    """``hold_exponential`` of a stack (n, k, K) with a given number of squarings, no autograd node.

    The stack's own path reads ‖F‖ on the host to choose the squarings, a value a traced graph
    (an exported one-step model, ``hypa.export``) would freeze at its example; given, the graph
    is the same series for every F, accurate to the dtype's epsilon wherever ‖F‖_1 <= θ 2^s
    (``squarings_for``), and equal to the free run's where s is the one it chose.
    """
    n = generator.shape[0]
    ramp = bottom[:, n:]
    if bool((ramp @ ramp).any()):
        return _phi_forward(_stacked(generator, bottom), 0, squarings)[0][0][:n]
    return _hold_forward(generator, ramp if bool(ramp.any()) else None, squarings)[0]


def phi_functions(m: Tensor, order: int) -> tuple[Tensor, ...]:
    """φ_0(M), ..., φ_order(M) (order <= 2) of a square matrix (k, k) or a stack (..., k, k), differentiable.

    φ_0(M) = e^M,  φ_1(M) = Σ_j M^j / (j + 1)! = ∫_0^1 e^{M s} ds,  φ_2(M) = Σ_j M^j / (j + 2)!
    = ∫_0^1 e^{M s} (1 - s) ds: what a held input (φ_1) and a ramp (φ_2) add over a sample.
    Same algorithm and accuracy as ``expm`` (which is ``phi_functions(m, 0)[0]``), see ``_PhiFunctions``.
    """
    if m.dim() < 2 or m.shape[-1] != m.shape[-2]:
        raise ValueError(f"phi_functions takes a square matrix or a stack of them, got shape {tuple(m.shape)}")
    if order not in (0, 1, 2):
        raise ValueError(f"phi_functions computes φ_0 to φ_2, got order {order}")
    if m.dim() == 2:
        return _PhiFunctions.apply(m, order)
    stacked = m.reshape(-1, *m.shape[-2:]).permute(1, 2, 0).contiguous()  # (k, k, K): the stack index last
    return tuple(p.permute(2, 0, 1).reshape(m.shape) for p in _PhiFunctions.apply(stacked, order))


def expm(m: Tensor) -> Tensor:
    """e^M of a small square matrix (k, k) or a stack (..., k, k), differentiable; same values as
    ``torch.linalg.matrix_exp``.

    Scaling and squaring: e^M = (e^{M / 2^s})^{2^s} with s chosen so that ‖M / 2^s‖_1 <= 1/2,
    and e^X by its Taylor series in Horner form, truncated where the remainder bound
    ‖X‖^{q+1}/(q+1)! drops below the dtype's epsilon (q = 14 in float64, 7 in float32). The
    backward runs the same steps in reverse (see ``_PhiFunctions``). For a small matrix this
    is a few dozen tiny products, several times cheaper (forward and backward) than the
    general batched ``torch.linalg.matrix_exp``, which matters when the physics is rebuilt
    every training step. A stack shares one number of squarings, that of its largest norm
    (extra squarings of a smaller matrix cost a few ulps, not accuracy), so every step is one
    batched product: several times cheaper than ``matrix_exp``'s per-matrix Padé, forward and
    backward.
    """
    if m.dim() < 2 or m.shape[-1] != m.shape[-2]:
        raise ValueError(f"expm takes a square matrix or a stack of them, got shape {tuple(m.shape)}")
    return _PhiFunctions.apply(m, 0)[0] if m.dim() == 2 else phi_functions(m, 0)[0]


_THETA = 0.5  # ‖X‖_1 bound after scaling


def squarings_for(norm: float) -> int:
    """The squarings s of ``expm`` (and of the φ-functions) for a 1-norm ``norm``: the fewest with norm / 2^s <= θ."""
    return max(0, math.ceil(math.log2(norm / _THETA))) if norm > 0 else 0


@functools.cache
def _taylor_degree(dtype: torch.dtype, order: int = 0) -> int:
    """The degree q of the Taylor series of φ_order at ‖X‖ <= θ: its remainder bound θ^{q+1}/(q+1+order)!
    below the dtype's epsilon (exp: 14 in float64, 7 in float32)."""
    eps, q = torch.finfo(dtype).eps, 1
    while _THETA ** (q + 1) / math.factorial(q + 1 + order) > eps:
        q += 1
    return q


def _addmm(c: Tensor | None, a: Tensor, b: Tensor, alpha: float = 1.0, beta: float = 1.0) -> Tensor:
    """β c + α a b for one matrix (k, l), or for a stack laid out (k, l, K), index last (c None: β = 0).

    A stack's product is Σ_j a[:, j] ⊗ b[j], one ``addcmul`` per j over the whole stack (every op
    a long contiguous vector): several times faster for thousands of small matrices than a
    batched ``bmm``, whose cost is a per-matrix call, and about 1.5x faster than one broadcast
    multiply (k, l, l', K) and its sum.
    """
    if a.dim() == 2:
        if c is None or beta == 0:
            return torch.mm(a, b) if alpha == 1 else alpha * torch.mm(a, b)
        return torch.addmm(c, a, b, beta=beta, alpha=alpha)
    out = None if c is None or beta == 0 else (c if beta == 1 else beta * c)
    for j in range(a.shape[1]):
        if out is None:
            out = a[:, j : j + 1] * b[j : j + 1] if alpha == 1 else (alpha * a[:, j : j + 1]) * b[j : j + 1]
        else:
            out = torch.addcmul(out, a[:, j : j + 1], b[j : j + 1], value=alpha)
    return out


def _t(a: Tensor) -> Tensor:
    """The transpose of one matrix or of every matrix of a (k, k, K) stack."""
    return a.transpose(0, 1)


class _PhiFunctions(torch.autograd.Function):
    """φ_0(M), ..., φ_p(M) (p = ``order``) of m (k, k) or a stack (k, k, K): ``_phi_forward``,
    adjoint ``_phi_backward``."""

    @staticmethod
    def forward(ctx, m: Tensor, order: int) -> tuple[Tensor, ...]:  # type: ignore[override]
        phis, saved, ctx.steps = _phi_forward(m, order)
        ctx.save_for_backward(*saved)
        return tuple(phis)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, *grads: Tensor | None) -> tuple[Tensor, None]:  # type: ignore[override]
        return _phi_backward(ctx.saved_tensors, ctx.steps, list(grads)), None


class _HoldExponential(torch.autograd.Function):
    """[φ_0(F), φ_1(F) G + φ_2(F) G N] from [F, G] (n, n + r) or a stack (n, n + r, K) and N (r, r)
    (None: N = 0, φ_2 not needed), for ``hold_exponential``.

    One graph node: the backward is dL/dG = φ_1ᵀ Ψ̄ + N (φ_2ᵀ Ψ̄) (N applied to each row's columns),
    dL/dφ_1 = Ψ̄ Gᵀ, dL/dφ_2 = Ψ̄ (G N)ᵀ, then ``_phi_backward`` for dL/dF (Ψ̄ = dL/dΨ).
    """

    @staticmethod
    def forward(ctx, generator: Tensor, ramp: Tensor | None) -> Tensor:  # type: ignore[override]
        top, (g, ramped, phis, saved, ctx.steps) = _hold_forward(generator, ramp)
        ctx.save_for_backward(g, ramp, ramped, *phis[1:], *saved)
        return top

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None]:  # type: ignore[override]
        g, ramp, ramped, *rest = ctx.saved_tensors
        n, order, grad = grad.shape[0], ctx.steps[0], grad.contiguous()  # the stack index last in memory too
        (phi_1, *phi_2), saved = rest[:order], rest[order:]
        grad_phi, grad_psi = grad[:, :n], grad[:, n:]
        grads = [grad_phi, _addmm(None, grad_psi, _t(g))]
        grad_g = _addmm(None, _t(phi_1), grad_psi)
        if ramp is not None:
            grads.append(_addmm(None, grad_psi, _t(ramped)))
            grad_g = grad_g + _right(_addmm(None, _t(phi_2[0]), grad_psi), ramp.T)
        return torch.cat([_phi_backward(saved, ctx.steps, grads), grad_g], 1), None


def _hold_forward(generator: Tensor, ramp: Tensor | None, squarings: int | None = None) -> tuple[Tensor, tuple]:
    """``_HoldExponential``'s values [Φ, Ψ] and what its backward needs (G, G N, the φ's, ``_phi_forward``'s)."""
    n = generator.shape[0]
    f, g = generator[:, :n], generator[:, n:]
    phis, saved, steps = _phi_forward(f, 1 if ramp is None else 2, squarings)
    psi = _addmm(None, phis[1], g)
    ramped = None if ramp is None else _right(g, ramp)  # G N
    if ramped is not None:
        psi = _addmm(psi, phis[2], ramped)
    return torch.cat([phis[0], psi], 1), (g, ramped, phis, saved, steps)


def _right(a: Tensor, b: Tensor) -> Tensor:
    """a b for a (n, r) or a stack (n, r, K) and a constant b (r, s): each matrix of the stack times b."""
    return a @ b if a.dim() == 2 else torch.matmul(b.T, a)  # row i of a stack: (bᵀ a[i]) (s, K)


def _phi_forward(m: Tensor, order: int, squarings: int | None = None
                 ) -> tuple[list[Tensor], list[Tensor], tuple]:
    """φ_0(M), ..., φ_p(M) (p = ``order``) by scaling, Horner and doubling, and what ``_phi_backward`` needs:

        X = M / 2^s;   T_q = I,  T_{j-1} = I + X T_j / (j + p)  (j = q..1),  φ_p(X) = T_0 / p!
        φ_{k-1}(X) = I / (k-1)! + X φ_k(X)                        (k = p..1)
        doubling (s times, E = φ_0 + I):  φ_0 <- φ_0²,  φ_1 <- φ_1 E / 2,  φ_2 <- (φ_1 + φ_2 E) / 4

    (the doublings are e^{2X} = (e^X)², (e^{2z} - 1)/(2z) = (e^z - 1)(e^z + 1)/(2z) and its
    next term; for p = 0 this is ``expm``'s scaling and squaring exactly). m is one matrix (k, k)
    or a stack (k, k, K) (``_addmm``) sharing s (its largest norm's). Returns the φ's, the
    tensors to save and (p, q, s) (q None where ‖M‖ is not finite: NaN out, NaN gradients back).
    """
    eye = torch.eye(m.shape[0], dtype=m.dtype, device=m.device)
    eye = eye if m.dim() == 2 else eye[..., None].expand_as(m)
    if squarings is not None:  # noqa: SIM108 -- given (``hold_exponential_steps``): no host sync, nothing read from the values
        norm = 0.0
    else:
        norm = float(m.abs().sum(0).max()) if m.numel() else 0.0  # ‖M‖_1, the largest of a stack: a host sync
    if not math.isfinite(norm):  # no series converges
        return [torch.full_like(m, math.nan) for _ in range(order + 1)], [m], (order, None, 0)
    if squarings is None:
        squarings = squarings_for(norm)
    x = m / 2**squarings
    horner = [eye]  # T_q, ..., T_0
    for j in range(_taylor_degree(m.dtype, order), 0, -1):
        horner.append(_addmm(eye, x, horner[-1], alpha=1.0 / (j + order)))
    phis = [horner[-1] if order < 2 else horner[-1] / 2]  # φ_p, then φ_{p-1}, ..., φ_0 in front
    for k in range(order, 0, -1):
        phis.insert(0, _addmm(eye if k == 1 else eye / math.factorial(k - 1), x, phis[0]))
    levels = [phis]  # (φ_0, ..., φ_p) after 0, ..., s doublings
    for _ in range(squarings):
        levels.append(_double(levels[-1], eye))
    saved = [x, *horner[:-1], *phis[1:], *(p for level in levels[:-1] for p in level)]
    return levels[-1], saved, (order, len(horner) - 1, squarings)


def _phi_backward(saved: Sequence[Tensor], steps: tuple, grads: list[Tensor | None]) -> Tensor:
    """dL/dM from dL/dφ_k (None: 0) by the steps of ``_phi_forward`` in reverse: each product P = U V
    gives dL/dU = P̄ Vᵀ, dL/dV = Uᵀ P̄, so this is the derivative of the truncated series, accurate
    to the same epsilon as the values."""
    order, degree, squarings = steps
    x = saved[0]
    if degree is None:
        return torch.full_like(x, math.nan)
    horner, lower, flat = saved[1 : degree + 1], saved[degree + 1 : degree + 1 + order], saved[degree + 1 + order :]
    levels = [flat[i : i + order + 1] for i in range(0, len(flat), order + 1)]  # (φ_0, ..., φ_p) before each doubling
    eye = torch.eye(x.shape[0], dtype=x.dtype, device=x.device)
    eye = eye if x.dim() == 2 else eye[..., None].expand_as(x)
    g = [torch.zeros_like(x) if gr is None else gr.contiguous() for gr in grads]
    for level in reversed(levels):  # the doublings, last first
        g = _double_adjoint(level, g, eye)
    x_t, grad_x = _t(x), torch.zeros_like(x)
    for k in range(1, order + 1):  # φ_{k-1} = I/(k-1)! + X φ_k, φ_0 made last; lower = φ_1..φ_p at X
        grad_x = _addmm(grad_x, g[k - 1], _t(lower[k - 1]))
        g[k] = _addmm(g[k], x_t, g[k - 1])
    grad, scale = (g[order] if order < 2 else g[order] / 2), 1.0  # dL/dT_0; dL/dT_j = scale · grad
    for j, t in enumerate(reversed(horner), start=1):  # T_{j-1} = I + X T_j / (j + p)
        alpha = 1.0 / (j + order)
        grad_x = _addmm(grad_x, grad, _t(t), alpha=alpha * scale)
        if j < len(horner):
            grad, scale = _addmm(None, x_t, grad), scale * alpha
    return grad_x / 2**squarings


def _double(phis: list[Tensor], eye: Tensor) -> list[Tensor]:
    """(φ_0, ..., φ_p) at 2X from those at X: φ_0², φ_1 E / 2, (φ_1 + φ_2 E) / 4 with E = φ_0 + I."""
    p0, out = phis[0], [_addmm(None, phis[0], phis[0])]
    if len(phis) > 1:
        e = p0 + eye
        out.append(_addmm(None, phis[1], e, alpha=0.5))
    if len(phis) > 2:
        out.append(_addmm(phis[1], phis[2], e, alpha=0.25, beta=0.25))
    return out


def _double_adjoint(phis: Sequence[Tensor], grads: list[Tensor], eye: Tensor) -> list[Tensor]:
    """dL/d(φ_0, ..., φ_p) at X from dL/d(φ_0, ..., φ_p) at 2X (``_double`` reversed)."""
    p0_t = _t(phis[0])
    out = [_addmm(_addmm(None, grads[0], p0_t), p0_t, grads[0])]  # φ_0² -> G φ_0ᵀ + φ_0ᵀ G
    if len(phis) > 1:
        e_t = _t(phis[0] + eye)
        out.append(_addmm(None, grads[1], e_t, alpha=0.5))  # φ_1 E / 2
        out[0] = _addmm(out[0], _t(phis[1]), grads[1], alpha=0.5)
    if len(phis) > 2:
        out[1] = out[1] + 0.25 * grads[2]  # (φ_1 + φ_2 E) / 4
        out.append(_addmm(None, grads[2], e_t, alpha=0.25))
        out[0] = _addmm(out[0], _t(phis[2]), grads[2], alpha=0.25)
    return out
