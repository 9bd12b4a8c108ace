"""What an explanation is about and what it found: the explained signal (``ExplainedSignal``; the
diagnosis's ``Problem`` is another thing), the ladder's settings and result (``Settings``,
``BlockExplanation``), and their formatting.

The types every part of ``hypa.explain`` reads (the run, the report, the figures), with
nothing of how they are computed, so those parts import them without a circle.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from hypa.core.units import unit_ratio
from hypa.explain.forms import Explanation
from hypa.reporting.numbers import significant

FIT_SPLIT, SCORE_SPLIT = "train", "val"
PAIRS = {"learned_vs_measured": ("measured", "learned"), "explained_vs_measured": ("measured", "explained"),
         "explained_vs_learned": ("learned", "explained")}


@dataclass(frozen=True)
class Settings:
    """How the ladder is fitted (see :func:`hypa.explain.explain`); ``extra`` None: the default extras."""

    extra: tuple[str, ...] | None = None
    penalty: float = 0.002
    margin: float = 0.005
    max_lag: float = 2.0  # [s]
    max_delay: float = 0.25  # [s]
    plot: bool = True


@dataclass(frozen=True)
class ExplainedSignal:
    """One explained signal: an output of an ANN block, its regressors and extra signals, their units.

    A correction network (``residual_of``) adds its output to a physics signal: what it learned
    is the difference, so ``output`` is then ``<output>_correction`` and ``corrects`` holds the
    (total, physics) pair it is computed from. ``measured``: the channel of the records that
    measures the output, where one does (:func:`measuring_channel`)."""

    block: str
    output: str
    inputs: tuple[str, ...]
    extra: tuple[str, ...]
    units: Mapping[str, str]
    corrects: tuple[str, str] | None = None
    measured: str | None = None

    @property
    def names(self) -> tuple[str, ...]:
        return (self.output, *self.inputs, *self.extra)

    @property
    def key(self) -> str:
        """A file-name stem: the block, and the output where the block has several."""
        return self.block if self.output == self.block else f"{self.block}_{self.output}"


@dataclass
class BlockExplanation:
    """The ladder fitted to one problem, compared with the measurement where one exists."""

    problem: ExplainedSignal
    explanation: Explanation
    comparison: dict[str, dict[str, float]] | None  # PAIRS -> corr, rms, share (validation)
    figures: dict[str, Path] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    replacement: dict | None = None  # the block replaced by its form: config, validation errors (hypa.explain.replace)
    seconds: float = 0.0  # [s] fitting the ladder (the free runs, the replacement and the figures not counted)

    def summary(self) -> str:
        """One line: the block, the chosen form, and the comparison with the measurement."""
        line = f"{self.problem.block}: {self.explanation.describe()}"
        if self.comparison:
            unit = self.problem.units[self.problem.output]
            lm, em = self.comparison["learned_vs_measured"], self.comparison["explained_vs_measured"]
            line += (f"; vs measured {self.problem.measured}: "
                     f"learned r {lm['corr']:.2f} (RMS {significant(lm['rms'])} {unit}), "
                     f"explained r {em['corr']:.2f} (RMS {significant(em['rms'])} {unit})")
        return line


def gain_unit(problem: ExplainedSignal) -> str:
    """Unit of the gain from the block's first input to its output."""
    return unit_ratio(problem.units[problem.output], problem.units[problem.inputs[0]])
