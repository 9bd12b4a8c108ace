"""Benchmark scores: a trained run simulated free-running over each test set, beside published figures.

Every test record is simulated from its start (the first ``past`` + 1 samples start the
model and are not scored, as in the benchmarks' own protocols) to its end; the RMS error and
R² per output are taken over all scored samples of a test set. A model trained with several
seeds is reported as the mean and standard deviation over its seeds: on a knife edge (the
free run of an integrating axis) one seed's figure says little.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hypa.data import HypaDataModule
from hypa.evaluation.benchmark_result import Benchmark, Summary
from hypa.evaluation.runs import TrainedRun
from hypa.metrics import mean_std, regression_metrics
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
              kept_physics: Mapping[str, Sequence[int]] | None = None) -> Benchmark:
    """The data set's :class:`~hypa.evaluation.benchmark_result.Benchmark` (written by its
    ``to_json`` and ``markdown``): per model, test set and output the scores' mean ± std over seeds.

    ``units``: output -> (display unit, factor from SI); ``published``: test set -> output ->
    {label: RMS in the output's display unit}; ``training_time_s``: model -> mean seconds per seed;
    ``kept_physics``: model -> the seeds whose hybrid run kept its identified physics (its best checkpoint
    the model before its networks' first epoch).
    """
    rows = summarize(scores)
    models = dict.fromkeys(k[0] for k in rows)
    return Benchmark(dataset, rows, {m: training_time_s.get(m) for m in models},
                     {k: {o: dict(f) for o, f in v.items()} for k, v in published.items()},
                     {k: (u, f) for k, (u, f) in units.items()},
                     {m: sorted(s) for m, s in (kept_physics or {}).items() if s})
