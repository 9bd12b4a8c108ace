"""A non-vehicle instance of the generic LTI block: a mass-spring-damper driven by a force.

m q̈ + d q̇ + k q = F   with states x = [position q (m), velocity q̇ (m/s)], input u = [force F (N)]:

    A = [[0, 1], [-k/m, -d/m]],   B = [[0], [1/m]]
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.lti import LTIModel, StateSpace
from hypa.physics.parameters import ParameterSpec


class MassSpringDamper(LTIModel):
    """Parameters: ``mass`` [kg], ``stiffness`` [N/m], ``damping`` [N s/m], all positive."""

    state_names = ("position", "velocity")
    input_names = ("force",)
    output_names = ("position", "velocity")
    parameter_names = ("mass", "stiffness", "damping")

    def parameter_specs(self, values: Mapping[str, float]) -> list[ParameterSpec]:
        units = {"mass": "kg", "stiffness": "N/m", "damping": "N s/m"}
        return [ParameterSpec(k, float(values[k]), u) for k, u in units.items()]

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        m, k, d = p["mass"], p["stiffness"], p["damping"]
        zero, one = torch.zeros_like(m), torch.ones_like(m)
        a = torch.stack([torch.stack([zero, one]), torch.stack([-k / m, -d / m])])
        b = torch.stack([zero, 1.0 / m]).reshape(2, 1)
        return StateSpace(a, b, torch.eye(2, dtype=m.dtype, device=m.device), m.new_zeros(2, 1))
