"""A nonlinear recursion x_{k+1} = F_k(x_k) solved for every sample at once (Newton over the sequence).

A nonlinear (Lur'e) block steps its samples one after the other: on a long record each step is
a handful of tiny tensor operations, so a free run costs tens of microseconds per sample whatever
the state's size (an EMPS training record, 20 000 samples: 1.2 s per run, and an output-error
identification runs it a few hundred times). The same states solve the sequence's equations

    x_{k+1} - F_k(x_k) = 0,   k = 0..S-1,   x_0 given,

all of them at once, which Newton's method does with whole-sequence operations (Lim et al.,
"Parallelizing non-linear sequential models over the sequence length", ICLR 2024): linearized
about the current iterate x̄, the equations are the affine recursion

    x_{k+1} = J_k x_k + (F_k(x̄_k) - J_k x̄_k),   J_k = ∂F_k/∂x at x̄_k,

which a parallel scan solves in log2(S) levels (:func:`hypa.physics.scan.affine_scan`). F is
evaluated on every sample in one call, and its Jacobian by forward differences in ``n`` more
(whatever the user's nonlinearity). Each full Newton step makes at least one more leading sample
exact, and near the solution the error squares at every step, so a stable system converges in a
few iterations.

What it returns is the step-by-step recursion's own fixed point, not an approximation of the
dynamics: it is accepted where ``max_k |x_{k+1} - F_k(x_k)|`` (in units of the states' spread) has
fallen to the dtype's round-off, or where Newton stalls within ``STALLED`` epsilons of it: F sums
terms larger than the states (EMPS: a motor force over the mass, a friction that switches with the
speed), so its own evaluation's round-off can sit above the states' epsilon (there 5e-13 of the
spread, 1e-8 of it on the training record's position had that defect accumulated over every sample);
Newton then no longer halves the residual, and the loop would reach no closer. The caller falls back
to the sample-by-sample loop otherwise (``None``: a chaotic or badly scaled system, a non-finite
iterate).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from hypa.physics.scan import affine_scan

MAX_ITERATIONS = 40  # Newton steps before giving up (each a few dozen whole-sequence operations)
BACKTRACKS = 6  # halvings of a Newton step that does not lower the residual, before giving up
ROUND_OFF = 64  # accepted: the equations' residual within this many epsilons of the states' size
STALLED = 1e6  # ... or within this many epsilons of their spread where a Newton step no longer halves it


def solve_recursion(step: Callable[[Tensor], Tensor], x0: Tensor, guess: Tensor, scale: Tensor,
                    max_iterations: int = MAX_ITERATIONS) -> Tensor | None:
    """States x_1..x_S (B, S, n) of x_{k+1} = F_k(x_k) from x_0 = ``x0`` (B, n), or ``None`` when
    Newton's method does not reach the recursion's fixed point to round-off.

    ``step(x)`` evaluates every F_k at once: x (B, S, n) holding x_k at index k -> F_k(x_k) (B, S, n),
    each F_k reading only its own x_k. ``guess`` (B, S, n): the first iterate of x_1..x_S (any finite states:
    it only sets how many iterations it takes); ``scale`` (n,): the states' spread, the unit of the
    residual max_k |x_{k+1} - F_k(x_k)| / scale. A full Newton step that does not lower it is halved
    until it does (far from the solution the linearization overshoots: a sine map started at 0
    needs a quarter step, then converges in six more); none that does, or ``max_iterations``
    steps, and it gives up. Runs without a graph: a solution for evaluation (free runs,
    identification), not for training through it.
    """
    eps = torch.finfo(guess.dtype).eps
    with torch.no_grad():
        x = guess
        before, value, residual = _residual(step, x0, x, scale)
        for _ in range(max_iterations):
            if not residual < float("inf"):  # NaN or inf: no step from here
                return None
            if residual <= ROUND_OFF * eps * max(1.0, float((x / scale).abs().max())):
                return x
            jacobian = _jacobian(step, before, value, scale)  # (B, S, n, n)
            offset = value - (jacobian @ before[..., None]).squeeze(-1)  # F(x̄) - J x̄
            offset[:, 0] += (jacobian[:, 0] @ x0[..., None]).squeeze(-1)  # the known x_0 folded into step 0
            newton, share = affine_scan(jacobian, offset, prefix=False)[1], 1.0
            for _ in range(BACKTRACKS + 1):
                candidate = newton if share == 1.0 else x + share * (newton - x)
                trial = _residual(step, x0, candidate, scale)
                if trial[2] < residual:
                    break
                share /= 2
            else:
                return x if residual <= STALLED * eps else None  # at the floor: no step lowers it
            if trial[2] > residual / 2 and trial[2] <= STALLED * eps:
                return candidate  # stalled at the evaluation's own round-off
            x, (before, value, residual) = candidate, trial
    return x if residual <= STALLED * eps else None


def _residual(step: Callable[[Tensor], Tensor], x0: Tensor, x: Tensor, scale: Tensor) -> tuple[Tensor, Tensor, float]:
    """x̄_0..x̄_{S-1} (x_0, then x's first S - 1), F_k(x̄_k) and max_k |x_{k+1} - F_k(x̄_k)| / scale."""
    before = torch.cat([x0[:, None], x[:, :-1]], 1)
    value = step(before)
    return before, value, float(((x - value) / scale).abs().max())


def _jacobian(step: Callable[[Tensor], Tensor], x: Tensor, value: Tensor, scale: Tensor) -> Tensor:
    """∂F_k/∂x_k (B, S, n, n) for every k by forward differences, one call of ``step`` per state
    (each F_k reads only its own x_k), the step √ε of the larger of the state and its spread.
    Differences, not autograd: they work inside ``torch.inference_mode`` (Lightning's validation)
    and on any nonlinearity; their error only slows Newton's convergence, never moves the fixed
    point, which the residual checks exactly."""
    root = torch.finfo(x.dtype).eps ** 0.5
    columns = []
    for j in range(x.shape[-1]):
        probe = x.clone()
        probe[..., j] += root * torch.maximum(x[..., j].abs(), scale[j])
        columns.append((step(probe) - value) / (probe[..., j] - x[..., j])[..., None])  # the step as represented
    return torch.stack(columns, -1)
