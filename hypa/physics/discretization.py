"""Exact discretization of continuous LTI systems by the matrix exponential (differentiable).

Every hold comes from one matrix exponential of an augmented matrix, so gradients flow back
through ``expm`` to the physical parameters. A hold is how the input moves between samples,
a polynomial through its taps (``HoldForm``): constant (``zoh``), a line to the next sample
(``foh``), or a cubic through u_{k-1}..u_{k+2} (``cubic``, Catmull-Rom: a smooth, band-limited
input such as a generator's output behind its reconstruction filter, what MATLAB calls a
band-limited intersample behaviour).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from hypa.physics.exponential import hold_exponential

Hold = Literal["zoh", "foh", "cubic"]
HOLDS: tuple[str, ...] = ("zoh", "foh", "cubic")


@dataclass(frozen=True)
class HoldForm:
    """How a hold reads the input samples: the input over sample k, u(t_k + s dt) for 0 <= s <= 1,
    is a polynomial through T taps u_{k-P}, ..., u_{k+T-1-P} (P = ``past``).

    ``basis`` (T rows of T): its value and derivatives d^j u / ds^j at s = 0 from the taps, so
    the derivatives move by the shift S (d q_j / ds = q_{j+1}, the last constant), and in the
    taps' own basis by N = K⁻¹ S K (``dynamics``; N^T = 0): what the augmented exponential of
    ``discretize`` integrates.
    """

    past: int
    basis: tuple[tuple[float, ...], ...]

    @property
    def n_taps(self) -> int:
        return len(self.basis)

    @property
    def lead(self) -> int:
        """Taps after u_k: input samples a step reads beyond its own."""
        return self.n_taps - 1 - self.past

    def dynamics(self, m: int, dtype: torch.dtype = torch.float64, device: torch.device | None = None) -> Tensor:
        """N ⊗ I_m (T m, T m): the taps' dynamics over a sample, for m inputs."""
        return torch.kron(_tap_dynamics(self), torch.eye(m, dtype=torch.float64)).to(dtype=dtype, device=device)


@functools.cache
def _tap_dynamics(form: HoldForm) -> Tensor:
    """N = K⁻¹ S K (T, T) of a hold, in float64 (exact small rationals: K's inverse is the taps from the
    derivatives)."""
    k = torch.tensor(form.basis, dtype=torch.float64)
    shift = torch.diag(torch.ones(form.n_taps - 1, dtype=torch.float64), 1)
    return torch.linalg.solve(k, shift @ k).contiguous()


HOLD_FORMS: dict[str, HoldForm] = {
    "zoh": HoldForm(0, ((1.0,),)),
    "foh": HoldForm(0, ((1.0, 0.0), (-1.0, 1.0))),
    # Catmull-Rom: through u_k and u_{k+1} with the slopes (u_{k+1} - u_{k-1}) / 2 and (u_{k+2} - u_k) / 2
    "cubic": HoldForm(1, ((0.0, 1.0, 0.0, 0.0), (-0.5, 0.0, 0.5, 0.0), (2.0, -5.0, 4.0, -1.0),
                          (-3.0, 9.0, -9.0, 3.0))),
}


def hold_form(hold: str) -> HoldForm:
    """The ``HoldForm`` of a hold's name (a one-line error for an unknown one)."""
    if hold not in HOLD_FORMS:
        raise ValueError(f"unknown hold {hold!r}; choose one of {', '.join(HOLDS)}")
    return HOLD_FORMS[hold]


@dataclass(frozen=True)
class DiscreteLTI:
    """x_{k+1} = Φ x_k + Σ_t Γ_t u_{k+t-P} + γ  (P = ``past``).

    ``taps[t]`` multiplies u_{k+t-P}: a zero-order hold has one tap (u_k), a first-order hold
    two (u_k, u_{k+1}), a cubic hold four (u_{k-1}..u_{k+2}, P = 1).
    ``drift`` γ = ∫_0^dt e^{Aτ} dτ e is the constant drift e over one sample (None: e = 0).
    """

    phi: Tensor  # (n, n)
    taps: tuple[Tensor, ...]  # each (n, m)
    hold: str
    drift: Tensor | None = None  # (n,)

    @property
    def past(self) -> int:
        return hold_form(self.hold).past

    @property
    def input_gain(self) -> Tensor:
        """Σ_t Γ_t: the map from a constant input to the next state (n, m)."""
        return sum(self.taps[1:], self.taps[0])


def discretize(a: Tensor, b: Tensor, dt: float, hold: Hold = "zoh", e: Tensor | None = None) -> DiscreteLTI:
    """Discretize dx/dt = A x + B u + e with sample time ``dt`` [s].

    With the taps v = (u_{k-P}, ..., u_{k+T-1-P}) held as states that move by N over the sample
    (``HoldForm``) and u(s) = u_k + ... their polynomial, one exponential gives every tap's Γ:

        expm([[A dt, B dt E_P], [0, N]]) = [[Φ, Γ_0, ..., Γ_{T-1}], [0, e^N]]

    (E_P puts B on the tap of u_k). zoh: N = 0, Γ_0 = ∫_0^dt e^{Aτ} dτ B. foh: N = [[-1, 1],
    [-1, 1]] (the ramp from u_k to u_{k+1}), so Γ_0 = E_1 - E_2 and Γ_1 = E_2 with E_1 = ∫_0^dt
    e^{Aτ} dτ B, E_2 = (1/dt) ∫_0^dt e^{Aτ} (dt - τ) dτ B. cubic: the Catmull-Rom cubic (a
    smooth input: an error of order dt⁴ between samples where the first-order hold's is dt²).

    A drift e (n,) is an input held at 1, the same under every hold: it is discretized as one
    more input column, whose taps sum to γ = ∫_0^dt e^{Aτ} dτ e. Every hold is the top rows of
    those exponentials: ``hold_exponential``, the one place a hold is computed.
    """
    if e is not None:
        system = discretize(a, torch.cat([b, e[:, None]], dim=-1), dt, hold)
        taps = tuple(t[:, :-1] for t in system.taps)
        return DiscreteLTI(system.phi, taps, hold, drift=sum(t[:, -1] for t in system.taps))
    form = hold_form(hold)
    if not dt > 0:
        raise ValueError(f"sample time must be positive, got {dt}")
    n, m = b.shape[-2], b.shape[-1]
    if a.shape[-2:] != (n, n):
        raise ValueError(f"A must be ({n}, {n}) to match B {tuple(b.shape)}, got {tuple(a.shape)}")
    width = form.n_taps * m
    held = torch.zeros(n, width, dtype=a.dtype, device=a.device)
    held[:, form.past * m : (form.past + 1) * m] = b * dt
    bottom = torch.cat([torch.zeros(width, n, dtype=a.dtype, device=a.device),
                        form.dynamics(m, a.dtype, a.device)], dim=1)
    top = hold_exponential(torch.cat([a * dt, held], dim=-1), bottom)
    return DiscreteLTI(phi=top[:, :n], taps=tuple(top[:, n + t * m : n + (t + 1) * m] for t in range(form.n_taps)),
                       hold=hold)
