"""Evaluation and diagnosis: Table 1 metrics, frequency responses (Fig. 5) and their figures."""

from hypa.metrics import METRICS, floored_mape, regression_metrics, state_metrics
from hypa.evaluation.plots import bode, rear_steer
from hypa.evaluation.transfer import TransferEstimate, frequency_response, h1_estimate

__all__ = [
    "METRICS",
    "TransferEstimate",
    "bode",
    "floored_mape",
    "frequency_response",
    "h1_estimate",
    "rear_steer",
    "regression_metrics",
    "state_metrics",
]
