"""Training: the LightningModule and its callbacks (stages, figures); :mod:`hypa.training.baseline`
holds the defaults (the learning rates, and the networks' budget from the data's size).

Names are imported lazily (PEP 562), so the defaults are read without importing Lightning.
"""

from __future__ import annotations

from hypa.core.lazy import lazy_exports

_EXPORTS = {"HybridModule": "module", "StagedTraining": "staging", "ValidationFigures": "figures"}

__all__ = sorted(_EXPORTS)  # noqa: PLE0605 -- a list of the lazy exports' names


__getattr__, __dir__ = lazy_exports(__name__, globals(), _EXPORTS)
