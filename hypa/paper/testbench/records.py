"""One test-bench run: excitation -> truth -> sensors, and its measured-data file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from hypa.paper.testbench.config import RecordConfig, TestbenchConfig
from hypa.paper.testbench.excitation import Segment, steering_programme
from hypa.paper.testbench.sensors import CHANNELS, UNITS, measure
from hypa.paper.testbench.truth import TruthTrajectory, simulate_truth

COLUMNS = ("time", *CHANNELS)


@dataclass(frozen=True)
class SimulatedRecord:
    """A simulated measurement: the file's columns plus the noise-free truth behind them.

    ``columns`` maps :data:`COLUMNS` to arrays in SI units (see ``UNITS``); ``time`` starts
    at 0 s with a step of exactly 1 / sample rate. ``steering_wheel_angle`` is the robot's
    true angle [rad]; ``segments`` cover the record without gaps.
    """

    name: str
    columns: dict[str, np.ndarray]
    truth: TruthTrajectory
    steering_wheel_angle: np.ndarray
    segments: list[Segment]

    @property
    def duration_s(self) -> float:
        """Record length [s] = samples / sample rate (end of the last segment)."""
        return self.segments[-1].end_s


def config_truth(config: TestbenchConfig, steering_wheel_angle: np.ndarray) -> TruthTrajectory:
    """The truth of the test bench ``config`` (its vehicle, tires, relaxation, ECU, steering and load
    transfer) from rest, for a steering-wheel angle [rad] at its sample rate."""
    return simulate_truth(steering_wheel_angle, config.sample_rate_hz, config.vehicle, config.tires, config.relaxation,
                          config.rear_steering, config.steering, config.load_transfer)


def simulate_record(config: TestbenchConfig, record: str | RecordConfig) -> SimulatedRecord:
    """Simulate one record of ``config`` (by name, or any :class:`RecordConfig`)."""
    name = record if isinstance(record, str) else "record"
    spec = config.records[record] if isinstance(record, str) else record
    fs = config.sample_rate_hz
    steering_wheel_angle, segments = steering_programme(spec, config.excitation, fs)
    truth = config_truth(config, steering_wheel_angle)
    n = len(steering_wheel_angle)
    true_channels = {
        "steering_wheel_angle": steering_wheel_angle,
        "yaw_rate": truth.yaw_rate,
        "side_slip": truth.side_slip,
        "lateral_acceleration": truth.lateral_acceleration,
        "velocity": np.full(n, config.vehicle.velocity),
        "rear_wheel_angle": truth.rear_wheel_angle,
    }
    columns = {"time": np.arange(n) / fs, **measure(true_channels, config.sensors, spec.seed)}
    return SimulatedRecord(name, columns, truth, steering_wheel_angle, segments)


def write_record(path: Path, columns: dict[str, np.ndarray]) -> None:
    """Write the columns (float64, units in the field metadata) as a parquet file."""
    fields = [pa.field(name, pa.float64(), metadata={"unit": UNITS[name]}) for name in COLUMNS]
    table = pa.table(
        [np.asarray(columns[name], dtype=np.float64) for name in COLUMNS], schema=pa.schema(fields)
    )
    pq.write_table(table, path)


def read_record(path: Path) -> dict[str, np.ndarray]:
    """Read a measured-data file back as ``{column: float64 array}``."""
    table = pq.read_table(path)
    return {name: table.column(name).to_numpy() for name in table.column_names}
