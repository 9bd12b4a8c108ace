"""Cascaded tanks: a pump fills an upper tank, which drains into a lower one, which drains away.

Linear (``cascaded_tanks``), the outflows linearised about a level:

    d upper / dt = -k1 upper + gain pump
    d lower / dt =  k1 upper - k2 lower,        level = lower

The levels are in the unit of the lower tank's level sensor (V on the cascaded-tanks benchmark,
``../shared/data/cascaded_tanks``), the pump in its input unit. This is the physics an engineer
writes first: the outflows linearised about a level. Real outflows through an orifice follow
Torricelli's √h, and the upper tank overflows at its rim: what ``hypa diagnose`` is for (its
``root_state`` entry bends a positive state's couplings towards √h, ``upper_state_limit`` lets a
state spill over a level). The upper level is not measured: a window starts from the estimate
over its past samples (``initial_state: estimate``).

Through orifices (``torricelli_tanks``, :class:`TorricelliTanks`), Torricelli's law with the tanks
alike (the flow out of the upper one is the flow into the lower one, both levels in the sensor's
unit):

    d upper / dt = -k1 upper^a + gain (pump - pump_offset)
    d lower / dt =  k1 upper^a - k2 (lower - level_offset)^a,        level = lower

a = 1/2 for an orifice; the pump's inflow is linear in its input from ``pump_offset`` on (its
voltage at no flow), ``level_offset`` is what the sensor reads at the lower orifice's height (a
level's root is taken above 0: an empty tank drains nothing). A tank that overflows is the model's
``limited:`` key (``hypa.physics.limited``): the upper tank's spill, a share of it falling into the
lower one; the lower tank's, lost. The sensor may read the level along a curve,

    level = lower + sensor_curvature (lower - level_offset)^2

(``sensor_curvature`` 0: a linear sensor; a capacitive or pressure sensor's reading bends with the
level): the states stay in the linear scale, the outputs bend.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, StateSpace

FLOOR = 1e-6  # [sensor unit] a level's root is taken above it: an empty tank drains nothing, with a finite slope


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


class TorricelliTanks(LTIModel):
    """Two alike tanks in series draining through orifices, q = k h^a (module docstring)."""

    state_names = ("upper", "lower")
    input_names = ("pump",)
    output_names = ("level",)
    parameters = (
        ParameterSpec("k1", 0.05, "V^0.5/s"),  # the upper orifice: its outflow, into the lower tank, per root of level
        ParameterSpec("k2", 0.05, "V^0.5/s"),  # the lower orifice's
        ParameterSpec("gain", 0.03, "1/s"),  # the pump's inflow per unit input, as a rise of the upper level
        ParameterSpec("exponent", 0.5, "-"),  # a of q = k h^a: 1/2 through an orifice (Torricelli)
        ParameterSpec("pump_offset", 0.0, "V", positive=False),  # the pump's input at no flow
        ParameterSpec("level_offset", 0.0, "V", positive=False),  # what the sensor reads at the lower orifice
        ParameterSpec("sensor_curvature", 0.0, "1/V", positive=False),  # the sensor's reading bends with the level
    )

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        gain = p["gain"]
        zero, one = torch.zeros_like(gain), torch.ones_like(gain)
        return StateSpace(torch.zeros(2, 2, dtype=gain.dtype), torch.stack([gain, zero]).reshape(2, 1),
                          torch.stack([zero, one]).reshape(1, 2), gain.new_zeros(1, 1),
                          torch.stack([-gain * p["pump_offset"], zero]))

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        k1, k2 = p["k1"], p["k2"]
        return torch.stack([torch.stack([-k1, torch.zeros_like(k1)]), torch.stack([k1, -k2])])

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        origin = torch.stack([torch.zeros_like(p["level_offset"]), p["level_offset"]])
        return (x - origin).clamp_min(FLOOR) ** p["exponent"]

    output_reads_inputs = False  # the sensor's curve reads the level only

    def output_nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        return p["sensor_curvature"] * (x[..., 1:2] - p["level_offset"]) ** 2
