"""The result of evaluating a run, :class:`Evaluation`, and its writers: ``metrics.json``,
``metrics.csv`` and ``summary.md``.

What it holds is computed by :func:`hypa.evaluation.api.evaluate_run`; this module only
writes and reads it. ``metrics.json`` (SI units)::

    {"model", "checkpoint",
     "splits": {split: {"windowed": {segment: {output: {"mae", "mse", "mape", "r2"}}},  # and "overall"
                        "free_run": {...}, "signals": {name: {"corr", "rmse"}}}},       # signals if any
     "units": {channel: SI unit}}
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hypa.evaluation.transfer import TransferEstimate
from hypa.reporting import markdown as md
from hypa.reporting.numbers import r_squared

OVERALL = "overall"  # the mean over the outputs, beside them


@dataclass(frozen=True)
class OutputMetrics:
    """One output's (or ``overall``'s: the mean over the outputs) metrics: MAE [unit], MSE [unit²],
    floored MAPE [%] and R² (:func:`hypa.core.metrics.regression_metrics`)."""

    mae: float
    mse: float
    mape: float
    r2: float

    @property
    def rmse(self) -> float:
        return self.mse ** 0.5

    def to_dict(self) -> dict[str, float]:
        return {"mae": self.mae, "mse": self.mse, "mape": self.mape, "r2": self.r2}

    @classmethod
    def from_dict(cls, data: dict) -> OutputMetrics:
        return cls(_number(data["mae"]), _number(data["mse"]), _number(data["mape"]), _number(data["r2"]))


@dataclass(frozen=True)
class SignalMetrics:
    """An internal model signal against its measurement (free run): correlation and RMS error [SI]."""

    corr: float
    rmse: float


Segments = dict[str, dict[str, OutputMetrics]]  # segment -> output (and "overall") -> metrics


def segments(data: dict[str, dict[str, dict[str, float]]]) -> Segments:
    """``{segment: {output: {metric: value}}}`` (e.g. of :func:`hypa.core.metrics.state_metrics`) typed."""
    return {s: {o: OutputMetrics.from_dict(m) for o, m in outputs.items()} for s, outputs in data.items()}


@dataclass
class SplitMetrics:
    """One split's (or named test set's) metrics: windowed (N steps from each window start, as in
    training) and free-running over whole records, each per segment (``all``, the named segments
    of the data set's ``dataset.json``, ``maneuvers``), and the compared internal signals."""

    windowed: Segments = field(default_factory=dict)
    free_run: Segments = field(default_factory=dict)
    signals: dict[str, SignalMetrics] = field(default_factory=dict)

    def mode(self, name: str) -> Segments:
        """``windowed`` or ``free_run`` by name."""
        if name not in ("windowed", "free_run"):
            raise KeyError(name)
        return self.windowed if name == "windowed" else self.free_run

    def to_dict(self) -> dict:
        out: dict = {mode: {s: {o: m.to_dict() for o, m in outputs.items()} for s, outputs in self.mode(mode).items()}
                     for mode in ("windowed", "free_run")}
        if self.signals:
            out["signals"] = {n: {"corr": s.corr, "rmse": s.rmse} for n, s in self.signals.items()}
        return out

    @classmethod
    def from_dict(cls, data: dict) -> SplitMetrics:
        return cls(segments(data.get("windowed") or {}), segments(data.get("free_run") or {}),
                   {n: SignalMetrics(_number(s["corr"]), _number(s["rmse"]))
                    for n, s in (data.get("signals") or {}).items()})


@dataclass
class RunMetrics:
    """``metrics.json``: a run's metrics per split, segment and output, in SI ``units``."""

    model: str  # the run's label
    checkpoint: str
    splits: dict[str, SplitMetrics] = field(default_factory=dict)  # val, test or test/<name>
    units: dict[str, str] = field(default_factory=dict)  # channel -> SI unit

    def to_dict(self) -> dict:
        return {"model": self.model, "checkpoint": self.checkpoint,
                "splits": {k: s.to_dict() for k, s in self.splits.items()}, "units": dict(self.units)}

    @classmethod
    def from_dict(cls, data: dict) -> RunMetrics:
        return cls(str(data["model"]), str(data["checkpoint"]),
                   {k: SplitMetrics.from_dict(s) for k, s in (data.get("splits") or {}).items()},
                   {k: str(u) for k, u in (data.get("units") or {}).items()})

    def to_json(self, path: Path) -> None:
        """Write ``metrics.json``: a figure that is not finite (a free run that diverged) as null."""
        Path(path).write_text(json.dumps(md.json_ready(self.to_dict()), indent=2, allow_nan=False))

    @classmethod
    def from_json(cls, path: Path) -> RunMetrics:
        return cls.from_dict(json.loads(Path(path).read_text()))

    def rows(self) -> Iterator[tuple[str, str, str, str, str, float]]:
        """(split, mode, segment, channel, metric, value [SI]) of every figure; a signal's under
        ``free_run``, segment ``all``."""
        for split, s in self.splits.items():
            for mode in ("windowed", "free_run"):
                for segment, outputs in s.mode(mode).items():
                    for channel, m in outputs.items():
                        for key, value in m.to_dict().items():
                            yield split, mode, segment, channel, key, value
            for name, signal in s.signals.items():
                for key, value in (("corr", signal.corr), ("rmse", signal.rmse)):
                    yield split, "free_run", "all", name, key, value

    def write_csv(self, path: Path) -> None:
        """``metrics.csv``: one row per figure (:meth:`rows`)."""
        with Path(path).open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["model", "split", "mode", "segment", "channel", "metric", "value (SI)"])
            for row in self.rows():
                writer.writerow([self.model, *row])

    def markdown(self, figures: Sequence[str] = (), units: dict[str, str] | None = None,
                 scale: dict[str, float] | None = None) -> str:
        """``summary.md``: a short report in the channels' display ``units`` (``scale``: factor from
        SI; SI where not given), then the ``figures`` (file names)."""
        units, scale = units or {}, scale or {}
        lines = [f"# Evaluation of {self.model}", "", f"checkpoint: `{self.checkpoint}`", "",
                 "MAPE is floored: |error| / max(|y|, 10 % of the channel's RMS), so zero crossings do not explode it.",
                 "`overall` is the mean over the outputs of MAPE and R² (MAE and MSE mix units there: SI).", ""]
        for split, s in self.splits.items():
            rows = []
            for mode in ("windowed", "free_run"):
                for segment, outputs in s.mode(mode).items():
                    for channel, m in outputs.items():
                        k, unit = scale.get(channel, 1.0), units.get(channel, "SI")
                        rows.append([mode, segment, channel, f"{m.mae * k:.3g} {unit}",
                                     f"{np.sqrt(m.mse) * k:.3g} {unit}", f"{m.mape:.3g}", r_squared(m.r2)])
            lines += [f"## {split}", "",
                      *md.table(["mode", "segment", "output", "MAE", "RMSE", "MAPE [%]", "R²"], rows)]
            for name, r in s.signals.items():
                k, unit = scale.get(name, 1.0), units.get(name, "SI")
                lines += ["", (f"Model vs measured {name} (free run; never trained on): correlation {r.corr:.3f}, "
                          f"RMSE {r.rmse * k:.3g} {unit}")]
            lines.append("")
        lines += [f"![{f}]({f})" for f in figures]
        return "\n".join(lines) + "\n"


@dataclass
class Evaluation:
    """What ``evaluate_run`` found: the metrics (``metrics.json``), and the curves to overlay across
    models (not written to JSON: :meth:`from_json` reads the metrics alone)."""

    metrics: RunMetrics
    transfer: dict[str, TransferEstimate] = field(default_factory=dict)
    # "measured" and "model" of the first input -> output pair (val)
    signals: dict[str, tuple[np.ndarray, np.ndarray | None, np.ndarray]] = field(default_factory=dict)
    # learned signal -> (time, measured, model) [SI], first validation record
    model_blocks: tuple = ()  # the model's BlockSpecs (which signals a network learns)
    display_units: dict[str, str] = field(default_factory=dict)  # channel -> unit shown
    display_factors: dict[str, float] = field(default_factory=dict)  # channel -> SI to shown
    # one line per output whose free run sits at a level the data never reach (hypa.models.rollout.free_run_levels)
    warnings: list[str] = field(default_factory=list)

    def to_json(self, path: Path) -> None:
        """``metrics.json``."""
        self.metrics.to_json(path)

    @classmethod
    def from_json(cls, path: Path) -> Evaluation:
        """The metrics of a ``metrics.json`` (no curves, SI units shown)."""
        return cls(RunMetrics.from_json(path))

    def markdown(self, figures: Sequence[str] = ()) -> str:
        """``summary.md`` in the display units (the :attr:`warnings` first)."""
        text = self.metrics.markdown(figures, self.display_units, self.display_factors)
        if not self.warnings:
            return text
        head, _, rest = text.partition("\n")
        return "\n".join([head, "", *(f"> **Warning:** {w}" for w in self.warnings), rest])


def _number(value: float | None) -> float:
    """A figure of ``metrics.json``: null (written for one that was not finite) reads as NaN."""
    return math.nan if value is None else float(value)
