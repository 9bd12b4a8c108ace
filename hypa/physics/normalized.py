"""The normalized state-space form of the paper (eq. 2-8).

With x̂ = (x - μx)/σx and û = (u - μu)/σu (element-wise, eq. 2), the discrete system
x_{k+1} = Φ x_k + Σ_t Γ_t u_{k+t} becomes (eq. 5)

    x̂_{k+1} = Â x̂_k + Σ_t B̂_t û_{k+t} + Ĥ

    Â = diag(1/σx) Φ diag(σx)                                   (eq. 6)
    B̂_t = diag(1/σx) Γ_t diag(σu)                               (eq. 7)
    Ĥ = (Φ μx + Σ_t Γ_t μu - μx) / σx                            (eq. 8)

and the output y = C x + D u, scaled by (μy, σy), becomes ŷ = Ĉ x̂ + D̂ û + Ĝ with
Ĉ = diag(1/σy) C diag(σx), D̂ = diag(1/σy) D diag(σu), Ĝ = (C μx + D μu - μy)/σy.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from hypa.physics.discretization import DiscreteLTI


@dataclass(frozen=True)
class Scaling:
    """Means and standard deviations of states, inputs and outputs (physical units)."""

    state_mean: Tensor  # (n,)
    state_std: Tensor  # (n,)
    input_mean: Tensor  # (m,)
    input_std: Tensor  # (m,)
    output_mean: Tensor  # (p,)
    output_std: Tensor  # (p,)

    @staticmethod
    def identity(n: int, m: int, p: int, dtype: torch.dtype = torch.float64) -> "Scaling":
        """μ = 0, σ = 1: the normalized system is the physical one."""
        z = lambda k: torch.zeros(k, dtype=dtype)  # noqa: E731
        o = lambda k: torch.ones(k, dtype=dtype)  # noqa: E731
        return Scaling(z(n), o(n), z(m), o(m), z(p), o(p))

    def validate(self) -> None:
        for name in ("state_std", "input_std", "output_std"):
            std = getattr(self, name)
            if not bool(torch.all(std > 0)):
                raise ValueError(f"{name} must be positive everywhere, got {std.tolist()}")


@dataclass(frozen=True)
class NormalizedLTI:
    """x̂_{k+1} = Â x̂_k + Σ_t B̂_t û_{k+t} + Ĥ;  ŷ = Ĉ x̂ + D̂ û + Ĝ."""

    a: Tensor  # (n, n)
    b_taps: tuple[Tensor, ...]  # each (n, m)
    h: Tensor  # (n,)
    c: Tensor  # (p, n)
    d: Tensor  # (p, m)
    g: Tensor  # (p,)


def normalize(system: DiscreteLTI, c: Tensor, d: Tensor, scaling: Scaling) -> NormalizedLTI:
    """Apply eq. 6-8 (and their output counterparts) to a discrete system."""
    s = scaling
    inv_sx = 1.0 / s.state_std
    a_hat = inv_sx[:, None] * system.phi * s.state_std[None, :]
    b_hat = tuple(inv_sx[:, None] * g * s.input_std[None, :] for g in system.taps)
    h_hat = (system.phi @ s.state_mean + system.input_gain @ s.input_mean - s.state_mean) * inv_sx
    inv_sy = 1.0 / s.output_std
    c_hat = inv_sy[:, None] * c * s.state_std[None, :]
    d_hat = inv_sy[:, None] * d * s.input_std[None, :]
    g_hat = (c @ s.state_mean + d @ s.input_mean - s.output_mean) * inv_sy
    return NormalizedLTI(a=a_hat, b_taps=b_hat, h=h_hat, c=c_hat, d=d_hat, g=g_hat)
