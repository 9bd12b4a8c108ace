"""Measurement chain of the test bench: white noise and a constant bias per channel."""

from __future__ import annotations

import numpy as np

from hypa.data.channels import ChannelSpec
from hypa.paper.testbench.config import SensorConfig
from hypa.paper.testbench.excitation import NOISE_STREAM

# Measured channels, in the order the noise is drawn (changing it changes every file).
CHANNELS = (
    "steering_wheel_angle",
    "yaw_rate",
    "side_slip",
    "lateral_acceleration",
    "velocity",
    "rear_wheel_angle",
)
#: The files are written in the measured-data format hypa reads: its standard names and SI units
#: (a column's unit, the one declaration every channel below reads).
UNITS: dict[str, str] = {
    "time": "s",
    "steering_wheel_angle": "rad",
    "yaw_rate": "rad/s",
    "side_slip": "rad",
    "lateral_acceleration": "m/s^2",
    "velocity": "m/s",
    "rear_wheel_angle": "rad",
}

#: The default data set's declarations (mirrors conf/dataset/testbench.yaml): the paper trains
#: without the measured rear wheel angle and uses it afterwards to judge the learned RWS block.
TESTBENCH_CHANNELS: tuple[ChannelSpec, ...] = (
    ChannelSpec("steering_wheel_angle", "input", UNITS["steering_wheel_angle"], display_unit="deg"),
    ChannelSpec("yaw_rate", "output", UNITS["yaw_rate"], display_unit="deg/s"),
    ChannelSpec("side_slip", "output", UNITS["side_slip"], display_unit="deg"),
    ChannelSpec("rear_wheel_angle", "evaluation", UNITS["rear_wheel_angle"], display_unit="deg"),
    ChannelSpec("lateral_acceleration", "evaluation", UNITS["lateral_acceleration"]),
)


def measure(
    truth: dict[str, np.ndarray], sensors: SensorConfig, seed: int
) -> dict[str, np.ndarray]:
    """Measured channels: truth + bias_scale * bias + noise_scale * noise_std * N(0, 1).

    ``truth`` maps every name of :data:`CHANNELS` to its true signal (channel units).
    Every channel draws its noise even when its scale is zero, so switching one channel
    off leaves the noise of the others (and the excitation, a separate stream) unchanged.
    """
    missing = [name for name in CHANNELS if name not in truth]
    if missing:
        raise ValueError(f"truth lacks channels {missing}")
    rng = np.random.default_rng([seed, NOISE_STREAM])
    measured = {}
    for name in CHANNELS:
        true = np.asarray(truth[name], dtype=float)
        noise = rng.standard_normal(true.shape)
        if not sensors.enabled:
            measured[name] = true.copy()
            continue
        channel = getattr(sensors, name)
        bias = sensors.bias_scale * channel.bias
        measured[name] = true + bias + sensors.noise_scale * channel.noise_std * noise
    return measured
