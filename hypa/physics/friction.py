"""A mass with viscous friction and an offset force, driven by a force: the EMPS axis.

The EMPS (electro-mechanical positioning system, Janot et al. 2019) is a prismatic joint: a
motor force u moves a load of mass M along a ball screw. Its reference model is

    M q̈ = u - Fv q̇ - Fc sign(q̇) + F0

with states x = [position q (m), velocity q̇ (m/s)], output y = [position q]. The Coulomb term
Fc sign(q̇) is not linear (``MassWithCoulombFriction``, fed back in Lur'e form, as is a friction
growing with the cube of the speed, ``MassWithCubicFriction``); the rest is the state space

    A = [[0, 1], [0, -Fv/M]],   B = [[0], [1/M]],   C = [[1, 0]],   D = [[0]],   e = [0, F0/M]

A has an eigenvalue 0 (the position integrates the velocity): marginally stable, which
``LTIBlock.check_stable`` accepts.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.lti import LTIModel, StateSpace
from hypa.physics.parameters import ParameterSpec


class MassWithFriction(LTIModel):
    """Parameters: ``mass`` M [kg], ``viscous_friction`` Fv [N s/m] (positive), ``offset_force``
    F0 [N] (signed: a constant force on the load, e.g. a cable's pull or gravity on a tilt).

    Nominal values are Janot et al.'s identified EMPS model (M = 95.1 kg, Fv = 203.5 N s/m,
    offset OF = -3.16 N, written there on the friction side: F0 = -OF).
    """

    state_names = ("position", "velocity")
    input_names = ("force",)
    output_names = ("position",)
    parameters = (
        ParameterSpec("mass", 95.1, "kg"),
        ParameterSpec("viscous_friction", 203.5, "N s/m"),
        ParameterSpec("offset_force", 3.16, "N", positive=False),
    )

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        m, fv, f0 = p["mass"], p["viscous_friction"], p["offset_force"]
        zero, one = torch.zeros_like(m), torch.ones_like(m)
        a = torch.stack([torch.stack([zero, one]), torch.stack([zero, -fv / m])])  # (2, 2)
        b = torch.stack([zero, 1.0 / m]).reshape(2, 1)
        c = torch.stack([one, zero]).reshape(1, 2)  # y = position
        e = torch.stack([zero, f0 / m])  # (2,) the offset force accelerates the load
        return StateSpace(a, b, c, m.new_zeros(1, 1), e)


class MassWithCoulombFriction(MassWithFriction):
    """The EMPS reference model with its Coulomb friction: M q̈ = u - Fv q̇ - Fc sign(q̇) + F0,
    ``coulomb_friction`` Fc [N] (positive; Janot et al. identified ≈ 20 N), sign(q̇) smoothed to
    tanh(q̇ / v_s) with v_s = ``SMOOTHING_MPS`` (differentiable; far below the axis' speeds). The
    Coulomb force is fed back in Lur'e form (F = [0, 1/M]): nonlinear, simulated step by step."""

    SMOOTHING_MPS = 0.005  # [m/s]

    parameters = (*MassWithFriction.parameters, ParameterSpec("coulomb_friction", 20.0, "N"))

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        m = p["mass"]
        return torch.stack([torch.zeros_like(m), 1.0 / m]).reshape(2, 1)

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        return {"coulomb": -p["coulomb_friction"]}  # once per simulation, not at every sample

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        return p["coulomb"] * torch.tanh(x[..., 1:2] * (1.0 / self.SMOOTHING_MPS))


class MassWithCubicFriction(MassWithCoulombFriction):
    """The Coulomb model with a viscous friction that is not linear in the speed: its force
    Fv q̇ becomes Fv q̇ ((1 - w) + w q̇² / v_c²), so

        M q̈ = u - Fv (1 - w) q̇ - Fv w q̇³ / v_c² - Fc sign(q̇) + F0

    ``cubic_share`` w (signed; 0: the Coulomb model) is the share of the viscous force that grows
    with the cube of the speed, ``cubic_speed`` v_c [m/s] the speed at which the two laws give the
    same force (w pivots the friction curve about it). A lubricated contact's friction rises
    faster than linearly at speed (w > 0); w < 0 flattens it. Nominal: w = 0 and v_c = Fc / Fv at
    the nominal values (0.098 m/s), the speed at which the viscous friction equals the Coulomb one:
    the model's own speed scale. Fitted with the others, w and Fv give the two coefficients of the
    friction law; v_c only sets their units, so it is left fixed (with w and Fv it is not
    identifiable). The cubic term is fed back with the Coulomb force."""

    parameters = (*MassWithCoulombFriction.parameters, ParameterSpec("cubic_share", 0.0, "-", positive=False),
                  ParameterSpec("cubic_speed", 20.0 / 203.5, "m/s"))

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        share = p["viscous_friction"] * p["cubic_share"]  # Fv w: the viscous force moved to the cubic law
        return {**super().prepare(p), "linear": share, "cubic": -share / p["cubic_speed"] ** 2}

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        v = x[..., 1:2]
        return super().nonlinearity(x, u, p) + v * torch.addcmul(p["linear"], v * v, p["cubic"])
