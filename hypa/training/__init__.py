"""Training: the LightningModule and its callbacks (stages, figures)."""

from hypa.training.figures import ValidationFigures
from hypa.training.module import HybridModule
from hypa.training.staging import StagedTraining

__all__ = ["HybridModule", "StagedTraining", "ValidationFigures"]
