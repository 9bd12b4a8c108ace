"""Compositions of physics and ANN blocks wired by named signals (``model`` config group)."""

from hypa.models.composed import ComposedModel
from hypa.models.spec import BlockSpec, ModelSpec, ModelSpecError, StageSpec, parse_model_spec

__all__ = ["BlockSpec", "ComposedModel", "ModelSpec", "ModelSpecError", "StageSpec", "parse_model_spec"]
