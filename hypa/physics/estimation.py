"""Estimating a block's state from a past window of measured outputs: least squares, differentiable.

A window starts at sample P ("k" in the paper) after P past samples 0..P-1. Where the state is
not measured, the past tells it: with the normalized system (eq. 5, per-sample matrices for a
scheduled block) and an unknown x̂_0,

    x̂_{j+1} = Â_j x̂_j + c_j,    c_j = Σ_t B̂_{t,j} û_{j+t} + Ĥ_j          (j = 0..P-1)
    ŷ_j = Ĉ_j x̂_j + D̂_j û_j + Ĝ_j                                         (j = 0..P)

every state is affine in x̂_0: x̂_j = Ψ_j x̂_0 + r_j with Ψ_0 = I, r_0 = 0, Ψ_{j+1} = Â_j Ψ_j,
r_{j+1} = Â_j r_j + c_j (the prefix compositions of the steps, ``scan.affine_scan``: r_j
is the response to the inputs from a zero state). The measured outputs (the rows of ``observed``)
are then linear in x̂_0:

    z_j = ŷ_j - D̂_j û_j - Ĝ_j - Ĉ_j r_j = Ĉ_j Ψ_j x̂_0 + noise,   stacked: z = O x̂_0 + noise

with O = [Ĉ_0 Ψ_0; ...; Ĉ_P Ψ_P] the observability matrix of the window. The estimate

    x̂_0* = argmin ‖O x̂_0 - z‖² + λ ‖x̂_0‖²,       x̂_P* = Ψ_P x̂_0* + r_P

is the least-squares (Gauss-Markov) one for white output noise; λ (``ridge``, absolute, in the
normalized scale where states have unit spread) is tiny, so it only decides directions the
outputs do not see: those go to x̂ = 0, the state mean. It is solved by a QR factorization of
[O; √λ I] (not the normal equations, whose condition number is squared: it matters in float32),
all differentiable, so a loss on the prediction trains the physics through the estimate too.
Only samples 0..P are read.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from hypa.physics.scan import affine_scan


def estimate_last_state(phi: Tensor, forced: Tensor, c: Tensor, offset: Tensor, y: Tensor, observed: Tensor,
                        ridge: float = 1e-8, first: bool = False) -> Tensor:
    """x̂_P* (B, n) from a past window (see the module docstring); x̂_0* with ``first``.

    phi: (B' , P, n, n) Â_j (B' = 1 for constant matrices); forced: (B, P, n) c_j;
    c: (B' | 1, P+1 | 1, p, n) Ĉ_j; offset: (B, P+1, p) D̂_j û_j + Ĝ_j; y: (B, P+1, p) normalized
    outputs (unobserved channels are never read, NaN there is fine); observed: (p,) bool.
    """
    if ridge < 0:
        raise ValueError(f"ridge must be >= 0, got {ridge}")
    n, (batch, samples) = phi.shape[-1], y.shape[:2]
    eye = torch.eye(n, dtype=y.dtype, device=y.device)
    transition, response = eye.expand(1, 1, n, n), y.new_zeros(batch, 1, n)  # Ψ_0, r_0
    if samples > 1:
        powers, responses = affine_scan(phi, forced)  # Ψ_1..Ψ_P, r_1..r_P
        transition = torch.cat([transition.expand(*powers.shape[:-3], 1, n, n), powers], -3)  # (B', P+1, n, n)
        response = torch.cat([response, responses], -2)  # (B, P+1, n)
    c_seen = c[..., observed, :]  # (B'|1, P+1|1, p_o, n)
    gain = c_seen @ transition  # (B', P+1, p_o, n): O by sample
    z = y[..., observed] - offset[..., observed] - (c_seen @ response[..., None]).squeeze(-1)  # (B, P+1, p_o)
    rows = gain.reshape(gain.shape[0], -1, n)  # (B', M, n), M = (P+1) p_o
    if ridge > 0:
        rows = torch.cat([rows, math.sqrt(ridge) * eye.expand(rows.shape[0], n, n)], -2)
    q, r = torch.linalg.qr(rows)  # (B', M (+n), n), (B', n, n)
    measured = z.reshape(batch, -1, 1)  # (B, M, 1); the ridge rows' targets are 0
    x0 = torch.linalg.solve_triangular(r, q[:, : measured.shape[1]].transpose(-1, -2) @ measured, upper=True)
    if first:
        return x0.squeeze(-1).expand(batch, n)
    return (transition[:, -1] @ x0).squeeze(-1) + response[:, -1]  # (B, n)


GAUSS_NEWTON_STEPS = 3  # refinements of a nonlinear block's estimate (each one simulation of the past, n + 1 wide)
# ... of a nonlinear output's: its linearised start can be far off where h bends (an OCV curve read from its
# operating point), and a step that overshoots is halved rather than dropped
NONLINEAR_OUTPUT_STEPS = 8
OUTPUT_HALVINGS = 4
REFINED = 1e-3  # a refinement that lowers the windows' summed cost by less than this share ends them


def refine_first_state(simulate: Callable[[Tensor], tuple[Tensor, Tensor]], x0: Tensor, y: Tensor,
                       observed: Tensor, ridge: float = 1e-8, steps: int = GAUSS_NEWTON_STEPS,
                       halvings: int = 0) -> Tensor:
    """x̂_P (B, n) of a nonlinear block whose x̂_0 is refined by Gauss-Newton on its own simulation of
    the past window.

    ``simulate(x0)`` (K, n) -> (ŷ_0..ŷ_P (K, P+1, p), x̂_P (K, n)): the normalized outputs and last
    state of the block's nonlinear steps started at x̂_0 = x0; ``x0`` the start (the linear part's
    estimate); y (B, P+1, p) and observed (p,) as ``estimate_last_state``. Each step minimizes

        ‖ŷ(x̂_0 + δ) - y‖² + λ ‖x̂_0 + δ‖²     over the observed rows, ŷ linearized at x̂_0,

    with the Jacobian ∂ŷ/∂x̂_0 by forward differences (n more simulations in the same batch,
    so any ``nonlinearity`` works) and takes δ only where it lowers that cost (per window),
    so a window the linear part already fits keeps its estimate; where no window's cost falls,
    δ is halved up to ``halvings`` times before the refinement stops. Differentiable in y, u and
    the parameters through the simulations (the Jacobian's values enter as they are).

    Why: the linear part alone may not see a state that the feedback couples to the outputs
    (an upper tank whose outflow fills the measured lower one): its estimate is then the
    ridge's 0, the state mean, and the window starts far off.
    """
    batch, n = x0.shape
    columns = torch.nonzero(observed).flatten()  # index_select: a boolean mask's indexing costs more than the steps
    seen = y.index_select(-1, columns)  # (B, P+1, p_o)
    eps = torch.finfo(x0.dtype).eps  # normalized units: the states have unit spread
    delta, tolerance = eps ** (1 / 3), math.sqrt(eps)  # the difference's step; a step that changes nothing
    eye = torch.eye(n, dtype=x0.dtype, device=x0.device)

    def cost(residual: Tensor, x: Tensor) -> Tensor:
        return residual.square().flatten(1).sum(1) + ridge * x.square().sum(1)  # (B,)

    def run(start: Tensor) -> tuple[Tensor, Tensor]:  # outputs (B, n + 1, P+1, p_o) of start and its nudges, x̂_P
        outputs, last = simulate(torch.cat([start[:, None], start[:, None] + delta * eye], 1).reshape(-1, n))
        outputs = outputs.reshape(batch, n + 1, *y.shape[1:]).index_select(-1, columns)
        return outputs, last.reshape(batch, n + 1, n)[:, 0]

    out, last = run(x0)
    current = cost(out[:, 0] - seen, x0)
    for _ in range(steps):
        residual = out[:, 0] - seen
        jacobian = ((out[:, 1:] - out[:, :1]) / delta).flatten(2).transpose(1, 2)  # (B, M, n)
        rows = torch.cat([jacobian, math.sqrt(ridge) * eye.expand(batch, n, n)], 1) if ridge > 0 else jacobian
        target = torch.cat([-residual.flatten(1), -math.sqrt(ridge) * x0], 1) if ridge > 0 else -residual.flatten(1)
        finite = torch.isfinite(rows).flatten(1).all(1) & torch.isfinite(target).all(1)  # a diverged window: no step
        if not bool(finite.all()):  # (LAPACK refuses a non-finite matrix outright)
            rows, target = rows * finite[:, None, None], torch.where(finite[:, None], target, 0.0)
            rows = torch.nan_to_num(rows, nan=0.0, posinf=0.0, neginf=0.0)
        # in double precision: single-precision LAPACK gives run-to-run differences of its round-off
        # (5e-8, with the buffers' alignment) that these iterations, on a state the outputs barely see
        # (the tanks' upper level), carried to 7e-5 of its spread: the same record started elsewhere
        step = torch.linalg.lstsq(rows.double(), target[..., None].double()).solution.squeeze(-1).to(x0.dtype)
        if not bool(torch.isfinite(step.detach()).all()) or float(step.detach().abs().max()) <= tolerance:
            break  # converged: a step below the dtype's resolution of a state of unit spread
        for halved in range(halvings + 1):
            candidate = x0 + step / 2**halved
            trial, trial_last = run(candidate)
            trial_cost = cost(trial[:, 0] - seen, candidate)
            better = (trial_cost < current) & torch.isfinite(trial_cost)  # (B,)
            if bool(better.any()):
                break
        if not bool(better.any()):
            break
        x0 = torch.where(better[:, None], candidate, x0)
        last = torch.where(better[:, None], trial_last, last)
        out = torch.where(better[:, None, None, None], trial, out)
        before, current = current, torch.where(better, trial_cost, current)
        if float((before - current).detach().sum()) <= REFINED * float(before.detach().sum()):
            break  # the step lowered the windows' cost by less than REFINED: converged (a run of the past saved)
    return last
