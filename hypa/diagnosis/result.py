"""The result of a diagnosis, :class:`Diagnosis`, and its writers: ``diagnosis.json`` and ``diagnosis.md``.

What it holds is computed by :func:`hypa.diagnosis.api.diagnose_system`; this module only
writes and reads it (the fleet summary reads every log's ``diagnosis.json`` back through
:meth:`Diagnosis.from_json`). The JSON keys are documented in docs/diagnosis.md; a report
written by an older hypa (without ``named`` rows, say) reads back with those parts empty.
All values are in SI units; the Markdown report shows them in the units given to it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from hypa.core.errors import UserError
from hypa.core.trust import read_bounded
from hypa.diagnosis.coverage import ChannelCoverage
from hypa.diagnosis.generic import GenericFit
from hypa.diagnosis.scales import Scales, duration
from hypa.diagnosis.structure import OutputStructure
from hypa.reporting import markdown as md
from hypa.reporting.numbers import change_text, r_squared, share_text

WRITTEN = {"diagnosed": "the named causes at their fitted values, the uncertain ones trainable",
           "diagnosed_hybrid": "the same with a correction network on the outputs",
           "diagnosed_learned": ("the subsystems the named causes stand in for learned by networks in the frozen "
                                 "physics; then `hypa explain run=<its run>` says what they learned")}
MIN_GAIN = 0.15  # hypa diagnose's default diagnosis.min_gain


@dataclass
class SystemSummary:
    """The diagnosed system: the nominal model's name and the data's channels by role."""

    model: str = ""
    inputs: list[str] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)
    scheduling: list[str] = field(default_factory=list)


@dataclass
class DataSummary:
    """What the data held: sample time [s], records, the cross-validation (``folds`` 1 and ``blocks``
    0 without), the training evidence and the time scales the search ran at (``scales``:
    :meth:`hypa.diagnosis.scales.Scales.to_dict`)."""

    dt: float
    train_records: int
    val_records: int
    folds: int = 1
    blocks: int = 0
    train_s: float | None = None
    train_windows: int | None = None  # without overlap
    train_stretches: int | None = None
    stretch_s: float | None = None
    scales: dict[str, Any] = field(default_factory=dict)

    def time_scales(self) -> Scales:
        return Scales(**{f.name: self.scales[f.name] for f in fields(Scales)})


@dataclass
class SearchScore:
    """The search's own score, 1 − R² (mean over outputs), before and after the named causes."""

    nominal: float
    extended: float


@dataclass
class ErrorShares:
    """The headline: free-run error on the validation records as a share of the output variance
    (1 − R² of :attr:`Diagnosis.metrics`, mean over outputs), per model, and ``change``:
    extended / nominal − 1."""

    nominal: float
    extended: float
    change: float
    trained: float | None = None

    def to_dict(self) -> dict:
        return {"nominal": self.nominal, "extended": self.extended,
                **({"trained": self.trained} if self.trained is not None else {}), "change": self.change}


@dataclass
class FreeRunMetrics:
    """One output's free run over the validation records: RMS error [SI], MSE [SI²] and R²."""

    rmse: float
    mse: float
    r2: float


@dataclass
class FindingRow:
    """A fitted candidate as reported: a row of ``named``, ``dropped`` and ``rounds``
    (:meth:`hypa.diagnosis.finding.Finding.to_dict`; the fields are documented in docs/diagnosis.md)."""

    cause: str
    target: str = ""
    values: dict[str, float] = field(default_factory=dict)  # [SI] knobs by name
    units: dict[str, str] = field(default_factory=dict)
    score: float | None = None  # 1 − R² with it
    gain: float | None = None  # relative to the model before it
    seconds: float | None = None
    error: str | None = None
    alternatives: list[str] = field(default_factory=list)
    refined: dict[str, float] = field(default_factory=dict)
    steps: list[int] | None = None  # gradient fits: [done, of]
    z: float | None = None
    small: bool = False
    too_short: str = ""
    generic: float | None = None
    text: str = ""  # one line in units (a dropped row: with the reason)
    folds: list[dict[str, float]] = field(default_factory=list)
    screened: bool = False

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FindingRow:
        return _make(cls, data)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def fitted(self) -> str:
        """The text's part after the cause and target: the fitted values in units ("" if none)."""
        return self.text.split(": ", 1)[1] if ": " in self.text else ""

    @property
    def reason(self) -> str:
        """A dropped row's reason (the end of its ``text``)."""
        at = self.text.find("dropped: ")
        return self.text[at:] if at >= 0 else self.fitted


@dataclass
class CandidateRow:
    """A row of ``candidates`` (the named first, then the first round's others): ``score`` the
    share of the error it removes, ``estimate`` its fitted values [SI], ``evidence`` one line."""

    cause: str
    target: str = ""
    score: float | None = None
    estimate: dict[str, Any] = field(default_factory=dict)
    evidence: str = ""
    alternatives: list[str] = field(default_factory=list)


@dataclass
class SignalAgreement:
    """A recovered internal signal against its measurement: correlation, RMS error and measured RMS [SI]."""

    correlation: float
    rmse: float
    measured_rms: float


@dataclass
class NetworkExplanation:
    """What one output of a trained network learned (:func:`hypa.explain.explain_run`): the chosen
    form in words, its validation R² and the report it is in."""

    block: str
    signal: str
    description: str
    form: str = ""
    r2_val: float | None = None
    report: str = ""


@dataclass
class TrainedSummary:
    """The extension trained by ``hypa train`` (``extension.train=true``): its free-run metrics per
    output, its ``gain`` (``all``: relative MSE change per output and ``overall``) and what its
    networks learned."""

    model: str
    run: str = ""
    metrics: dict[str, FreeRunMetrics] = field(default_factory=dict)
    gain: dict[str, dict[str, float]] = field(default_factory=dict)
    explained: list[NetworkExplanation] = field(default_factory=list)

    @property
    def change(self) -> float | None:
        """Its validation error against the nominal model's, relative."""
        return (self.gain.get("all") or {}).get("overall")

    def to_dict(self) -> dict:
        return {"model": self.model, "run": self.run, "metrics": _metrics_dict(self.metrics), "gain": self.gain,
                "explained": [e.__dict__.copy() for e in self.explained]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrainedSummary:
        return cls(str(data["model"]), str(data.get("run", "")), _metrics(data.get("metrics") or {}),
                   dict(data.get("gain") or {}), [_make(NetworkExplanation, e) for e in data.get("explained") or []])


@dataclass
class Extension:
    """The written models: per name its config file and the command that trains it, the recovered
    signals against their measurements, and the trained one (if trained)."""

    config: dict[str, str] = field(default_factory=dict)
    train_command: dict[str, str] = field(default_factory=dict)
    signals: dict[str, SignalAgreement] = field(default_factory=dict)
    trained: TrainedSummary | None = None

    def to_dict(self) -> dict:
        return {"config": dict(self.config), "train_command": dict(self.train_command),
                "signals": {k: s.__dict__.copy() for k, s in self.signals.items()},
                **({"trained": self.trained.to_dict()} if self.trained else {})}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Extension:
        trained = data.get("trained")
        return cls(dict(data.get("config") or {}), dict(data.get("train_command") or {}),
                   {k: _make(SignalAgreement, s) for k, s in (data.get("signals") or {}).items()},
                   TrainedSummary.from_dict(trained) if trained else None)


@dataclass
class Diagnosis:
    """``diagnosis.json``: the named causes, their gain and what remains (docs/diagnosis.md)."""

    causes: list[str]  # named, most important first
    cause: str = "none"  # the first named (the schema of old reports)
    estimate: dict[str, Any] = field(default_factory=dict)  # its fitted values
    system: SystemSummary = field(default_factory=SystemSummary)
    named: list[FindingRow] = field(default_factory=list)
    dropped: list[FindingRow] = field(default_factory=list)
    candidates: list[CandidateRow] = field(default_factory=list)
    rounds: list[list[FindingRow]] = field(default_factory=list)
    score: SearchScore | None = None
    error: ErrorShares | None = None
    metrics: dict[str, dict[str, FreeRunMetrics]] = field(default_factory=dict)  # model -> output -> metrics
    gain: dict[str, dict[str, float]] = field(default_factory=dict)  # "all" -> output (and "overall") -> change
    too_short: list[str] = field(default_factory=list)
    generic: list[GenericFit] = field(default_factory=list)
    standin: str = ""
    coverage: list[ChannelCoverage] = field(default_factory=list)
    not_covered: list[str] = field(default_factory=list)
    unexplained: list[OutputStructure] = field(default_factory=list)
    structure: dict[str, OutputStructure] = field(default_factory=dict)
    extended: Extension = field(default_factory=Extension)
    data: DataSummary | None = None
    seconds: float | None = None
    figures: dict[str, list[str]] = field(default_factory=dict)  # time_series, signals: PNG file names

    @property
    def change(self) -> float | None:
        """The validation error change with the named causes applied (``gain.all.overall``)."""
        return (self.gain.get("all") or {}).get("overall")

    def to_dict(self) -> dict:
        return {
            "cause": self.cause, "estimate": self.estimate, "system": self.system.__dict__.copy(),
            "causes": list(self.causes), "named": _dicts(self.named), "dropped": _dicts(self.dropped),
            "candidates": [c.__dict__.copy() for c in self.candidates], "rounds": [_dicts(r) for r in self.rounds],
            "score": None if self.score is None else self.score.__dict__.copy(),
            "error": None if self.error is None else self.error.to_dict(),
            "metrics": {m: _metrics_dict(o) for m, o in self.metrics.items()}, "gain": self.gain,
            "too_short": list(self.too_short),
            "generic": [{"score": g.score, "gain": g.gain, "numbers": g.numbers} for g in self.generic],
            "standin": self.standin, "coverage": [c.to_dict() for c in self.coverage],
            "not_covered": list(self.not_covered), "unexplained": [s.to_dict() for s in self.unexplained],
            "structure": {o: s.to_dict() for o, s in self.structure.items()}, "extended": self.extended.to_dict(),
            "data": None if self.data is None else self.data.__dict__.copy(), "seconds": self.seconds,
            "figures": self.figures,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Diagnosis:
        causes = [str(c) for c in data["causes"]]  # what makes it a diagnosis.json
        score, error, facts = data.get("score"), data.get("error"), data.get("data")
        return cls(
            causes, str(data.get("cause", causes[0] if causes else "none")), dict(data.get("estimate") or {}),
            _make(SystemSummary, data.get("system") or {}), _rows(data.get("named")), _rows(data.get("dropped")),
            [_make(CandidateRow, c) for c in data.get("candidates") or []],
            [_rows(r) for r in data.get("rounds") or []],
            _make(SearchScore, score) if score else None, _make(ErrorShares, error) if error else None,
            {m: _metrics(o) for m, o in (data.get("metrics") or {}).items()}, dict(data.get("gain") or {}),
            list(data.get("too_short") or []), [_make(GenericFit, g) for g in data.get("generic") or []],
            str(data.get("standin") or ""), [_coverage(c) for c in data.get("coverage") or []],
            list(data.get("not_covered") or []), [_structure(s) for s in data.get("unexplained") or []],
            {o: _structure(s) for o, s in (data.get("structure") or {}).items()},
            Extension.from_dict(data.get("extended") or {}), _make(DataSummary, facts) if facts else None,
            data.get("seconds"), {k: list(v) for k, v in (data.get("figures") or {}).items()})

    def to_json(self, path: Path) -> None:
        """Write ``diagnosis.json``: a number that is not finite (the score of a fit that diverged) as null."""
        Path(path).write_text(json.dumps(md.json_ready(self.to_dict()), indent=2, default=float, allow_nan=False))

    @classmethod
    def from_json(cls, path: Path) -> Diagnosis:
        """A ``diagnosis.json`` read back: bounded in size (:func:`hypa.core.trust.read_bounded`), every value
        checked against the fields' types first, so that a file hypa did not write (a wrong type, a
        missing key, not JSON) is one line naming the file and the value, never a traceback later."""
        path = Path(path)
        try:
            data = json.loads(read_bounded(path, what="diagnosis.json"))
        except (ValueError, RecursionError) as error:  # not JSON, not UTF-8, nested without end
            if isinstance(error, UserError):
                raise
            raise UserError(f"{path}: not a diagnosis.json of hypa diagnose ({type(error).__name__}: "
                            f"{' '.join(str(error).split())[:200]})") from None
        try:
            return cls.from_dict(_conform(data, Diagnosis, ""))
        except _Mismatch as error:
            raise UserError(f"{path}: not a diagnosis.json of hypa diagnose ({error})") from None
        except (KeyError, TypeError, AttributeError, ValueError) as error:  # what the types do not say
            raise UserError(f"{path}: not a diagnosis.json of hypa diagnose ({type(error).__name__}: "
                            f"{' '.join(str(error).split())[:200]})") from None

    def headline(self) -> dict[str, str]:
        """The headline figures as printed, for diagnosis.md and the command's last line alike (one
        place, so the two cannot disagree): ``nominal``, ``extended`` (``trained``) as shares of the
        output variance, and ``change``, extended against nominal."""
        error = self.error
        shares = {"nominal": error.nominal, "extended": error.extended, "trained": error.trained}
        out = {m: share_text(v) for m, v in shares.items() if v is not None}
        out["change"] = change_text(error.change)
        return out

    def markdown(self, units: Mapping[str, tuple[str, float]] | None = None, min_gain: float = MIN_GAIN) -> str:
        """diagnosis.md: the engineer's report. ``units``: channel -> (unit shown, factor from SI)
        (SI where not given); ``min_gain``: the search's floor, as it ran."""
        return _markdown(self, units or {}, min_gain)


class _Mismatch(Exception):
    """A value of diagnosis.json that is not of its field's type: ``where`` and what it should be."""


# The classes whose fields Diagnosis.from_dict reads with ``or``: null there reads as empty, as a missing key does.
_NULL_AS_EMPTY = {"Diagnosis", "Extension", "TrainedSummary"}


def _conform(value: Any, hint: Any, where: str) -> Any:
    """``value`` (parsed JSON) as the type ``hint`` (a field's annotation: a dataclass of this
    module's, ``float``, ``list[...]``, ``X | None``, ...) takes it: the same value, except that null
    where a number must be reads as NaN (:meth:`Diagnosis.to_json` writes a number that is not finite
    as null). Raise :class:`_Mismatch` where it is not of that type."""
    import types
    import typing
    from numbers import Integral, Real

    if hint is Any:
        return value
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, Mapping):
            raise _Mismatch(f"{where or 'the file'} is {_kind(value)}, not an object of {hint.__name__}'s keys")
        hints, conformed = _hints(hint), dict(value)
        for f in fields(hint):
            key = f"{where}.{f.name}" if where else f.name
            if f.name not in value:
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                    raise _Mismatch(f"{key} is missing")
                continue
            item = value[f.name]
            if item is None and hint.__name__ in _NULL_AS_EMPTY:
                continue
            conformed[f.name] = _conform(item, hints[f.name], key)
        return conformed
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        problems = []
        for option in (a for a in args if a is not type(None)):
            try:
                return _conform(value, option, where)
            except _Mismatch as mismatch:  # noqa: PERF203 -- the next option may fit
                problems.append(mismatch)
        raise problems[0]
    if hint is type(None):
        if value is not None:
            raise _Mismatch(f"{where} is {_kind(value)}, not null")
        return None
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise _Mismatch(f"{where} is {_kind(value)}, not a list")
        items = args if origin is tuple and args and args[-1] is not Ellipsis else None
        if items is not None and len(items) != len(value):
            raise _Mismatch(f"{where} has {len(value)} values, not {len(items)}")
        return [_conform(item, items[i] if items is not None else (args[0] if args else Any), f"{where}[{i}]")
                for i, item in enumerate(value)]
    if origin is dict:
        if not isinstance(value, Mapping):
            raise _Mismatch(f"{where} is {_kind(value)}, not an object")
        for key in value:
            if not isinstance(key, str):
                raise _Mismatch(f"{where} has the key {key!r}, not a string")
        return {key: _conform(item, args[1] if args else Any, f"{where}.{key}") for key, item in value.items()}
    expected = {float: (Real, "a number"), int: (Integral, "an integer"), str: (str, "a string"),
                bool: (bool, "true or false")}.get(hint)
    if expected is None:
        raise _Mismatch(f"{where} cannot be checked")  # a field of a type this function does not know: a bug
    if value is None and hint is float:  # a number that was not finite, written as null
        return math.nan
    if not isinstance(value, expected[0]) or (hint is not bool and isinstance(value, bool)):
        raise _Mismatch(f"{where} is {_kind(value)}, not {expected[1]}")
    return value


def _hints(cls: type) -> dict[str, Any]:
    """The resolved annotations of a dataclass (its module's names: ``float | None``, ``list[FindingRow]``)."""
    import typing

    hints = _HINTS.get(cls)
    if hints is None:
        hints = _HINTS[cls] = typing.get_type_hints(cls)
    return hints


_HINTS: dict[type, dict[str, Any]] = {}


def _kind(value: Any) -> str:
    """A value of parsed JSON as a reader names it: ``the string 'abc'``, ``a list``, ``null``."""
    if value is None:
        return "null"
    if isinstance(value, str):
        return f"the string {value[:40]!r}"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (int, float)):
        return f"the number {value:g}"
    return "a list" if isinstance(value, list) else "an object" if isinstance(value, Mapping) else type(value).__name__


def _make(cls: type, data: Mapping[str, Any]) -> Any:
    """``cls`` from the keys of ``data`` it has fields for (a report may carry more, or fewer where
    the fields have defaults; one without a field that has none is a TypeError)."""
    known = {f.name for f in fields(cls)}
    return cls(**{k: v for k, v in data.items() if k in known})


def _rows(data: list[Mapping[str, Any]] | None) -> list[FindingRow]:
    return [FindingRow.from_dict(f) for f in data or []]


def _dicts(rows: list[FindingRow]) -> list[dict]:
    return [f.to_dict() for f in rows]


def _metrics(data: Mapping[str, Mapping[str, float]]) -> dict[str, FreeRunMetrics]:
    return {o: FreeRunMetrics(m["rmse"], m["mse"], m["r2"]) for o, m in data.items()}


def _metrics_dict(metrics: Mapping[str, FreeRunMetrics]) -> dict[str, dict[str, float]]:
    return {o: {"rmse": m.rmse, "mse": m.mse, "r2": m.r2} for o, m in metrics.items()}


def _coverage(data: Mapping[str, Any]) -> ChannelCoverage:
    return ChannelCoverage(data["channel"], data["role"], tuple(data["train"]), tuple(data["val"]), data["covered"],
                           data["amplitude"])


def _structure(data: Mapping[str, Any]) -> OutputStructure:
    return _make(OutputStructure, {**data, "bands_hz": [tuple(b) for b in data["bands_hz"]],
                              "worst_band_hz": tuple(data["worst_band_hz"])})


def _markdown(d: Diagnosis, units: Mapping[str, tuple[str, float]], min_gain: float) -> str:
    def unit(channel: str) -> tuple[str, float]:
        si = d.structure[channel].unit if channel in d.structure else ""
        return units.get(channel, (si, 1.0))

    system, data, outputs = d.system, d.data, d.system.outputs
    lines = [f"# Diagnosis of `{system.model}`", ""]
    lines += [f"Inputs {', '.join(system.inputs)}; outputs {', '.join(outputs)}"
              + (f"; scheduling {', '.join(system.scheduling)}" if system.scheduling else "")
              + f". {data.train_records} training and {data.val_records} validation "
              f"record(s) at {1 / data.dt:.4g} Hz. Free-run error on the validation records, as a share of each "
              "output's variance (1 − R², the table \"Per output\"), averaged over the outputs:", ""]
    figures = d.headline()

    def per_output(model: str) -> str:
        return ", ".join(f"{o} {share_text(1 - d.metrics[model][o].r2)}" for o in outputs)

    lines.append(f"- nominal model: **{figures['nominal']}** ({per_output('nominal')})")
    lines.append(f"- with the named causes: **{figures['extended']}** ({per_output('extended')})")
    if "trained" in figures:
        lines.append(f"- the trained extension: **{figures['trained']}** ({per_output('trained')})")
    lines.append(f"- change with the named causes: **{figures['change']}**")
    crossed = data.folds > 1
    error = "cross-validated error" if crossed else "validation error"
    if d.not_covered:
        lines += ["", "## Validation data", "",
                  ("The figures above are free runs on the validation records, and they do not cover the operating "
                   "range of the training records (1st–99th percentile; amplitude as RMS about the training mean). "
                   "The causes were judged on all records (cross-validation); the figures above show their effect "
                   "on a part of the range only; other validation records are chosen with `data.splits`."
                   if crossed else
                   "Every candidate is judged on the validation records, and they do not cover the operating range "
                   "of the training records (1st–99th percentile; amplitude as RMS about the training mean). A cause "
                   "that matters outside what they cover can look useless here, and a stand-in can look right; "
                   "other validation records are chosen with `data.splits`."), ""]
        lines += [f"- {line}." for line in d.not_covered]
    stretch = duration(data.stretch_s)
    lines += ["", "## Named causes", "",
              (f"The gains below are cross-validated: every record, training and validation, cut into "
               f"{data.blocks} blocks of {stretch}; each candidate fitted on every other block and scored on the "
               f"others (free runs started from the data at each block), then the other way round, the "
               f"{data.folds} halves' errors pooled. Its values are the mean of the {data.folds} fits (each "
               "fit's in `diagnosis.json`, `named[].folds`), so the validation figures above are not held out. "
               if crossed else
               "The gains below are the search's own score: free runs over the validation records restarted from "
               f"the data every {stretch} (on longer records a little different from the figures above). ")
              + f"Time scales from the nominal model and the data: {data.time_scales().describe()}.", ""]
    if not d.named:
        lines.append(f"None: no catalogue cause lowers the {error} by {100 * min_gain:.0f} % or more"
                     + (" among those the data could support (see \"Too little data\")." if d.too_short else "."))
    nominal = previous = d.score.nominal
    for k, f in enumerate(d.named, 1):
        share = (previous - f.score) / nominal if nominal > 0 else 0.0
        # a nominal value identified before the structural causes (listed after them: they re-fitted it)
        identified = f.cause == "parameter_mismatch" and f.score > previous
        lines.append(f"{k}. **{f.cause}** on `{f.target}`: " + (f.fitted or "no value")
                     + (f". Identified before the structural causes: it removes {100 * f.gain:.2g} % of the {error} "
                        "that its nominal value leaves (the others identified)." if identified else
                        f". {error.capitalize()} {_lower(f.gain)} against the model before it; "
                        f"{100 * share:.2g} % of the nominal error.")
                     + (f" Small (below the {100 * min_gain:.0f} % floor), but {f.z:.0f} standard errors from zero."
                        if f.small else "")
                     + (f" A generic linear filter from the inputs in its place: {_lower(f.generic)}."
                        if f.generic is not None else ""))
        if f.alternatives:
            lines.append(f"   The data cannot tell it from: {'; '.join(f.alternatives)}.")
        previous = previous if identified else f.score
    if d.standin:
        lines.append(f"- Not named: {d.standin}.")
    for f in d.dropped:
        lines.append(f"- Named, then dropped: **{f.cause}** on `{f.target}`; {f.reason}.")
    if d.too_short:
        lines += ["", "## Too little data", "",
                  ("What the training records are too short to fit or to judge (a fit needs more training windows "
                   "without overlap than the numbers it fits; an offset's standard error needs more training "
                   "stretches than the offsets fitted with it):"), ""]
        lines += [f"- {line}." for line in d.too_short]
    models = [m for m in ("nominal", "extended", "trained") if m in d.metrics]
    output_rows = []
    for o in outputs:
        shown, factor = unit(o)
        scores = [d.metrics[m][o] for m in models]
        output_rows.append([o, *(f"{r.rmse * factor:.3g} {shown}" for r in scores), *(r_squared(r.r2) for r in scores)])
    lines += ["", "## Per output (validation, free run)", "",
              *md.table(["output", *(f"{m} RMS" for m in models), *(f"{m} R²" for m in models)], output_rows)]
    trained = d.extended.trained
    if trained:
        lines += ["", (f"The trained extension is `{trained.model}` trained by hypa train (run `{trained.run}`): "
                  f"validation error {change_text(trained.change)} against the nominal model.")]
        if trained.explained:
            lines += ["", ("What its networks learned (hypa.explain; fitted on the training records, R² on the "
                      f"validation records; report `{trained.explained[0].report}`):"), ""]
            lines += [f"- `{e.block}`, {e.signal}: {e.description}" for e in trained.explained]
    if d.extended.signals:
        recovered = []
        for channel, a in d.extended.signals.items():
            shown, factor = unit(channel)
            recovered.append([channel, f"{a.correlation:.3f}", f"{a.rmse * factor:.3g} {shown}",
                              f"{a.measured_rms * factor:.3g} {shown}"])
        lines += ["", "## Recovered signals against their measurement", "",
                  ("What a diagnosed block recovers, compared with a channel the data measure but that was "
                  "never trained on:"), "",
                  *md.table(["signal", "correlation", "RMS error", "measured RMS"], recovered)]
    lines += ["", "## What remains", ""]
    for s in d.structure.values():
        if s.unexplained:
            text = "**unexplained structure**: " + "; ".join(s.where)
        elif s.where:
            text = "too little to matter (under 0.2 % of the variance); seen: " + "; ".join(s.where)
        else:
            text = "no structure: what is left looks like noise"
        lines.append(f"- `{s.output}`: {100 * s.share:.3g} % of its variance left; {text}.")
    lines += ["", "## The extended model", ""]
    for name, path in d.extended.config.items():
        lines.append(f"- `{path}` ({WRITTEN.get(name, name)}): train it with `{d.extended.train_command[name]}`")
    candidates = []
    for f in d.rounds[0] if d.rounds else []:
        fitted = f.fitted or (f.error or "–")
        if f.steps and f.steps[0] < f.steps[1]:
            fitted += f" (stopped after {f.steps[0]} of at most {f.steps[1]} steps: gain at least this)"
        if f.too_short and not f.error:
            fitted += " (standard error not judged: too few training stretches)"
        if f.screened:
            fitted += " (first fold only: far behind that fold's best)"
        change = "–" if f.too_short and f.error else _lower(f.gain)
        candidates.append([f.cause, f.target, fitted, change])
    lines += ["", "## Every candidate of the first round", "",
              *md.table(["cause", "on", "fitted", "error change"], candidates)]
    for name in [*d.figures.get("time_series", []), *d.figures.get("signals", [])]:
        lines += ["", f"![{name}]({name})"]
    return "\n".join(lines) + "\n"


def _lower(gain: float | None) -> str:
    """A row's ``gain`` (how much lower its error is than before it, a share) as the change of that
    error (:func:`hypa.reporting.numbers.change_text`: ``-80 %``; a diverged fit's ``did not converge``)."""
    return change_text(None if gain is None else -gain)
