"""Cascaded tanks, linear: a pump fills an upper tank, which drains into a lower one, which drains away.

    d upper / dt = -k1 upper + gain pump
    d lower / dt =  k1 upper - k2 lower,        level = lower

The levels are in the unit of the lower tank's level sensor (V on the cascaded-tanks benchmark,
``../shared/data/cascaded_tanks``), the pump in its input unit. This is the physics an engineer
writes first: the outflows linearised about a level. Real outflows through an orifice follow
Torricelli's √h, and the upper tank overflows at its rim: what ``hypa diagnose`` is for (its
``root_state`` entry bends a positive state's couplings towards √h, ``upper_state_limit`` lets a
state spill over a level). The upper level is not measured: a window starts from the estimate
over its past samples (``initial_state: estimate``).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, StateSpace


class CascadedTanks(LTIModel):
    """Two tanks in series, outflows linear in the level (module docstring)."""

    state_names = ("upper", "lower")
    input_names = ("pump",)
    output_names = ("level",)
    parameters = (
        ParameterSpec("k1", 0.02, "1/s"),  # the upper tank's outflow per level, into the lower tank
        ParameterSpec("k2", 0.02, "1/s"),  # the lower tank's outflow per level
        ParameterSpec("gain", 0.02, "1/s"),  # the pump's inflow per unit input, as a rise of the upper level
    )

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        k1, k2, gain = p["k1"], p["k2"], p["gain"]
        zero, one = torch.zeros_like(k1), torch.ones_like(k1)
        a = torch.stack([torch.stack([-k1, zero]), torch.stack([k1, -k2])])
        return StateSpace(a, torch.stack([gain, zero]).reshape(2, 1), torch.stack([zero, one]).reshape(1, 2),
                          k1.new_zeros(1, 1))
