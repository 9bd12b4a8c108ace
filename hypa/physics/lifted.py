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
from torch import Tensor


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
    """[I, A, A², ..., A^{count-1}] as a (count, n, n) tensor, by repeated doubling."""
    n = a.shape[-1]
    powers = torch.stack([torch.eye(n, dtype=a.dtype, device=a.device), a])
    while powers.shape[0] < count:
        # powers holds A^0..A^k; A^k @ A^1..A^k appends A^{k+1}..A^{2k}
        powers = torch.cat([powers, powers[-1] @ powers[1:]])
    return powers[:count]


def lifted_matrices(a: Tensor, b_taps: tuple[Tensor, ...], h: Tensor, horizon: int) -> LiftedMatrices:
    """Build 𝒜, ℬ, ℋ (eq. 9-11) from the normalized Â, B̂_t, Ĥ for ``horizon`` steps."""
    if horizon < 1:
        raise ValueError(f"horizon must be at least 1, got {horizon}")
    n, m, n_taps = a.shape[-1], b_taps[0].shape[-1], len(b_taps)
    powers = matrix_powers(a, horizon + 1)  # (N+1, n, n)
    lifted_a = powers[1:].reshape(horizon * n, n)

    n_in = horizon + n_taps - 1
    i = torch.arange(horizon, device=a.device)[:, None]  # output step
    j = torch.arange(n_in, device=a.device)[None, :]  # input sample
    blocks = a.new_zeros(horizon, n_in, n, m)
    for t, b_t in enumerate(b_taps):
        markov = powers[:horizon] @ b_t  # (N, n, m): Â^d B̂_t
        d = i - j + t
        valid = (j >= t) & (d >= 0)
        blocks = blocks + markov[d.clamp(0, horizon - 1)] * valid[..., None, None].to(a.dtype)
    lifted_b = blocks.permute(0, 2, 1, 3).reshape(horizon * n, n_in * m)

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
