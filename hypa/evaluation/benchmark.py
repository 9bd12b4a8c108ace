"""Benchmark scores: a trained run simulated free-running over each test set, beside published figures.

Every test record is simulated from its start (the first ``past`` + 1 samples start the
model and are not scored, as in the benchmarks' own protocols) to its end; the RMS error and
R² per output are taken over all scored samples of a test set.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hypa.data import HypaDataModule
from hypa.evaluation.metrics import regression_metrics
from hypa.evaluation.runs import TrainedRun, free_run


@dataclass(frozen=True)
class Score:
    """One model on one test set and output: RMS error [SI] and R² of the free run."""

    model: str
    test_set: str
    output: str
    rms: float
    r2: float
    samples: int


def score_run(run: TrainedRun, dm: HypaDataModule, label: str) -> list[Score]:
    """Free-run scores of a trained run on every test set of its data (``dm.test_sets()``)."""
    scores = []
    for test_set, records in dm.test_sets().items():
        predictions = [free_run(run.module.model, dm, record) for record in records]
        for output in dm.output_names:
            predicted = np.concatenate([p.predicted[output][p.first :] for p in predictions])
            measured = np.concatenate([p.measured[output][p.first :] for p in predictions])
            m = regression_metrics(predicted, measured)
            scores.append(Score(label, test_set, output, m["mse"] ** 0.5, m["r2"], int(measured.size)))
    return scores


def benchmark_table(scores: Sequence[Score], training_time_s: Mapping[str, float], published: Mapping[str, Mapping],
                    units: Mapping[str, tuple[str, float]], dataset: str) -> str:
    """A Markdown table: per test set and output, each model's RMS and R², the published RMS figures.

    ``units``: output -> (display unit, factor from SI); ``published``: test set -> output ->
    {label: RMS in the output's display unit}.
    """
    models = list(dict.fromkeys(s.model for s in scores))
    shown = list(dict.fromkeys(k for outputs in published.values() for figures in outputs.values() for k in figures))
    head = ["test set", "output", *[f"{m} RMS" for m in models], *[f"{m} R²" for m in models],
            *[f"published {k}" for k in shown]]
    lines = [f"### {dataset}: free-run test error", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    by_key = {(s.model, s.test_set, s.output): s for s in scores}
    for test_set, output in dict.fromkeys((s.test_set, s.output) for s in scores):
        unit, factor = units.get(output, ("", 1.0))
        rms = [by_key.get((m, test_set, output)) for m in models]
        cells = [test_set, output, *[f"{s.rms * factor:.3g} {unit}" if s else "–" for s in rms],
                 *[f"{s.r2:.4f}" if s else "–" for s in rms]]
        figures = published.get(test_set, {}).get(output, {})
        cells += [f"{figures[k]:g} {unit}" if k in figures else "–" for k in shown]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "training time: " + ", ".join(f"{m} {training_time_s.get(m, float('nan')):.0f} s" for m in models)]
    return "\n".join(lines)


def write_benchmark_json(path: Path, dataset: str, scores: Sequence[Score], training_time_s: Mapping[str, float],
                         published: Mapping[str, Mapping], units: Mapping[str, tuple[str, float]]) -> None:
    """``benchmark.json``: {dataset: {model: {"training_time_s", "test_sets": {set: {output: {rms, r2,
    samples}}}}}, "published"}, RMS in SI units (V, m, rad/s, rad)."""
    models: dict[str, dict] = {}
    for s in scores:
        entry = models.setdefault(s.model, {"training_time_s": training_time_s.get(s.model), "test_sets": {}})
        entry["test_sets"].setdefault(s.test_set, {})[s.output] = {k: v for k, v in asdict(s).items()
                                                                   if k in ("rms", "r2", "samples")}
    content = json.loads(path.read_text()) if path.is_file() else {}
    content[dataset] = {"models": models, "published": {k: {o: dict(f) for o, f in v.items()} for k, v in published.items()},
                        "display_units": {k: {"unit": u, "factor": f} for k, (u, f) in units.items()}}
    path.write_text(json.dumps(content, indent=2))
