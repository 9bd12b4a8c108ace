"""The operating point of nonlinear physics where no data give it: where the system settles.

A state that no output reads has no operating point in the data. For a linear system 0 serves
(its dynamics are the same everywhere), for a nonlinear one it does not: tanks draining through
orifices have no slope of √h at 0 V. :func:`settled_state_scales` puts such a state where the
nominal system settles under the inputs' mean; :func:`output_level_state_scales`, for a system
with a nonlinear output, puts the levels its dynamics leave free (a state of charge) where the
outputs are the data's means.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from hypa.physics.lti import LTIBlock
from hypa.physics.parameters import PhysicalParameters
from hypa.physics.statespace import LTIModel

Scale = tuple[float, float]  # (mean, std) of a signal in SI units

SETTLE_CHUNK = 200  # [samples] simulated between the checks whether the states settled ...
SETTLE_CHUNKS = 50  # ... at most this many times (10,000 samples)
SETTLE_TOLERANCE = 1e-6  # a change below this share of a state's scale: settled


def settled_state_scales(system: LTIModel, params: PhysicalParameters, dt: float, inputs: Sequence[Scale],
                         states: list[Scale], unread: Sequence[int]) -> list[Scale]:
    """``states`` with the operating point of each ``unread`` state of nonlinear physics: where the
    nominal system settles under the inputs' mean, started from the other states' operating points
    (those from the data) and 0 for these. Tanks draining through orifices: the upper tank, which
    no output reads, fills to (k4 ū / k1)², not 0 V, where √h has no slope (its linearisation,
    :meth:`LTIBlock.linearised_a`, had no time constant there, and the initial-state estimate's
    ridge pulled toward it). Kept at 0 where the system does not settle within ``SETTLE_CHUNKS``
    chunks of ``SETTLE_CHUNK`` samples (it drifts, oscillates or diverges); the spreads are kept."""
    if not unread:
        return states
    block = LTIBlock(system, params, dt, horizon=SETTLE_CHUNK, hold="zoh")  # identity scaling: physical units
    x = torch.tensor([m for m, _ in states], dtype=torch.float64)[None]
    u = torch.tensor([m for m, _ in inputs], dtype=torch.float64).expand(1, SETTLE_CHUNK, len(inputs))
    scale = torch.tensor([s for _, s in states], dtype=torch.float64)[list(unread)]
    with torch.no_grad():
        for _ in range(SETTLE_CHUNKS):
            try:
                new = block.states(x, u)[:, -1]
            except (ArithmeticError, ValueError, RuntimeError):
                return states
            if not bool(torch.isfinite(new).all()):
                return states
            change = (new - x)[0, list(unread)].abs()
            x = new
            if bool((change <= SETTLE_TOLERANCE * torch.maximum(scale, x[0, list(unread)].abs())).all()):
                settled = list(states)
                for j in unread:
                    settled[j] = (float(x[0, j]), states[j][1])
                return settled
    return states


LEVEL_ITERATIONS = 30  # Gauss-Newton steps of the measured level's fit (each one evaluation of h and its slope)


def output_level_state_scales(system: LTIModel, params: PhysicalParameters, inputs: Sequence[Scale],
                              outputs: Sequence[Scale | None], states: list[Scale], unread: Sequence[int]
                              ) -> list[Scale]:
    """``states`` with the operating point of each ``unread`` state of a system with a nonlinear output
    (``LTIModel.output_nonlinearity``): the states that settle (A x + B ū + e = 0 decides them) where
    they settle, and the levels the dynamics leave free (A's null space: a state of charge) where the
    outputs at that point, C x + D ū + h(x, ū), are the measured means (``outputs``: each output's
    (mean, std) in the data, None where it is not measured), by Gauss-Newton in the outputs' spreads.

    A cell's OCV read through h: no output reads its state of charge alone, and 0 (the default of a
    state no data give) is an empty cell, where the estimate's ridge would pull it and the OCV
    curve may have no meaning. Where no level fits better than the start, the states are kept."""
    if not unread:
        return states
    unread = list(unread)
    with torch.no_grad():
        p = params.values(system.parameter_names, torch.float64)
        ss = system.matrices(p)
        u = torch.tensor([m for m, _ in inputs], dtype=torch.float64)
        x = torch.tensor([m for m, _ in states], dtype=torch.float64)
        force = ss.b @ u + (ss.e if ss.e is not None else 0.0)
        settled = -torch.linalg.pinv(ss.a) @ force  # the settling states' level; the free ones' 0
        _, sv, vh = torch.linalg.svd(ss.a)
        tol = 1e-9 * float(sv.max()) if sv.numel() and float(sv.max()) > 0 else 1e-300
        free = vh[vh.shape[0] - int((sv <= tol).sum()):]  # (k, n): A's null space, the levels it leaves free
        rows = [i for i, o in enumerate(outputs) if o is not None]
        if not rows:
            return states
        target = torch.tensor([outputs[i][0] for i in rows], dtype=torch.float64)
        spread = torch.tensor([outputs[i][1] for i in rows], dtype=torch.float64)
        mask = torch.zeros(len(states), dtype=torch.float64)
        mask[unread] = 1.0
        base = torch.where(mask.bool(), settled, x)
        basis = free * mask  # only the unread states move
        basis = basis[basis.abs().sum(1) > 0]

    def residual(alpha: torch.Tensor) -> torch.Tensor:
        point = base + alpha @ basis
        y = ss.c @ point + ss.d @ u + system.output_nonlinearity(point, u, p)
        return (y[rows] - target) / spread

    alpha = torch.zeros(basis.shape[0], dtype=torch.float64)
    try:
        with torch.no_grad():
            cost = float(residual(alpha).square().sum())
        start_cost = cost
        for _ in range(LEVEL_ITERATIONS if basis.shape[0] else 0):
            r = residual(alpha).detach()
            jac = torch.func.jacrev(residual)(alpha).detach()  # (rows, k)
            step = torch.linalg.lstsq(jac, -r[:, None]).solution[:, 0]
            for halved in range(8):
                trial = alpha + step / 2**halved
                trial_cost = float(residual(trial).detach().square().sum())
                if trial_cost < cost:
                    break
            else:
                break
            alpha, cost = trial, trial_cost
            if float(step.abs().max()) < 1e-12:
                break
    except (ArithmeticError, ValueError, RuntimeError):
        return states
    point = (base + alpha @ basis).detach()
    if not (bool(torch.isfinite(point).all()) and cost <= start_cost):
        return states
    out = list(states)
    for j in unread:
        out[j] = (float(point[j]), states[j][1])
    return out
