"""A user's own system for hypa: a DC motor driving an inertia (armature current and speed).

This file is all hypa needs: an ``LTIModel`` subclass in an importable module. With this
folder on the Python path a model YAML names it by import path::

    blocks:
      motor:
        kind: physics
        system: dc_motor:DCMotor
        inputs: [voltage]
        outputs: [speed]
        initial_state: estimate          # the current is not measured
        trainable: [torque_constant, friction, load_torque]

Physics (armature inductance L, resistance R, torque / back-EMF constant K, rotor inertia J,
viscous friction b, a constant load torque τL)::

    L di/dt = V - R i - K ω
    J dω/dt = K i - b ω - τL

so with x = [i, ω], u = [V], y = [ω]:

    A = [[-R/L, -K/L], [K/J, -b/J]],  B = [[1/L], [0]],  C = [[0, 1]],  D = [[0]],  e = [0, -τL/J]

Run ``python dc_motor.py`` to check the contract and print a voltage step's final speed
against the static one, K V / (R b + K²) (zero load torque).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics import LTIModel, ParameterSpec, StateSpace


class DCMotor(LTIModel):
    """A permanent-magnet DC motor: voltage [V] in, speed [rad/s] out (current [A] a hidden state).

    Parameters show the three kinds of storage: positive (log-stored), bounded (a torque
    constant known to lie in a catalogue range) and signed within bounds (a load torque).
    """

    state_names = ("current", "speed")
    input_names = ("voltage",)
    output_names = ("speed",)
    parameters = (
        ParameterSpec("resistance", 1.0, "Ohm"),
        ParameterSpec("inductance", 2e-3, "H"),
        ParameterSpec("torque_constant", 0.05, "N m/A", bounds=(0.01, 0.2)),
        ParameterSpec("inertia", 1e-4, "kg m^2"),
        ParameterSpec("friction", 1e-5, "N m s/rad"),
        ParameterSpec("load_torque", 0.0, "N m", positive=False, bounds=(-0.05, 0.05)),
    )

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        """Continuous A, B, C, D, e from scalar parameter tensors (torch ops: differentiable)."""
        r, ind, k, j = p["resistance"], p["inductance"], p["torque_constant"], p["inertia"]
        b, load = p["friction"], p["load_torque"]
        zero, one = torch.zeros_like(r), torch.ones_like(r)
        a = torch.stack([torch.stack([-r / ind, -k / ind]), torch.stack([k / j, -b / j])])  # (2, 2)
        b_in = torch.stack([1.0 / ind, zero]).reshape(2, 1)  # (2, 1)
        c = torch.stack([zero, one]).reshape(1, 2)  # (1, 2): y = speed
        e = torch.stack([zero, -load / j])  # (2,): the load torque decelerates the rotor
        return StateSpace(a, b_in, c, r.new_zeros(1, 1), e)


if __name__ == "__main__":
    from hypa.physics import LTIBlock, PhysicalParameters, check_system

    motor = DCMotor()
    check_system(motor)
    block = LTIBlock(motor, PhysicalParameters(motor.parameters), dt=1e-3, horizon=100)
    block.check_stable()
    volts = torch.full((1, 1000, 1), 12.0, dtype=torch.float64)  # a 12 V step for 1 s
    speed = block.simulate_physical(torch.zeros(1, 2, dtype=torch.float64), volts)[0, -1, 0]
    nominal = {s.name: s.value for s in motor.parameters}
    k, r, b = nominal["torque_constant"], nominal["resistance"], nominal["friction"]
    print(f"speed after 1 s: {float(speed):.3f} rad/s; static: {k * 12.0 / (r * b + k * k):.3f} rad/s")
