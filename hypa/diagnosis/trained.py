"""Step 4 with training: train the written extension, free-run it and explain the networks it added.

``hypa diagnose extension.train=true`` trains the written model with the printed ``hypa train``
arguments (the command gives the training: in its own process, the progress on the console, the run
folder inside the diagnosis folder), loads the best checkpoint and
free-runs it over the validation records, so the report can put the trained model (the named
causes, plus a correction network where structure stays unexplained) beside the nominal one.
Each network of the trained model is then explained by :func:`hypa.explain.explain_run` (what
the correction adds, as a form in units), into ``extended_run/explanation``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hypa.core.errors import UserError
from hypa.data import HypaDataModule
from hypa.diagnosis.result import NetworkExplanation
from hypa.evaluation.api import run_datamodule
from hypa.evaluation.runs import load_run
from hypa.explain.api import Settings, ann_blocks, explain_run
from hypa.models.rollout import Prediction, free_run


class ExtensionTrainingError(UserError):
    """The training of the written extension failed (the message says why and gives the ``hypa
    train`` command to rerun it alone), so ``hypa diagnose`` reports it in one line."""


@dataclass
class TrainedExtension:
    """The trained extension: its run folder, its free runs over the validation records and, per
    output of each of its networks, what that network learned (``explanations``)."""

    run: Path
    predictions: list[Prediction]
    explanations: list[NetworkExplanation] = field(default_factory=list)


def train_extension(train: Callable[[Sequence[str], Path], None], arguments: Sequence[str], run_dir: Path,
                    dm: HypaDataModule, extra_overrides: Sequence[str] = (), explain: bool = True, plot: bool = True,
                    progress: Callable[[str], None] = lambda text: None) -> TrainedExtension:
    """Train with ``hypa train ARGUMENTS`` into ``run_dir`` (``train(arguments, run_dir)``, which the
    command gives: it raises :class:`ExtensionTrainingError` when the training fails), free-run its best
    checkpoint over ``dm``'s validation records and (``explain``) explain its networks.
    ``extra_overrides``: more ``hypa train`` overrides (e.g. a shorter training: ``trainer.max_epochs=5``)."""
    train([*arguments, *extra_overrides], run_dir)
    run = load_run(run_dir, trust=("*",))  # the run it trained just now, from its own model
    model = run.module.model
    if run.settings.data.get("past") != dm.past:  # raised for the extension (hypa.diagnosis.api.with_past)
        dm = run_datamodule(run)
    trained = TrainedExtension(run_dir, [free_run(model, dm, record) for record in dm.records("val")])
    if explain:
        trained.explanations = explain_networks(run, dm, run_dir / "explanation", plot, progress)
    return trained


def explain_networks(run, dm: HypaDataModule, out: Path, plot: bool = True,
                     progress: Callable[[str], None] = lambda text: None) -> list[NetworkExplanation]:
    """What each network of a trained run learned (:func:`hypa.explain.explain_run`), one entry per
    explained signal: block, signal, the chosen form in words, its validation R² and the report."""
    if not ann_blocks(run.module.model.spec):
        return []
    results = explain_run(run, dm, out, settings=Settings(plot=plot), progress=progress)
    return [NetworkExplanation(r.problem.block, r.problem.output, r.explanation.describe(),
                               r.explanation.best.form.name, r.explanation.best.r2_val, str(out / "explanation.md"))
            for r in results]
