"""Benchmark scores: a trained run simulated free-running over each test set, beside published figures.

Every test record is simulated from its start (the first ``past`` + 1 samples start the
model and are not scored, as in the benchmarks' own protocols) to its end; the RMS error and
R² per output are taken over all scored samples of a test set. A model trained with several
seeds is reported as the mean and standard deviation over its seeds: on a knife edge (the
free run of an integrating axis) one seed's figure says little.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hypa import markdown as md
from hypa.data import HypaDataModule
from hypa.metrics import mean_std, regression_metrics
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


@dataclass(frozen=True)
class Summary:
    """A model's scores on one test set and output over its seeds: mean and (sample) std."""

    rms: float
    rms_std: float
    r2: float
    r2_std: float
    samples: int
    seeds: dict[int, tuple[float, float]]  # seed -> (rms, r2)


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


def benchmark_table(scores: Sequence[Score], training_time_s: Mapping[str, float], published: Mapping[str, Mapping],
                    units: Mapping[str, tuple[str, float]], dataset: str) -> str:
    """A Markdown table: per test set and output, each model's RMS and R², the published RMS figures.

    ``units``: output -> (display unit, factor from SI); ``published``: test set -> output ->
    {label: RMS in the output's display unit}; ``training_time_s``: model -> mean seconds. A
    model with several seeds shows mean ± std (and its seeds are named under the table).
    """
    summary = summarize(scores)
    models = list(dict.fromkeys(s.model for s in scores))
    shown = list(dict.fromkeys(k for outputs in published.values() for figures in outputs.values() for k in figures))
    head = ["test set", "output", *[f"{m} RMS" for m in models], *[f"{m} R²" for m in models],
            *[f"published {k}" for k in shown]]
    rows = []
    for test_set, output in dict.fromkeys((s.test_set, s.output) for s in scores):
        unit, factor = units.get(output, ("", 1.0))
        rms = [summary.get((m, test_set, output)) for m in models]
        cells = [test_set, output, *[_rms_cell(s, factor, unit) for s in rms],
                 *[_r2_cell(s) for s in rms]]
        figures = published.get(test_set, {}).get(output, {})
        cells += [f"{figures[k]:g} {unit}" if k in figures else "–" for k in shown]
        rows.append(cells)
    lines = [f"### {dataset}: free-run test error", "", *md.table(head, rows)]
    lines += ["", "training time: " + ", ".join(f"{m} {training_time_s.get(m, float('nan')):.0f} s" for m in models)]
    seeds = {m: sorted(next(s for k, s in summary.items() if k[0] == m).seeds) for m in models}
    if any(len(v) > 1 for v in seeds.values()):
        lines += ["mean ± standard deviation over seeds " + ", ".join(f"{m} {v}" for m, v in seeds.items())
                  + " (training time: mean per seed); each seed in benchmark.json"]
    return "\n".join(lines)


def _r2_cell(s: Summary | None) -> str:
    if s is None:
        return "–"
    if len(s.seeds) == 1:
        return f"{s.r2:.4f}"
    std = _spread(s.r2_std, s.r2)
    return f"{s.r2:.4f} ± " + (f"{std:.4f}" if std >= 5e-5 or std == 0 else f"{std:.0e}")


def _rms_cell(s: Summary | None, factor: float, unit: str) -> str:
    if s is None:
        return "–"
    if len(s.seeds) == 1:
        return f"{s.rms * factor:.3g} {unit}"
    return f"{s.rms * factor:.3g} ± {_spread(s.rms_std, s.rms) * factor:.2g} {unit}"


def _spread(std: float, mean: float) -> float:
    """A standard deviation over seeds, 0 where it is round-off (seeds that gave the same model, e.g.
    identified physics, differ by float summation order only)."""
    return 0.0 if std <= 1e-9 * max(abs(mean), 1e-300) else std


def write_benchmark_json(path: Path, dataset: str, scores: Sequence[Score], training_time_s: Mapping[str, float],
                         published: Mapping[str, Mapping], units: Mapping[str, tuple[str, float]]) -> None:
    """``benchmark.json``: {dataset: {model: {"training_time_s", "test_sets": {set: {output: {rms, r2,
    samples, rms_std, r2_std, seeds: {seed: {rms, r2}}}}}}}, "published"}, RMS in SI units (V, m,
    rad/s, rad), rms and r2 the means over seeds."""
    models: dict[str, dict] = {}
    for (model, test_set, output), s in summarize(scores).items():
        entry = models.setdefault(model, {"training_time_s": training_time_s.get(model), "test_sets": {}})
        entry["test_sets"].setdefault(test_set, {})[output] = {
            **{k: v for k, v in asdict(s).items() if k != "seeds"},
            "seeds": {str(seed): {"rms": rms, "r2": r2} for seed, (rms, r2) in s.seeds.items()}}
    content = json.loads(path.read_text()) if path.is_file() else {}
    content[dataset] = {"models": models, "published": {k: {o: dict(f) for o, f in v.items()} for k, v in published.items()},
                        "display_units": {k: {"unit": u, "factor": f} for k, (u, f) in units.items()}}
    path.write_text(json.dumps(content, indent=2))
