"""Training: the LightningModule and its callbacks (stages, figures); :mod:`hypa.training.baseline`
holds the defaults (the learning rates, and the networks' budget from the data's size).

Names are imported lazily (PEP 562), so the defaults are read without importing Lightning.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {"HybridModule": "module", "StagedTraining": "staging", "ValidationFigures": "figures"}

__all__ = sorted(_EXPORTS)  # noqa: PLE0605 -- a list of the lazy exports' names


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'hypa.training' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"hypa.training.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
