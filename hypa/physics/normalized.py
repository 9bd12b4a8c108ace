"""The normalized state-space form of the paper (eq. 2-8).

With x̂ = (x - μx)/σx and û = (u - μu)/σu (element-wise, eq. 2), the discrete system
x_{k+1} = Φ x_k + Σ_t Γ_t u_{k+t} + γ (γ: a constant drift, 0 in the paper) becomes (eq. 5)

    x̂_{k+1} = Â x̂_k + Σ_t B̂_t û_{k+t} + Ĥ

    Â = diag(1/σx) Φ diag(σx)                                   (eq. 6)
    B̂_t = diag(1/σx) Γ_t diag(σu)                               (eq. 7)
    Ĥ = (Φ μx + Σ_t Γ_t μu + γ - μx) / σx                        (eq. 8)

and the output y = C x + D u, scaled by (μy, σy), becomes ŷ = Ĉ x̂ + D̂ û + Ĝ with
Ĉ = diag(1/σy) C diag(σx), D̂ = diag(1/σy) D diag(σu), Ĝ = (C μx + D μu - μy)/σy.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from hypa.physics.discretization import DiscreteLTI, discretize, hold_form
from hypa.physics.exponential import hold_exponential, hold_exponential_steps

if TYPE_CHECKING:
    from hypa.physics.lti import StateSpace


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
    def identity(n: int, m: int, p: int, dtype: torch.dtype = torch.float64) -> Scaling:
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
    h_hat = system.phi @ s.state_mean + system.input_gain @ s.input_mean - s.state_mean
    if system.drift is not None:
        h_hat = h_hat + system.drift
    h_hat = h_hat * inv_sx
    inv_sy = 1.0 / s.output_std
    c_hat = inv_sy[:, None] * c * s.state_std[None, :]
    d_hat = inv_sy[:, None] * d * s.input_std[None, :]
    g_hat = (c @ s.state_mean + d @ s.input_mean - s.output_mean) * inv_sy
    return NormalizedLTI(a=a_hat, b_taps=b_hat, h=h_hat, c=c_hat, d=d_hat, g=g_hat)


@dataclass(frozen=True)
class NormalizingMaps:
    """Constant matrices that apply eq. 5-8 to [A, B, e] and [C, D] as products (built once per scaling).

    With S_x = diag(σx), S_u = diag(σu) and the affine map W = [[S_x, 0, μx], [0, S_u, μu]]
    ((n+m, n+m+1), x = W [x̂; û; 1]), the normalized continuous system and the output are

        dx̂/dt = S_x⁻¹ ([A, B] W [x̂; û; 1] + e),        ŷ = S_y⁻¹ ([C, D] W [x̂; û; 1] - μy)

    The constant term (A μx + B μu + e, the drift e included) is an input held at 1, exact under
    either hold, so one exponential

        M = [[dt S_x⁻¹ [A, B, e] W_hold], [0, N]],   e^M[:n] = [Â, B̂_0, ..., Ĥ]

    gives eq. 6-8 directly: e^{D⁻¹ M D} = D⁻¹ e^M D for the rescaling D, and Ĥ of eq. 8 is
    S_x⁻¹ ∫_0^dt e^{Aτ} dτ (A μx + B μu + e) because Φ - I = ∫ e^{Aτ} dτ A and Σ_t Γ_t = ∫ e^{Aτ} dτ B.
    ZOH: W_hold = W (its last row, for e, picks the constant column) and the inputs (û, 1) are
    constant (N = 0). FOH (see ``discretize``): W_hold has zero columns for û_{k+1}, and the
    input ramp is written in the basis of its end points (û_k, û_{k+1}) by the similarity
    T = blockdiag(I, [[I, 0], [-I, I]], 1), which leaves the top rows e^M[:n] T =
    [Φ̂, E_1 - E_2, E_2, Ĥ] = [Â, B̂_0, B̂_1, Ĥ] and turns the ramp's dynamics [[0, I], [0, 0]]
    into N = [[-I, I], [-I, I]] (still N² = 0). Every hold is this with its own taps' basis
    and N (``HoldForm``: the B columns on the tap of û_k, N ⊗ I below). Only e^M's top rows are
    needed, and ``hold_exponential`` computes them from M's top rows and N.

    ``state_rows`` and ``output_rows`` also take stacks of matrices (..., n, n) (one system per
    sample of a scheduled block): then the exponentials are one batched ``hold_exponential``.
    """

    state_left: Tensor  # (n, n): dt S_x⁻¹, so M[:n] = state_left [A, B, e] state_right (k = n + T m + 1)
    state_right: Tensor  # (n+m+1, k): [W_hold; the constant column's unit row (for e)]
    state_map: Tensor  # (n, k, n+m+1): the same map row by row, M[i] = state_map[i] [A, B, e][i] (i < n; stacks)
    state_bottom: Tensor  # (k-n, k): M[n:] = [0, N], N the hold's input dynamics (0 for a ZOH)
    output_left: Tensor  # (p, p): S_y⁻¹
    output_right: Tensor  # (n+m, n+m+1): W
    output_rest: Tensor  # (p, n+m+1): [0, 0, -μy/σy]

    @staticmethod
    def build(scaling: Scaling, dt: float, hold: str, dtype: torch.dtype) -> NormalizingMaps:
        s = Scaling(*(t.to(dtype) for t in dataclasses.astuple(scaling)))
        n, m, p = s.state_mean.numel(), s.input_mean.numel(), s.output_mean.numel()
        form = hold_form(hold)
        k = n + form.n_taps * m + 1
        w = torch.zeros(n + m, n + m + 1, dtype=dtype, device=s.state_mean.device)
        w[:n, :n], w[n:, n : n + m] = torch.diag(s.state_std), torch.diag(s.input_std)
        w[:, -1] = torch.cat([s.state_mean, s.input_mean])
        before, after = w.new_zeros(n + m, form.past * m), w.new_zeros(n + m, form.lead * m)
        w_hold = torch.cat([w[:, :n], before, w[:, n : n + m], after, w[:, -1:]], dim=1)  # B on the tap of û_k
        drift_row = w.new_zeros(1, k)
        drift_row[0, -1] = 1.0
        bottom = w.new_zeros(k - n, k)
        bottom[: k - n - 1, n : k - 1] = form.dynamics(m, dtype, w.device)
        rest_out = torch.cat([w.new_zeros(p, n + m), (-s.output_mean / s.output_std)[:, None]], 1)
        right = torch.cat([w_hold, drift_row])
        state_map = (dt / s.state_std)[:, None, None] * right.T
        return NormalizingMaps(torch.diag(dt / s.state_std), right, state_map, bottom, torch.diag(1 / s.output_std),
                               w, rest_out)

    def state_rows(self, a: Tensor, b: Tensor, e: Tensor | None = None, squarings: int | None = None) -> Tensor:
        """[Â, B̂_0, ..., B̂_{T-1}, Ĥ] (..., n, n + T m + 1) from continuous A, B (and drift e): one exponential.

        a (..., n, n), b (..., n, m), e (..., n) or None. A stack is one batched
        ``hold_exponential`` over its samples laid out last, returned as a (..., n, k) view of
        that (n, k, K) layout (so ``scheduled.simulate_scheduled`` reads it without a copy).
        ``squarings``: a stack's, given (``hold_exponential_steps``: a traced graph holds no value of A).
        """
        parts = (a, b) if e is None else (a, b, e[..., None])
        j, lead = a.shape[-1] + b.shape[-1] + int(e is not None), a.shape[:-2]
        if not lead:  # M[:n] (n, k) by two plain products (cheaper to differentiate than a broadcast scaling)
            return hold_exponential(self.state_left @ (torch.cat(parts, -1) @ self.state_right[:j]), self.state_bottom)
        ab = torch.cat([p.reshape(-1, *p.shape[-2:]).permute(1, 2, 0) for p in parts], 1)  # (n, j, K): samples last
        generator = torch.matmul(self.state_map[..., :j], ab)  # M[:n] (n, k, K), n products
        rows = hold_exponential(generator, self.state_bottom) if squarings is None else \
            hold_exponential_steps(generator, self.state_bottom, squarings)
        return rows.permute(2, 0, 1).reshape(*lead, *rows.shape[:2])

    def output_rows(self, c: Tensor, d: Tensor) -> Tensor:
        """[Ĉ, D̂, Ĝ] (..., p, n + m + 1) from C (..., p, n), D (..., p, m)."""
        cd = torch.cat([c, d], -1) @ self.output_right
        if c.dim() == 2:
            return torch.addmm(self.output_rest, self.output_left, cd)
        return self.output_rest + self.output_left @ cd


def default_state_std(system: StateSpace, dt: float, input_std: Tensor, horizon: int,
                      floor: float = 1e-3) -> Tensor:
    """A data-free σx (n,) for states nobody measures: the spread the inputs give them in N steps.

    With the nominal zero-order-hold system x_{j+1} = Φ x_j + Γ u_j driven from x_0 = 0 by white
    inputs of standard deviation σu (physical units, e.g. the training data's), the state's
    covariance after N = ``horizon`` steps is the finite-horizon controllability Gramian

        W_N = Σ_{j=0}^{N-1} Φ^j Γ diag(σu²) Γᵀ (Φ^j)ᵀ,        σx = sqrt(diag W_N)

    It exists for any system, unlike the stationary Lyapunov solution W = Φ W Φᵀ + Γ S Γᵀ,
    which has none for an integrator (a position driven by a force: W_N grows like N³). White
    inputs are the fastest excitation, so smooth inputs may move an integrating state further;
    the scale only needs the right order of magnitude. A state the inputs never reach would
    get 0: σx is floored at ``floor`` · max σx (1 where no state is reached at all).
    """
    with torch.no_grad():
        a, b = system.a.detach().to(torch.float64), system.b.detach().to(torch.float64)
        n = a.shape[-1]
        if n == 0:
            return a.new_zeros(0)
        d = discretize(a, b, dt, "zoh")
        gamma = d.taps[0] * input_std.detach().to(torch.float64).reshape(1, -1)  # (n, m): Γ S_u
        response, variance = gamma, torch.zeros(n, dtype=torch.float64)
        for _ in range(horizon):  # Σ_j of the row sums of squares of Φ^j Γ S_u
            variance = variance + response.square().sum(-1)
            response = d.phi @ response
        std = variance.sqrt()
        top = float(std.max()) if torch.isfinite(std).all() else 0.0
        return std.clamp_min(floor * top) if top > 0 else torch.ones_like(std)
