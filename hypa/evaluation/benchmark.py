"""Benchmark scores: a trained run simulated free-running over each test set, beside published figures.

Every test record is simulated from its start (the first ``past`` + 1 samples start the
model and are not scored, as in the benchmarks' own protocols) to its end; the RMS error and
R² per output are taken over all scored samples of a test set. A model trained with several
seeds is reported as the mean and standard deviation over its seeds: on a knife edge (the
free run of an integrating axis) one seed's figure says little.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from hypa.core.metrics import mean_std, regression_metrics
from hypa.data import HypaDataModule
from hypa.evaluation.benchmark_result import Benchmark, Summary
from hypa.evaluation.runs import TrainedRun
from hypa.models.rollout import free_run


@dataclass(frozen=True)
class Score:
    """One model (trained with one seed) on one test set and output: RMS error [SI] and R² of the free run."""

    model: str
    test_set: str
    output: str
    rms: float
    r2: float
    samples: int
    seed: int = 0


def summarize(scores: Sequence[Score]) -> dict[tuple[str, str, str], Summary]:
    """(model, test set, output) -> its ``Summary`` over seeds, in the order first seen."""
    groups: dict[tuple[str, str, str], list[Score]] = {}
    for s in scores:
        groups.setdefault((s.model, s.test_set, s.output), []).append(s)
    out = {}
    for key, group in groups.items():
        rms, r2 = mean_std(s.rms for s in group), mean_std(s.r2 for s in group)  # std 0 for one seed
        out[key] = Summary(rms.mean, rms.std, r2.mean, r2.std, group[0].samples, {s.seed: (s.rms, s.r2) for s in group})
    return out


def score_run(run: TrainedRun, dm: HypaDataModule, label: str, seed: int = 0) -> list[Score]:
    """Free-run scores of a trained run on every test set of its data (``dm.test_sets()``)."""
    scores = []
    for test_set, records in dm.test_sets().items():
        predictions = [free_run(run.module.model, dm, record) for record in records]
        for output in dm.output_names:
            predicted = np.concatenate([p.predicted[output][p.first :] for p in predictions])
            measured = np.concatenate([p.measured[output][p.first :] for p in predictions])
            m = regression_metrics(predicted, measured)
            scores.append(Score(label, test_set, output, m["mse"] ** 0.5, m["r2"], int(measured.size), seed))
    return scores


def benchmark(dataset: str, scores: Sequence[Score], training_time_s: Mapping[str, float],
              published: Mapping[str, Mapping], units: Mapping[str, tuple[str, float]],
              kept_physics: Mapping[str, Sequence[int]] | None = None,
              capped: Mapping[str, Sequence[str]] | None = None,
              failed: Mapping[str, str] | None = None, extends: Mapping[str, str] | None = None) -> Benchmark:
    """The data set's :class:`~hypa.evaluation.benchmark_result.Benchmark` (written by its
    ``to_json`` and ``markdown``): per model, test set and output the scores' mean ± std over seeds.

    ``units``: output -> (display unit, factor from SI); ``published``: test set -> output ->
    {label: RMS in the output's display unit}; ``training_time_s``: model -> mean seconds per seed
    (its order: the table's, with the models that have scores and those that failed);
    ``kept_physics``: model -> the seeds whose hybrid run kept its identified physics (its best checkpoint
    the model before its networks' first epoch); ``capped``: model -> where its identification or
    training stopped at a cap (:func:`stopped_at_caps`); ``failed``: model -> why it failed, one line;
    ``extends``: model -> the row of the identified physics it extends (compared under the table).
    """
    rows = summarize(scores)
    failed = dict(failed or {})
    models = dict.fromkeys([*training_time_s, *(k[0] for k in rows), *failed])
    return Benchmark(dataset, rows, {m: training_time_s.get(m) for m in models},
                     {k: {o: dict(f) for o, f in v.items()} for k, v in published.items()},
                     {k: (u, f) for k, (u, f) in units.items()},
                     {m: sorted(s) for m, s in (kept_physics or {}).items() if s},
                     {m: list(dict.fromkeys(c)) for m, c in (capped or {}).items() if c}, failed,
                     {m: b for m, b in (extends or {}).items() if m in models and b in models})


def stopped_at_caps(run: TrainedRun) -> list[str]:
    """Where a trained run stopped at a cap rather than by convergence or early stopping, one line
    each: its identification at ``identification.max_evaluations`` or ``max_seconds`` (``run.json``'s
    ``identification``), its training at ``trainer.max_epochs`` (its last checkpoint's epoch and stage
    against the run's configuration: the last stage, or every stage before it, ran its whole budget
    without early stopping)."""
    notes = []
    found = run.info.get("identification")
    if isinstance(found, dict) and not found.get("converged", True):
        cap = found.get("capped")
        if cap is None:  # a run of an older hypa: scipy's words, or the time limit's
            message = str(found.get("message", ""))
            cap = ("max_seconds" if "time limit" in message
                   else "max_evaluations" if "function evaluations" in message else None)
        if cap:
            notes.append(f"identification stopped at identification.{cap} (not converged)")
    epochs = _epochs_at_cap(run)
    if epochs:
        notes.append(f"training ran trainer.max_epochs={epochs} epochs{' per stage' if _staged(run) else ''} "
                     "without early stopping")
    return notes


def identified_only(run: TrainedRun) -> bool:
    """Whether the run is physics alone, identified (``best-identified.ckpt``, no epochs): nothing random
    enters it (``hypa.identification.output_error``), so every seed gives its model."""
    best = run.info.get("best_checkpoint")
    return isinstance(best, dict) and str(best.get("path", "")).endswith("best-identified.ckpt")


def reseeded(scores: Sequence[Score], seed: int) -> list[Score]:
    """``scores`` as another seed's (a model that no seed changes, :func:`identified_only`)."""
    return [replace(s, seed=seed) for s in scores]


def _staged(run: TrainedRun) -> bool:
    return len(getattr(run.module.model.spec, "stages", ()) or ()) > 1


def _epochs_at_cap(run: TrainedRun) -> int | None:
    """``trainer.max_epochs`` where the run's training used it up (see :func:`stopped_at_caps`), else None."""
    from hypa.core.trust import inside
    from hypa.training.checkpoints import read_checkpoint

    last = run.info.get("last_checkpoint")
    max_epochs = run.settings.max_epochs
    if not isinstance(last, str) or not isinstance(max_epochs, int) or max_epochs < 1:
        return None
    if identified_only(run):
        return None  # physics alone: identified, no epochs
    path = inside(run.folder, last, f"{run.folder}/run.json's last_checkpoint")
    if not path.is_file():
        return None
    state = read_checkpoint(path)
    epoch = state.get("epoch")
    if not isinstance(epoch, int):
        return None
    callbacks = state.get("callbacks") or {}
    staged = next((v for k, v in callbacks.items() if str(k).startswith("StagedTraining")), None)
    stopping = next((v for k, v in callbacks.items() if str(k).startswith("EarlyStopping")), None)
    if isinstance(stopping, dict) and stopping.get("stopped_epoch") == epoch and epoch > 0:
        return None  # early stopping ended it, in the same epoch as the budget
    if isinstance(staged, dict):
        stage, start = int(staged.get("stage", 0)), int(staged.get("stage_start_epoch", 0))
        capped = epoch + 1 - start >= max_epochs or (stage > 0 and start >= stage * max_epochs)
    else:
        capped = epoch + 1 >= max_epochs
    return max_epochs if capped else None
