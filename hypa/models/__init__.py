"""Compositions of physics and ANN blocks wired by named signals (``model`` config group)."""

from hypa.models.composed import ComposedModel
from hypa.models.rollout import Prediction, free_run, free_run_metrics, model_inputs
from hypa.models.spec import BlockSpec, ModelSpec, ModelSpecError, StageSpec, parse_model_spec, spec_config

__all__ = ["BlockSpec", "ComposedModel", "ModelSpec", "ModelSpecError", "Prediction", "StageSpec", "free_run",
           "free_run_metrics", "model_inputs", "parse_model_spec", "spec_config"]
