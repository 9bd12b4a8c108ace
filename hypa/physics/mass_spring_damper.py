"""A non-vehicle instance of the generic LTI block: a mass-spring-damper driven by a force.

m q̈ + d q̇ + k q = F + F0   with states x = [position q (m), velocity q̇ (m/s)], input u = [force F (N)]
and output y = [position q] (the velocity is not measured):

    A = [[0, 1], [-k/m, -d/m]],   B = [[0], [1/m]],   C = [[1, 0]],   D = [[0]],   e = [0, F0/m]

(a constant force F0 shifts the rest position by F0 / k: a measurement's DC offset).

It is the linear part of the Silverbox benchmark (an electronic Duffing oscillator; its cubic
spring is left to a network), so the nominal values are those of an output-error fit of
Silverbox's linear part, with its input voltage as the force and its output voltage as the
position: resonance √(k/m) / 2π ≈ 70 Hz, damping ratio d / (2 √(k m)) ≈ 0.05, static gain
1 / k ≈ 1.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.lti import LTIModel, StateSpace
from hypa.physics.parameters import ParameterSpec


class MassSpringDamper(LTIModel):
    """Parameters: ``mass`` [kg], ``stiffness`` [N/m], ``damping`` [N s/m], all positive;
    ``offset_force`` F0 [N], signed (nominal 0: give a nonzero nominal value where it is fitted,
    so that its optimizer steps are relative to its size)."""

    state_names = ("position", "velocity")
    input_names = ("force",)
    output_names = ("position",)
    parameters = (
        ParameterSpec("mass", 5.1e-6, "kg"),
        ParameterSpec("stiffness", 0.98, "N/m"),
        ParameterSpec("damping", 2.2e-4, "N s/m"),
        ParameterSpec("offset_force", 0.0, "N", positive=False),
    )

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        m, k, d, f0 = p["mass"], p["stiffness"], p["damping"], p["offset_force"]
        zero, one = torch.zeros_like(m), torch.ones_like(m)
        a = torch.stack([torch.stack([zero, one]), torch.stack([-k / m, -d / m])])  # (2, 2)
        b = torch.stack([zero, 1.0 / m]).reshape(2, 1)
        c = torch.stack([one, zero]).reshape(1, 2)  # y = position
        return StateSpace(a, b, c, m.new_zeros(1, 1), torch.stack([zero, f0 / m]))


class DuffingOscillator(MassSpringDamper):
    """The mass-spring-damper with a stiffening spring (Duffing): the spring force is
    k q (1 + h q²), so ``hardening`` h [1/m²] (signed: < 0 softens) adds the cubic force
    -k h q³ to the linear part, fed back in Lur'e form (F = [0, 1/m]). Silverbox's nonlinearity."""

    parameters = (*MassSpringDamper.parameters, ParameterSpec("hardening", 1.0, "1/m^2", positive=False))

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        m = p["mass"]
        return torch.stack([torch.zeros_like(m), 1.0 / m]).reshape(2, 1)

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        q = x[..., :1]
        return -p["stiffness"] * p["hardening"] * q**3
