"""The lifted N-step form of the normalized state equation (eq. 9-11).

Stacking X̂ = [x̂_{k+1}; ...; x̂_{k+N}] and Û = [û_k; ...; û_{k+N-1+T-1}] (T input taps:
1 for a zero-order hold, 2 for a first-order hold, which also needs û_{k+N}) gives

    X̂ = 𝒜 x̂_k + ℬ Û + ℋ                                                  (eq. 11)

    𝒜 = [Â; Â²; ...; Â^N]                                                 (N n, n)
    ℬ[i, j] = Σ_t Â^{i-j+t} B̂_t  for t <= j <= i + t, else 0 (block Toeplitz)   (N n, (N+T-1) m)
    ℋ[i] = Σ_{d=0..i} Â^d Ĥ                                                 (N n,)

so a whole window is one batched matrix product instead of N dependent steps. For a zero-
order hold, row i of ℬ is [Â^i B̂, Â^{i-1} B̂, ..., B̂, 0, ...] and the last input used is
û_{k+N-1} (eq. 10). All powers of Â are built together by repeated doubling (⌈log2 N⌉
batched products), so rebuilding the matrices every step with trainable physics stays cheap.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass(frozen=True)
class LiftedMatrices:
    """𝒜, ℬ, ℋ of eq. 11 for a horizon of N steps."""

    a: Tensor  # (N n, n)
    b: Tensor  # (N n, (N+T-1) m)
    h: Tensor  # (N n,)
    horizon: int
    n_taps: int

    @property
    def input_length(self) -> int:
        """Number of input samples a window needs: N for ZOH, N + 1 for FOH."""
        return self.horizon + self.n_taps - 1


def matrix_powers(a: Tensor, count: int) -> Tensor:
    """[I, A, A², ..., A^{count-1}] as a (count, n, n) tensor, all at once (differentiable).

    Binary powering, vectorized over k: A^k = Π_{bits b of k} A^(2^b), so ⌈log2 count⌉ batched
    products build every power. The backward is analytic (see ``_MatrixPowers``) rather than
    taped, so rebuilding the lifted matrices every training step stays cheap.
    """
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    return _MatrixPowers.apply(a, count)


def _binary_powers(a: Tensor, count: int) -> Tensor:
    n = a.shape[-1]
    k = torch.arange(count, device=a.device)
    eye = torch.eye(n, dtype=a.dtype, device=a.device)
    powers, square = eye.expand(count, n, n), a
    for bit in range(max(count - 1, 1).bit_length()):
        if bit:
            square = square @ square  # A^(2^bit)
        powers = powers @ torch.where(((k >> bit) & 1).bool()[:, None, None], square, eye)
    return powers


class _MatrixPowers(torch.autograd.Function):
    """P_d = A^d, d = 0..count-1, with the adjoint

        dL/dA = Σ_d Σ_{k<d} (A^k)ᵀ Q_d (A^{d-1-k})ᵀ = Σ_k (A^k)ᵀ M_k,   M_k = Σ_l Q_{k+1+l} (A^l)ᵀ

    for Q_d = dL/dP_d; the inner sums are one strided (Toeplitz-like) contraction.
    """

    @staticmethod
    def forward(ctx, a: Tensor, count: int) -> Tensor:  # type: ignore[override]
        powers = _binary_powers(a, count)
        ctx.save_for_backward(powers)
        return powers

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None]:  # type: ignore[override]
        (powers,) = ctx.saved_tensors
        steps, n = powers.shape[0] - 1, powers.shape[-1]
        if steps == 0:
            return torch.zeros_like(powers[0]), None
        q = torch.cat([grad[1:], grad.new_zeros(steps - 1, n, n)])  # Q_1..Q_L, then zeros
        windows = q.unfold(0, steps, 1)  # (L, n, n, L): windows[k, ..., l] = Q_{k+1+l}
        m = torch.einsum("kabl,lcb->kac", windows, powers[:steps])
        return torch.einsum("kba,kbc->ac", powers[:steps], m), None


def block_toeplitz(markov: Tensor) -> Tensor:
    """Lower block-triangular Toeplitz T[i, :, j, :] = K[i - j] (j <= i), else 0.

    markov: (N, n, m) Markov parameters K_d = Â^d B̂. Returns (N, n, N, m). Built as a strided
    view of the zero-padded sequence (no gather), so forward and backward are plain copies.
    """
    horizon, n, m = markov.shape
    padded = torch.cat([markov.new_zeros(horizon - 1, n, m), markov])  # padded[s] = K[s - N + 1]
    windows = padded.unfold(0, horizon, 1)  # (N, n, m, N): windows[i, ..., c] = padded[i + c]
    return windows.flip(-1).permute(0, 1, 3, 2)  # c = N - 1 - j  ->  K[i - j]


def lifted_matrices(a: Tensor, b_taps: tuple[Tensor, ...], h: Tensor, horizon: int) -> LiftedMatrices:
    """Build 𝒜, ℬ, ℋ (eq. 9-11) from the normalized Â, B̂_t, Ĥ for ``horizon`` steps."""
    if horizon < 1:
        raise ValueError(f"horizon must be at least 1, got {horizon}")
    n, m, n_taps = a.shape[-1], b_taps[0].shape[-1], len(b_taps)
    powers = matrix_powers(a, horizon + 1)  # (N+1, n, n)
    lifted_a = powers[1:].reshape(horizon * n, n)

    n_in = horizon + n_taps - 1
    markov = powers[:horizon] @ torch.stack(b_taps)[:, None]  # (T, N, n, m): Â^d B̂_t
    lifted_b = block_toeplitz(markov[0])
    for t in range(1, n_taps):  # tap t reads the input t samples later: t columns further right
        lifted_b = nn.functional.pad(lifted_b, (0, 0, 0, 1)) + nn.functional.pad(
            block_toeplitz(markov[t]), (0, 0, t, 0))
    lifted_b = lifted_b.reshape(horizon * n, n_in * m)  # (N n, (N+T-1) m)

    lifted_h = torch.cumsum(powers[:horizon] @ h, dim=0).reshape(horizon * n)
    return LiftedMatrices(a=lifted_a, b=lifted_b, h=lifted_h, horizon=horizon, n_taps=n_taps)


def simulate_lifted(lifted: LiftedMatrices, x0: Tensor, u: Tensor) -> Tensor:
    """X̂ = 𝒜 x̂_k + ℬ Û + ℋ for a batch.

    x0: (B, n) normalized initial states; u: (B, N+T-1, m) normalized inputs.
    Returns (B, N, n): the states x̂_{k+1}..x̂_{k+N}.
    """
    batch, n = x0.shape
    if u.shape[1] != lifted.input_length:
        raise ValueError(
            f"expected {lifted.input_length} input samples for a horizon of {lifted.horizon} "
            f"with {lifted.n_taps} tap(s), got {u.shape[1]}"
        )
    flat = torch.addmm(lifted.h, u.reshape(batch, -1), lifted.b.T)  # (B, N n)
    if n:
        flat = flat.addmm(x0, lifted.a.T)
    return flat.view(batch, lifted.horizon, n)


def simulate_recursive(a: Tensor, b_taps: tuple[Tensor, ...], h: Tensor, x0: Tensor, u: Tensor) -> Tensor:
    """The reference: x̂_{k+1} = Â x̂_k + Σ_t B̂_t û_{k+t} + Ĥ, one step after another.

    x0: (B, n); u: (B, L, m). Returns (B, L - T + 1, n).
    """
    steps = u.shape[1] - len(b_taps) + 1
    x, out = x0, []
    for k in range(steps):
        x = x @ a.T + h
        for t, b_t in enumerate(b_taps):
            x = x + u[:, k + t] @ b_t.T
        out.append(x)
    return torch.stack(out, dim=1)
