"""Measured data for the DC-motor example, made by simulation (a stand-in for your logger's files).

    python make_data.py OUT_DIR [--seconds 60]

writes ``train.csv`` and ``val.csv`` (time [s], voltage [V], speed [rpm], current [A]) from a
"true" motor whose torque constant, friction and load torque differ from ``DCMotor``'s nominal
values, driven by a random staircase of voltages, with 0.5 % speed-sensor noise. The physics is
hypa's own (``LTIBlock.simulate_physical``), so what a fit should find is known exactly.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import torch

from dc_motor import DCMotor
from hypa.physics import LTIBlock, PhysicalParameters, ParameterSpec

TRUE = {"torque_constant": 0.065, "friction": 3e-5, "load_torque": 0.004}  # the nominal model is off
RATE_HZ = 1000.0
RPM = 60 / (2 * math.pi)  # rad/s -> rpm


def simulate(seconds: float, seed: int) -> dict[str, np.ndarray]:
    motor = DCMotor()
    specs = [ParameterSpec(s.name, TRUE.get(s.name, s.value), s.unit, s.positive, s.bounds) for s in motor.parameters]
    block = LTIBlock(motor, PhysicalParameters(specs), dt=1 / RATE_HZ, horizon=100, hold="zoh")
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE_HZ)
    steps = rng.uniform(-12, 12, size=n // 200 + 1)  # a new voltage every 0.2 s
    voltage = np.repeat(steps, 200)[:n]
    u = torch.tensor(voltage, dtype=torch.float64)[None, :, None]
    with torch.no_grad():  # the states [current, speed] over time, from rest
        states = block.states(torch.zeros(1, 2, dtype=torch.float64), u[:, :-1])[0].numpy()
    states = np.concatenate([np.zeros((1, 2)), states])
    speed = states[:, 1] * (1 + 0.005 * rng.standard_normal(n))
    return {"time": np.arange(n) / RATE_HZ, "voltage": voltage, "speed": speed * RPM, "current": states[:, 0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name, seed, share in (("train", 0, 1.0), ("val", 1, 0.4)):
        columns = simulate(args.seconds * share, seed)
        header = ",".join(columns)
        np.savetxt(args.out / f"{name}.csv", np.column_stack(list(columns.values())), delimiter=",",
                   header=header, comments="", fmt="%.9g")
    print(f"wrote {args.out / 'train.csv'} and {args.out / 'val.csv'}")


if __name__ == "__main__":
    main()
