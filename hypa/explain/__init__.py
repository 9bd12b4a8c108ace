"""Explain what a learned block learned: parametric forms fitted to its input → output behaviour.

``explain(train, val, dt, output, inputs, extra, units)`` fits a ladder of forms (gain, lag,
delay, second order, odd nonlinearity, extra signals), scores each on the validation records
and chooses the simplest that explains the block (see :mod:`hypa.explain.forms`).
"""

from hypa.explain.forms import (
    Explanation,
    FittedForm,
    Form,
    Value,
    choose,
    explain,
    frequency_response,
    predict,
)
from hypa.explain.residual import AmplitudeBin, Band, Remainder
from hypa.explain.signals import Recording

__all__ = ["AmplitudeBin", "Band", "Explanation", "FittedForm", "Form", "Recording", "Remainder",
           "Value", "choose", "explain", "frequency_response", "predict"]
