"""Simulated handling test bench: the default (synthetic) measured data of hypa.

A nonlinear single-track truth with saturating axles, tyre relaxation and an active
rear-wheel-steering ECU the nominal physics does not know, excited by a steering robot
(stochastic and deterministic programmes) and measured with noisy, biased sensors.
"""

from hypa.paper.testbench.config import TestbenchConfig
from hypa.paper.testbench.dataset import ensure_dataset, generate_dataset, load_description
from hypa.paper.testbench.records import SimulatedRecord, read_record, simulate_record

__all__ = [
    "SimulatedRecord",
    "TestbenchConfig",
    "ensure_dataset",
    "generate_dataset",
    "load_description",
    "read_record",
    "simulate_record",
]
