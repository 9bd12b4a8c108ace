"""The benchmark's result, :class:`Benchmark`, and its writers: ``benchmark.json`` and ``benchmark.md``.

What it holds is computed by :mod:`hypa.evaluation.benchmark` (free-run scores, mean ± std over
seeds); this module only writes and reads it. ``benchmark.json`` (RMS in SI units)::

    {dataset: {"models": {model: {"training_time_s", "kept_physics_seeds", "test_sets": {set: {output: {"rms",
     "rms_std", "r2", "r2_std", "samples", "seeds": {seed: {"rms", "r2"}}}}}}},
     "published": {set: {output: {label: RMS in display units}}},
     "display_units": {output: {"unit", "factor"}}}}
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from hypa import markdown as md


@dataclass(frozen=True)
class Summary:
    """A model's scores on one test set and output over its seeds: mean and (sample) std, RMS [SI]."""

    rms: float
    rms_std: float
    r2: float
    r2_std: float
    samples: int
    seeds: dict[int, tuple[float, float]]  # seed -> (rms, r2)

    def to_dict(self) -> dict:
        return {"rms": self.rms, "rms_std": self.rms_std, "r2": self.r2, "r2_std": self.r2_std,
                "samples": self.samples,
                "seeds": {str(s): {"rms": rms, "r2": r2} for s, (rms, r2) in self.seeds.items()}}

    @classmethod
    def from_dict(cls, data: dict) -> Summary:
        return cls(float(data["rms"]), float(data.get("rms_std", 0.0)), float(data["r2"]),
                   float(data.get("r2_std", 0.0)), int(data["samples"]),
                   {int(s): (float(v["rms"]), float(v["r2"])) for s, v in (data.get("seeds") or {}).items()})


Key = tuple[str, str, str]  # (model, test set, output)


@dataclass
class Benchmark:
    """One data set's benchmark: per model, test set and output its :class:`Summary` over seeds,
    the models' training times (mean per seed [s]), the published figures beside them and the
    outputs' display units."""

    dataset: str
    rows: dict[Key, Summary]  # in the order the table shows them
    training_time_s: dict[str, float | None] = field(default_factory=dict)  # model -> mean seconds per seed
    published: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)  # set -> output -> label -> RMS
    units: dict[str, tuple[str, float]] = field(default_factory=dict)  # output -> (display unit, factor from SI)
    # model -> the seeds whose run kept its identified physics (no epoch of its networks beat it on validation)
    kept_physics: dict[str, list[int]] = field(default_factory=dict)

    @property
    def models(self) -> list[str]:
        return list(dict.fromkeys(k[0] for k in self.rows))

    def to_dict(self) -> dict:
        """This data set's entry of ``benchmark.json``."""
        models: dict[str, dict] = {}
        for (model, test_set, output), s in self.rows.items():
            entry = models.setdefault(model, {"training_time_s": self.training_time_s.get(model),
                                              "kept_physics_seeds": list(self.kept_physics.get(model, [])),
                                              "test_sets": {}})
            entry["test_sets"].setdefault(test_set, {})[output] = s.to_dict()
        return {"models": models,
                "published": {k: {o: dict(f) for o, f in v.items()} for k, v in self.published.items()},
                "display_units": {k: {"unit": u, "factor": f} for k, (u, f) in self.units.items()}}

    @classmethod
    def from_dict(cls, dataset: str, data: dict) -> Benchmark:
        models = data.get("models") or {}
        rows = {(model, test_set, output): Summary.from_dict(s) for model, entry in models.items()
                for test_set, outputs in (entry.get("test_sets") or {}).items() for output, s in outputs.items()}
        return cls(dataset, rows, {m: e.get("training_time_s") for m, e in models.items()},
                   {k: {o: dict(f) for o, f in v.items()} for k, v in (data.get("published") or {}).items()},
                   {k: (str(u["unit"]), float(u["factor"])) for k, u in (data.get("display_units") or {}).items()},
                   {m: [int(s) for s in e["kept_physics_seeds"]] for m, e in models.items()
                    if e.get("kept_physics_seeds")})

    def to_json(self, path: Path) -> None:
        """Write this data set's entry into ``benchmark.json``, keeping the other data sets' entries."""
        path = Path(path)
        content = json.loads(path.read_text()) if path.is_file() else {}
        content[self.dataset] = self.to_dict()
        path.write_text(json.dumps(content, indent=2))

    @classmethod
    def from_json(cls, path: Path, dataset: str | None = None) -> Benchmark:
        """One data set's benchmark from ``benchmark.json`` (``dataset`` None: the file's only one)."""
        content = read_benchmarks(path)
        if dataset is None:
            if len(content) != 1:
                raise ValueError(f"{path} holds {len(content)} data sets ({', '.join(content)}): name one")
            return next(iter(content.values()))
        return content[dataset]

    def markdown(self) -> str:
        """``benchmark.md``: per test set and output, each model's RMS and R² (mean ± std over seeds
        where there are several, the seeds named under the table) and the published RMS figures."""
        models, published = self.models, self.published
        shown = list(dict.fromkeys(k for outputs in published.values() for figures in outputs.values()
                                   for k in figures))
        head = ["test set", "output", *[f"{m} RMS" for m in models], *[f"{m} R²" for m in models],
                *[f"published {k}" for k in shown]]
        rows = []
        for test_set, output in dict.fromkeys((k[1], k[2]) for k in self.rows):
            unit, factor = self.units.get(output, ("", 1.0))
            summaries = [self.rows.get((m, test_set, output)) for m in models]
            cells = [test_set, output, *[_rms_cell(s, factor, unit) for s in summaries],
                     *[_r2_cell(s) for s in summaries]]
            figures = published.get(test_set, {}).get(output, {})
            cells += [f"{figures[k]:g} {unit}" if k in figures else "–" for k in shown]
            rows.append(cells)
        lines = [f"### {self.dataset}: free-run test error", "", *md.table(head, rows)]
        times = {m: self.training_time_s.get(m) for m in models}
        lines += ["", "training time: " + ", ".join(f"{m} {math.nan if t is None else t:.0f} s"
                                                    for m, t in times.items())]
        for m in models:
            if self.kept_physics.get(m):
                kept = ", ".join(map(str, self.kept_physics[m]))
                lines.append(f"{m}: no epoch of its networks beat its identified physics on validation (seed {kept}), "
                             "so its row is that physics")
        seeds = {m: sorted(next(s for k, s in self.rows.items() if k[0] == m).seeds) for m in models}
        if any(len(v) > 1 for v in seeds.values()):
            lines += ["mean ± standard deviation over seeds " + ", ".join(f"{m} {v}" for m, v in seeds.items())
                      + " (training time: mean per seed); each seed in benchmark.json"]
        return "\n".join(lines)


def read_benchmarks(path: Path) -> dict[str, Benchmark]:
    """Every data set's :class:`Benchmark` in a ``benchmark.json``."""
    content = json.loads(Path(path).read_text())
    return {dataset: Benchmark.from_dict(dataset, entry) for dataset, entry in content.items()}


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
