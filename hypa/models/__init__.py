"""Compositions of physics and ANN blocks wired by named signals (``model`` config group).

Names are imported lazily (PEP 562), so a model's spec and its schema (:mod:`hypa.models.spec`,
:mod:`hypa.models.schema`) are read without importing torch.
"""

from __future__ import annotations

from hypa.core.lazy import lazy_exports

_EXPORTS = {"ComposedModel": "composed", "Prediction": "rollout", "free_run": "rollout", "free_run_metrics": "rollout",
            "model_inputs": "rollout", "BlockSpec": "spec", "ModelSpec": "spec", "ModelSpecError": "spec",
            "StageSpec": "spec", "parse_model_spec": "spec", "spec_config": "spec"}

__all__ = sorted(_EXPORTS)  # noqa: PLE0605 -- a list of the lazy exports' names


__getattr__, __dir__ = lazy_exports(__name__, globals(), _EXPORTS)
