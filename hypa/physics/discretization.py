"""Exact discretization of continuous LTI systems by the matrix exponential (differentiable).

Both holds come from one matrix exponential of an augmented matrix, so gradients flow back
through ``expm`` to the physical parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

Hold = Literal["zoh", "foh"]
HOLDS: tuple[str, ...] = ("zoh", "foh")


@dataclass(frozen=True)
class DiscreteLTI:
    """x_{k+1} = Φ x_k + Γ_0 u_k + Γ_1 u_{k+1} + γ  (Γ_1 = 0 for a zero-order hold).

    ``taps[t]`` multiplies u_{k+t}; a zero-order hold has one tap, a first-order hold two.
    ``drift`` γ = ∫_0^dt e^{Aτ} dτ e is the constant drift e over one sample (None: e = 0).
    """

    phi: Tensor  # (n, n)
    taps: tuple[Tensor, ...]  # each (n, m)
    hold: str
    drift: Tensor | None = None  # (n,)

    @property
    def input_gain(self) -> Tensor:
        """Σ_t Γ_t: the map from a constant input to the next state (n, m)."""
        return sum(self.taps[1:], self.taps[0])


def discretize(a: Tensor, b: Tensor, dt: float, hold: Hold = "zoh", e: Tensor | None = None) -> DiscreteLTI:
    """Discretize dx/dt = A x + B u + e with sample time ``dt`` [s].

    zoh: u is held constant over a sample;  expm([[A, B], [0, 0]] dt) = [[Φ, Γ], [0, I]].

    foh: u is linear between samples (a smooth input sampled fast is much closer to this);
    with F = A dt, G = B dt,  expm([[F, G, 0], [0, 0, I], [0, 0, 0]]) = [[Φ, E_1, E_2], ...]
    where E_1 = ∫_0^dt e^{Aτ} dτ B and E_2 = (1/dt) ∫_0^dt e^{Aτ} (dt - τ) dτ B, so
    x_{k+1} = Φ x_k + (E_1 - E_2) u_k + E_2 u_{k+1}.

    A drift e (n,) is an input held at 1, the same under either hold: it is discretized as one
    more input column, whose taps sum to γ = ∫_0^dt e^{Aτ} dτ e.
    """
    if e is not None:
        system = discretize(a, torch.cat([b, e[:, None]], dim=-1), dt, hold)
        taps = tuple(t[:, :-1] for t in system.taps)
        return DiscreteLTI(system.phi, taps, hold, drift=sum(t[:, -1] for t in system.taps))
    if hold not in HOLDS:
        raise ValueError(f"unknown hold {hold!r}; choose one of {', '.join(HOLDS)}")
    if not dt > 0:
        raise ValueError(f"sample time must be positive, got {dt}")
    n, m = b.shape[-2], b.shape[-1]
    if a.shape[-2:] != (n, n):
        raise ValueError(f"A must be ({n}, {n}) to match B {tuple(b.shape)}, got {tuple(a.shape)}")
    opts = dict(dtype=a.dtype, device=a.device)
    if hold == "zoh":
        top = torch.cat([a, b], dim=-1) * dt
        aug = torch.cat([top, torch.zeros(m, n + m, **opts)], dim=-2)
        e = expm(aug)
        return DiscreteLTI(phi=e[:n, :n], taps=(e[:n, n:],), hold=hold)
    top = torch.cat([a * dt, b * dt, torch.zeros(n, m, **opts)], dim=-1)
    mid = torch.cat([torch.zeros(m, n + m, **opts), torch.eye(m, **opts)], dim=-1)
    aug = torch.cat([top, mid, torch.zeros(m, n + 2 * m, **opts)], dim=-2)
    e = expm(aug)
    e1, e2 = e[:n, n : n + m], e[:n, n + m :]
    return DiscreteLTI(phi=e[:n, :n], taps=(e1 - e2, e2), hold=hold)


def expm(m: Tensor) -> Tensor:
    """e^M of a small square matrix (k, k) or a stack (..., k, k), differentiable; same values as
    ``torch.linalg.matrix_exp``.

    Scaling and squaring: e^M = (e^{M / 2^s})^{2^s} with s chosen so that ‖M / 2^s‖_1 <= 1/2,
    and e^X by its Taylor series in Horner form, truncated where the remainder bound
    ‖X‖^{q+1}/(q+1)! drops below the dtype's epsilon (q = 14 in float64, 7 in float32). The
    backward runs the same steps in reverse (see ``_MatrixExp``). For the 4x4 or 6x6 matrix
    of a hold this is a few dozen tiny products, several times cheaper (forward and backward)
    than the general batched ``torch.linalg.matrix_exp``, which matters when the physics is
    rebuilt every training step. A stack (one system per sample of a scheduled block) shares
    one number of squarings, that of its largest norm (extra squarings of a smaller matrix cost
    a few ulps, not accuracy), so every step is one batched product: several times cheaper than
    ``matrix_exp``'s per-matrix Padé, forward and backward.
    """
    if m.dim() < 2 or m.shape[-1] != m.shape[-2]:
        raise ValueError(f"expm takes a square matrix or a stack of them, got shape {tuple(m.shape)}")
    if m.dim() == 2:
        return _MatrixExp.apply(m)
    stacked = m.reshape(-1, *m.shape[-2:]).permute(1, 2, 0).contiguous()  # (k, k, K): the stack index last
    return _MatrixExp.apply(stacked).permute(2, 0, 1).reshape(m.shape)


_THETA = 0.5  # ‖X‖_1 bound after scaling


def _taylor_degree(dtype: torch.dtype) -> int:
    eps, q = torch.finfo(dtype).eps, 1
    while _THETA ** (q + 1) / math.factorial(q + 1) > eps:
        q += 1
    return q


def _addmm(c: Tensor, a: Tensor, b: Tensor, alpha: float = 1.0, beta: float = 1.0) -> Tensor:
    """β c + α a b for one matrix (k, k), or for a stack laid out (k, k, K), index last.

    Products of thousands of 5x5 matrices are several times faster as broadcast multiply-and-
    sum over such a stack (every op a long contiguous vector) than as a batched ``bmm``, whose
    cost is a per-matrix call.
    """
    if a.dim() == 2:
        return torch.addmm(c, a, b, beta=beta, alpha=alpha)
    product = (a[:, :, None] * b[None]).sum(1)  # (k, k, K)
    return alpha * product if beta == 0 else beta * c + alpha * product


def _t(a: Tensor) -> Tensor:
    """The transpose of one matrix or of every matrix of a (k, k, K) stack."""
    return a.transpose(0, 1)


class _MatrixExp(torch.autograd.Function):
    """E = e^M by scaling, Horner and squaring, with the adjoint of exactly those steps:

        X = M / 2^s;  T_q = I,  T_{j-1} = I + X T_j / j  (j = q..1);  E_0 = T_0,  E_{i+1} = E_i²
        dL/dE_i = E_iᵀ G + G E_iᵀ  (G = dL/dE_{i+1});   dL/dX = Σ_j (G_{j-1} T_jᵀ) / j,
        dL/dT_j = Xᵀ G_{j-1} / j;   dL/dM = dL/dX / 2^s

    which is the derivative of the truncated series, accurate to the same epsilon as E.
    m is one matrix (k, k) or a stack (k, k, K) (``_addmm``) sharing s (its largest norm's).
    """

    @staticmethod
    def forward(ctx, m: Tensor) -> Tensor:  # type: ignore[override]
        eye = torch.eye(m.shape[0], dtype=m.dtype, device=m.device)
        eye = eye if m.dim() == 2 else eye[..., None].expand_as(m)
        norm = float(m.abs().sum(0).max()) if m.numel() else 0.0  # ‖M‖_1, the largest of a stack: a host sync
        if not math.isfinite(norm):  # no series converges: NaN out, NaN gradients back
            ctx.degree = None
            return torch.full_like(m, math.nan)
        squarings = max(0, math.ceil(math.log2(norm / _THETA))) if norm > 0 else 0
        x = m / 2**squarings
        horner = [eye]  # T_q, ..., T_0
        for j in range(_taylor_degree(m.dtype), 0, -1):
            horner.append(_addmm(eye, x, horner[-1], alpha=1.0 / j))
        squares = [horner[-1]]  # E_0, ..., E_s
        for _ in range(squarings):
            squares.append(_addmm(squares[-1], squares[-1], squares[-1], beta=0.0))
        ctx.save_for_backward(x, *horner[:-1], *squares[:-1])
        ctx.degree = len(horner) - 1
        return squares[-1]

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> Tensor:  # type: ignore[override]
        if ctx.degree is None:
            return torch.full_like(grad, math.nan)
        x, *saved = ctx.saved_tensors
        horner, squares = saved[: ctx.degree], saved[ctx.degree :]
        grad = grad.contiguous()
        for e in reversed(squares):
            e_t = _t(e)
            grad = _addmm(_addmm(grad, grad, e_t, beta=0.0), e_t, grad)
        x_t, grad_x = _t(x), torch.zeros_like(x)
        for j, t in enumerate(reversed(horner), start=1):  # T_j feeds step j
            grad_x = _addmm(grad_x, grad, _t(t), alpha=1.0 / j)
            grad = _addmm(grad, x_t, grad, beta=0.0, alpha=1.0 / j)
        return grad_x / 2 ** len(squares)
