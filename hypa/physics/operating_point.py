"""The operating point of nonlinear physics where no data give it: where the system settles.

A state that no output reads has no operating point in the data. For a linear system 0 serves
(its dynamics are the same everywhere), for a nonlinear one it does not: tanks draining through
orifices have no slope of √h at 0 V. :func:`settled_state_scales` puts such a state where the
nominal system settles under the inputs' mean.
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
