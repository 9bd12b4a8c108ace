"""Exact discretization of continuous LTI systems by the matrix exponential (differentiable).

Both holds come from one matrix exponential of an augmented matrix, so gradients flow back
through ``torch.linalg.matrix_exp`` to the physical parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

Hold = Literal["zoh", "foh"]
HOLDS: tuple[str, ...] = ("zoh", "foh")


@dataclass(frozen=True)
class DiscreteLTI:
    """x_{k+1} = Φ x_k + Γ_0 u_k + Γ_1 u_{k+1}  (Γ_1 = 0 for a zero-order hold).

    ``taps[t]`` multiplies u_{k+t}; a zero-order hold has one tap, a first-order hold two.
    """

    phi: Tensor  # (n, n)
    taps: tuple[Tensor, ...]  # each (n, m)
    hold: str

    @property
    def input_gain(self) -> Tensor:
        """Σ_t Γ_t: the map from a constant input to the next state (n, m)."""
        return sum(self.taps[1:], self.taps[0])


def discretize(a: Tensor, b: Tensor, dt: float, hold: Hold = "zoh") -> DiscreteLTI:
    """Discretize dx/dt = A x + B u with sample time ``dt`` [s].

    zoh: u is held constant over a sample;  expm([[A, B], [0, 0]] dt) = [[Φ, Γ], [0, I]].

    foh: u is linear between samples (a smooth input sampled fast is much closer to this);
    with F = A dt, G = B dt,  expm([[F, G, 0], [0, 0, I], [0, 0, 0]]) = [[Φ, E_1, E_2], ...]
    where E_1 = ∫_0^dt e^{Aτ} dτ B and E_2 = (1/dt) ∫_0^dt e^{Aτ} (dt - τ) dτ B, so
    x_{k+1} = Φ x_k + (E_1 - E_2) u_k + E_2 u_{k+1}.
    """
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
        e = torch.linalg.matrix_exp(aug)
        return DiscreteLTI(phi=e[:n, :n], taps=(e[:n, n:],), hold=hold)
    top = torch.cat([a * dt, b * dt, torch.zeros(n, m, **opts)], dim=-1)
    mid = torch.cat([torch.zeros(m, n + m, **opts), torch.eye(m, **opts)], dim=-1)
    aug = torch.cat([top, mid, torch.zeros(m, n + 2 * m, **opts)], dim=-2)
    e = torch.linalg.matrix_exp(aug)
    e1, e2 = e[:n, n : n + m], e[:n, n + m :]
    return DiscreteLTI(phi=e[:n, :n], taps=(e1 - e2, e2), hold=hold)
