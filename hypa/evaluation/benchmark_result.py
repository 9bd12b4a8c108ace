"""The benchmark's result, :class:`Benchmark`, and its writers: ``benchmark.json`` and ``benchmark.md``.

What it holds is computed by :mod:`hypa.evaluation.benchmark` (free-run scores, mean ± std over
seeds); this module only writes and reads it. ``benchmark.json`` (RMS in SI units)::

    {dataset: {"models": {model: {"training_time_s", "kept_physics_seeds", "capped", "failed", "extends",
     "test_sets": {set: {output: {"rms", "rms_std", "r2", "r2_std", "samples", "seeds": {seed: {"rms", "r2"}}}}}}},
     "published": {set: {output: {label: RMS in display units}}},
     "display_units": {output: {"unit", "factor"}}}}

``capped``: where the model's identification or training stopped at a cap (one line each, e.g.
``identification.max_evaluations``); ``failed``: the one-line reason a model (or one of its seeds)
failed, null where none did; ``extends``: the row of the identified physics this model extends
(``diagnosed``: the nominal model ``hypa diagnose`` extended), null where none. A number that is
not finite is written as null (JSON has none).
Both files are written again after every row the benchmark finishes (:func:`write_report`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from hypa.reporting import markdown as md
from hypa.reporting.numbers import elapsed, percent_change, r_squared


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
        return cls(_number(data["rms"]), _number(data.get("rms_std", 0.0)), _number(data["r2"]),
                   _number(data.get("r2_std", 0.0)), int(data["samples"]),
                   {int(s): (_number(v["rms"]), _number(v["r2"])) for s, v in (data.get("seeds") or {}).items()})


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
    # model -> where its identification or training stopped at a cap, one line each
    capped: dict[str, list[str]] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)  # model -> why it (or a seed of it) failed, one line
    # model -> the row of the identified physics it extends (diagnosed -> the nominal that hypa diagnose extended)
    extends: dict[str, str] = field(default_factory=dict)

    @property
    def models(self) -> list[str]:
        """The models in the order they were benchmarked (those that failed too)."""
        return list(dict.fromkeys([*self.training_time_s, *(k[0] for k in self.rows), *self.failed]))

    def to_dict(self) -> dict:
        """This data set's entry of ``benchmark.json``."""
        models: dict[str, dict] = {m: {"training_time_s": self.training_time_s.get(m),
                                       "kept_physics_seeds": list(self.kept_physics.get(m, [])),
                                       "capped": list(self.capped.get(m, [])), "failed": self.failed.get(m),
                                       "extends": self.extends.get(m), "test_sets": {}} for m in self.models}
        for (model, test_set, output), s in self.rows.items():
            models[model]["test_sets"].setdefault(test_set, {})[output] = s.to_dict()
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
                    if e.get("kept_physics_seeds")},
                   {m: [str(c) for c in e["capped"]] for m, e in models.items() if e.get("capped")},
                   {m: str(e["failed"]) for m, e in models.items() if e.get("failed")},
                   {m: str(e["extends"]) for m, e in models.items() if isinstance(e.get("extends"), str)})

    def to_json(self, path: Path) -> None:
        """Write this data set's entry into ``benchmark.json``, keeping the other data sets' entries."""
        path = Path(path)
        content = json.loads(path.read_text()) if path.is_file() else {}
        content[self.dataset] = self.to_dict()
        _write_atomic(path, json.dumps(md.json_ready(content), indent=2, allow_nan=False))

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
        where there are several, the seeds named under the table) and the published RMS figures; the
        last row each model's training time (mean per seed), "(capped)" where its identification or
        training stopped at a cap (said under the table); a model that failed "failed: <why>"."""
        models, published = self.models, self.published
        shown = list(dict.fromkeys(k for outputs in published.values() for figures in outputs.values()
                                   for k in figures))
        head = ["test set", "output", *[f"{m} RMS" for m in models], *[f"{m} R²" for m in models],
                *[f"published {k}" for k in shown]]
        scored = {k[0] for k in self.rows}
        rows = []
        for test_set, output in dict.fromkeys((k[1], k[2]) for k in self.rows) or [("–", "–")]:
            unit, factor = self.units.get(output, ("", 1.0))
            summaries = [self.rows.get((m, test_set, output)) for m in models]
            cells = [test_set, output, *[_failed_cell(self.failed[m]) if m not in scored and m in self.failed
                                         else _rms_cell(s, factor, unit) for m, s in zip(models, summaries)],
                     *[_r2_cell(s) for s in summaries]]
            figures = published.get(test_set, {}).get(output, {})
            cells += [f"{figures[k]:g} {unit}" if k in figures else "–" for k in shown]
            rows.append(cells)
        rows.append(["training time", "", *[elapsed(self.training_time_s.get(m))
                                            + (" (capped)" if self.capped.get(m) else "") for m in models],
                     *[""] * len(models), *[""] * len(shown)])
        lines = [f"### {self.dataset}: free-run test error", "", *md.table(head, rows)]
        lines += [f"(capped) {m}: " + "; ".join(self.capped[m]) for m in models if self.capped.get(m)]
        # a model one of whose seeds failed: the others' figures are in the table
        lines += [f"{m}: {_one_line(self.failed[m])}" for m in models if m in self.failed and m in scored]
        for m in models:
            if self.kept_physics.get(m):
                kept = ", ".join(map(str, self.kept_physics[m]))
                lines.append(f"{m}: no epoch of its networks beat its identified physics on validation (seed {kept}), "
                             "so its row is that physics")
        lines += self._against_extended()
        seeds = {m: sorted(next(s for k, s in self.rows.items() if k[0] == m).seeds) for m in models if m in scored}
        if any(len(v) > 1 for v in seeds.values()):
            lines += ["mean ± standard deviation over seeds " + ", ".join(f"{m} {v}" for m, v in seeds.items())
                      + " (training time: mean per seed); each seed in benchmark.json"]
        return "\n".join(lines)


    def against_extended(self) -> dict[str, dict[tuple[str, str], tuple[float, float]]]:
        """Model -> (test set, output) -> (its RMS, the RMS of the row it extends) [SI], where both scored."""
        out: dict[str, dict[tuple[str, str], tuple[float, float]]] = {}
        for model, base in self.extends.items():
            for (m, test_set, output), s in self.rows.items():
                other = self.rows.get((base, test_set, output))
                if m == model and other is not None:
                    out.setdefault(model, {})[(test_set, output)] = (s.rms, other.rms)
        return out

    def _against_extended(self) -> list[str]:
        """Under the table: each model against the identified physics it extends, per test set and output
        (the diagnosis's promise: its extension is no worse), "worse" in bold where it is."""
        lines = []
        for model, pairs in self.against_extended().items():
            parts = []
            for (test_set, output), (rms, base) in pairs.items():
                unit, factor = self.units.get(output, ("", 1.0))
                change = percent_change(base, rms)
                parts.append(f"{test_set} {output} {base * factor:.3g} → {rms * factor:.3g} {unit} ({change})"
                             + (" **worse**" if rms > base else ""))
            lines.append(f"{model} against {self.extends[model]}, the identified physics it extends: "
                         + "; ".join(parts))
        return lines


def write_report(result: Benchmark, folder: Path) -> tuple[Path, Path]:
    """Write ``benchmark.md`` and ``benchmark.json`` into ``folder`` (each replaced whole, never left
    half written: the benchmark writes them after every row, and Ctrl-C may come at any time)."""
    folder = Path(folder)
    table, data = folder / "benchmark.md", folder / "benchmark.json"
    _write_atomic(table, result.markdown() + "\n")
    result.to_json(data)
    return table, data


def read_benchmarks(path: Path) -> dict[str, Benchmark]:
    """Every data set's :class:`Benchmark` in a ``benchmark.json``."""
    content = json.loads(Path(path).read_text())
    return {dataset: Benchmark.from_dict(dataset, entry) for dataset, entry in content.items()}


def _r2_cell(s: Summary | None) -> str:
    if s is None:
        return "–"
    if len(s.seeds) == 1:
        return r_squared(s.r2)
    std = _spread(s.r2_std, s.r2)
    return f"{r_squared(s.r2)} ± " + (f"{std:.4f}" if std >= 5e-5 or std == 0 else f"{std:.0e}")


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


def _failed_cell(reason: str) -> str:
    """A failed model's cell: its reason on one line, cut short (the whole reason is in benchmark.json)."""
    return f"failed: {_one_line(reason, 160)}"


def _one_line(text: str, limit: int = 300) -> str:
    """``text`` on one line, at most ``limit`` characters."""
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 1] + "…"


def _number(value: float | None) -> float:
    """A number of ``benchmark.json``: null (written for one that was not finite) reads as NaN."""
    return math.nan if value is None else float(value)


def _write_atomic(path: Path, text: str) -> None:
    """``path`` replaced by ``text`` in one step (written beside it, then renamed over it)."""
    part = path.with_name(f".{path.name}.part")
    part.write_text(text)
    os.replace(part, path)
