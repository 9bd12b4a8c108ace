"""Evaluation and diagnosis: Table 1 metrics, frequency responses (Fig. 5) and their figures; the
results (:class:`Evaluation` with its :class:`RunMetrics`, ``metrics.json``; :class:`Benchmark`,
``benchmark.json``) and their writers."""

from hypa.core.metrics import METRICS, floored_mape, regression_metrics, state_metrics
from hypa.evaluation.benchmark_result import Benchmark
from hypa.evaluation.figures import bode, rear_steer
from hypa.evaluation.result import Evaluation, RunMetrics
from hypa.evaluation.transfer import TransferEstimate, frequency_response, h1_estimate

__all__ = [
    "METRICS",
    "Benchmark",
    "Evaluation",
    "RunMetrics",
    "TransferEstimate",
    "bode",
    "floored_mape",
    "frequency_response",
    "h1_estimate",
    "rear_steer",
    "regression_metrics",
    "state_metrics",
]
