"""A fleet of logs: diagnose each log as one job of a Hydra multirun, then one summary table.

    hypa diagnose -m dataset=files data.dir=logs/a,logs/b,logs/c
    hypa fleet run 'logs/*/' [hypa diagnose overrides]   # a glob instead of a list
    hypa fleet summary outputs/diagnose/fleet_...         # (re)build the summary

Every job writes its ``diagnosis.json`` (or, if it failed, ``error.json`` with its one-line error:
:func:`hypa.commands.fleet.record_failures`) into its job folder; after the last job,
:class:`hypa.commands.fleet.FleetSummary` (a Hydra
callback registered in conf/diagnose.yaml, so it runs with any launcher) reads them all and writes
``fleet.md`` and ``fleet.json`` into the sweep folder: per log the named causes, their estimates
in the units an engineer reads and the validation error change; across logs how often each cause
is named and the spread of each estimate, where a parameter that drifts from log to log (tire
wear, load) shows up. Works for any system: the estimates and their units come from the named
causes' rows of ``diagnosis.json``. Like ``make -k``, a failed log does not stop the others, and
the exit status is 1 if any failed.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hypa.core.errors import UserError, one_line
from hypa.core.metrics import mean_std
from hypa.core.trust import read_bounded, read_yaml
from hypa.core.units import readable
from hypa.diagnosis.result import Diagnosis, FindingRow
from hypa.reporting import markdown as md
from hypa.reporting.numbers import change_text, plain

DIAGNOSIS_FILE = "diagnosis.json"
ERROR_FILE = "error.json"
JOB_NAME = "diagnose"  # hydra.job.name of hypa diagnose


@dataclass(frozen=True)
class Estimate:
    """One number of a named cause's estimate, in the unit an engineer reads."""

    value: float  # in ``unit``
    unit: str


@dataclass(frozen=True)
class LogDiagnosis:
    """One job of the sweep: its log, the named causes and estimates, or why it failed."""

    folder: Path  # the job folder
    overrides: tuple[str, ...]  # the job's command-line overrides
    error: str | None = None  # one line; None: diagnosed
    causes: tuple[str, ...] = ()  # named, most important first ([] = none)
    estimates: dict[str, Estimate] = field(default_factory=dict)  # "cause: what" -> estimate
    mse_change: dict[str, float | None] = field(default_factory=dict)  # all / trained: (after-before)/before
    label: str = ""  # what tells this log from the others (its data.dir)

    @property
    def failed(self) -> bool:
        return self.error is not None


@dataclass(frozen=True)
class Spread:
    """One estimate across the logs that name its cause."""

    cause: str
    unit: str
    values: tuple[float | None, ...]  # per log, in the logs' order (None: not named there)

    @property
    def present(self) -> np.ndarray:
        return np.array([v for v in self.values if v is not None], dtype=float)

    def stats(self) -> dict[str, float | int | None]:
        """``hypa.core.metrics.mean_std`` over the logs that name the cause; ``std`` None for one log."""
        s = mean_std(self.present)
        return {"logs": s.count, "mean": s.mean, "std": s.std if s.count > 1 else None, "min": s.min, "max": s.max}


@dataclass(frozen=True)
class Fleet:
    """Every job of a sweep folder, in the jobs' order, and what the summary computes from them."""

    sweep_dir: Path
    logs: tuple[LogDiagnosis, ...]

    @property
    def diagnosed(self) -> list[LogDiagnosis]:
        return [log for log in self.logs if not log.failed]

    def cause_counts(self) -> dict[str, int]:
        """In how many diagnosed logs each cause is named (``none``: nothing named), most frequent first."""
        counts: dict[str, int] = {}
        for log in self.diagnosed:
            for cause in dict.fromkeys(log.causes or ("none",)):
                counts[cause] = counts.get(cause, 0) + 1
        return dict(sorted(counts.items(), key=lambda item: (-item[1], item[0])))

    def spreads(self) -> dict[str, Spread]:
        """Every estimate named in some log, in the order of the causes' counts."""
        order = list(self.cause_counts())
        keys = sorted({(k, e.unit) for log in self.logs for k, e in log.estimates.items()},
                      key=lambda ku: (order.index(_cause(ku[0])), ku[0]))
        return {k: Spread(_cause(k), unit, tuple(log.estimates[k].value if k in log.estimates else None
                                                 for log in self.logs)) for k, unit in keys}

    def to_dict(self) -> dict:
        diagnosed = len(self.diagnosed)
        return {
            "sweep_dir": str(self.sweep_dir), "logs": len(self.logs), "diagnosed": diagnosed,
            "failed": len(self.logs) - diagnosed,
            "jobs": [{"folder": _relative(log.folder, self.sweep_dir), "log": log.label,
                      "overrides": list(log.overrides), "status": "failed" if log.failed else "diagnosed",
                      "error": log.error, "causes": list(log.causes),
                      "estimates": {k: {"value": e.value, "unit": e.unit} for k, e in log.estimates.items()},
                      "mse_change": log.mse_change} for log in self.logs],
            "causes": {c: {"logs": n, "share": n / diagnosed} for c, n in self.cause_counts().items()},
            "estimates": {k: {"cause": s.cause, "unit": s.unit, **s.stats(), "values": list(s.values)}
                          for k, s in self.spreads().items()},
        }


def _cause(key: str) -> str:
    return key.split(":", 1)[0]


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def estimates(named: FindingRow) -> dict[str, Estimate]:
    """A named cause's fitted values (a ``named`` row of diagnosis.json, SI) for the summary,
    keyed ``"cause: what"``: a value that is its target by the target (``parameter_mismatch: cr``,
    ``output_offset: position``), the knobs of an inserted block by their own name
    (``unmodeled_input: gain``, ``unmodeled_input: tau`` from ``.../tau_s``); in the units an
    engineer reads (:func:`hypa.core.units.readable`: times in ms, angles in deg)."""
    cause, target, units = named.cause, named.target, named.units or {}
    out = {}
    for knob, value in (named.values or {}).items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            continue
        unit, name = units.get(knob) or "-", knob.rsplit("/", 1)[-1]
        name = target if knob == target else name.removesuffix("_s") if unit == "s" else name
        shown, factor = readable(unit)
        out[f"{cause}: {name}"] = Estimate(float(value) * factor, shown)
    return out


def read_log(folder: Path) -> LogDiagnosis:
    """One job folder: its diagnosis.json, else its error.json, else a job that did not finish.
    A report without ``named`` rows (written before the one-engine diagnosis) gives its causes
    but no estimates. A file of the folder that cannot be read (too large, not what hypa writes, a
    ``!!python`` tag in its YAML) is that job's error: the folder is data, read as such
    (:mod:`hypa.core.trust`), and the other jobs are summarized."""
    try:
        job_name(folder / ".hydra" / "hydra.yaml")
        overrides = read_overrides(folder / ".hydra" / "overrides.yaml")
    except UserError as error:
        return LogDiagnosis(folder, (), error=one_line(error))
    if (folder / DIAGNOSIS_FILE).is_file():
        try:
            result = Diagnosis.from_json(folder / DIAGNOSIS_FILE)
            values: dict[str, Estimate] = {}
            for row in result.named:
                found = estimates(row)
                if values.keys() & found.keys():  # the same cause on two targets: told apart by the target
                    found = {f"{row.cause} on {row.target}: {k.split(': ', 1)[1]}": e for k, e in found.items()}
                values.update(found)
            trained = result.extended.trained
            change = {"all": result.change, "trained": trained.change if trained else None}
            causes = tuple(result.causes)
        except UserError as error:  # Diagnosis.from_json: a file that is not a diagnosis.json, in one line
            return LogDiagnosis(folder, overrides, error=one_line(error))
        except (ValueError, KeyError, TypeError, AttributeError) as error:
            return LogDiagnosis(folder, overrides, error=f"{folder / DIAGNOSIS_FILE} cannot be read "
                                                         f"({type(error).__name__}: {error})")
        return LogDiagnosis(folder, overrides, causes=causes, estimates=values, mse_change=change)
    if (folder / ERROR_FILE).is_file():
        return LogDiagnosis(folder, overrides, error=read_error(folder / ERROR_FILE))
    return LogDiagnosis(folder, overrides, error=f"no {DIAGNOSIS_FILE}: the job did not finish "
                                                 f"(see {folder / (JOB_NAME + '.log')})")


def read_error(path: Path) -> str:
    """The one-line error that :func:`hypa.commands.fleet.record_failures` wrote, or why the file is not one."""
    try:
        error = json.loads(read_bounded(path, what=ERROR_FILE))
    except UserError as refused:
        return one_line(refused)
    except (ValueError, RecursionError) as bad:  # not JSON, not UTF-8, nested without end
        return f"{path}: not an {ERROR_FILE} of hypa diagnose ({type(bad).__name__}); the job failed"
    if not isinstance(error, dict) or not isinstance(error.get("error"), str):
        return f"{path}: not an {ERROR_FILE} of hypa diagnose (no one-line error in it); the job failed"
    return " ".join(error["error"].split())[:2000]


def read_overrides(path: Path) -> tuple[str, ...]:
    """A job's command-line overrides (``.hydra/overrides.yaml``, a list of strings; none without the
    file), read as data (:func:`hypa.core.trust.read_yaml`); anything else is one line."""
    if not path.is_file():
        return ()
    overrides = read_yaml(path, "Hydra overrides file")
    if overrides is None:
        return ()
    if not isinstance(overrides, list) or not all(isinstance(o, (str, int, float, bool)) for o in overrides):
        raise UserError(f"{path}: not a Hydra overrides file (a list of key=value strings)")
    return tuple(str(o) for o in overrides)


def job_name(path: Path) -> str | None:
    """``hydra.job.name`` of a job folder's ``.hydra/hydra.yaml`` (``None`` without one), read as data
    (:func:`hypa.core.trust.read_yaml`); a file that cannot be read is one line."""
    if not path.is_file():
        return None
    config = read_yaml(path, "Hydra configuration file")
    name = _at(config, "hydra", "job", "name")
    return name if isinstance(name, str) else None


def _at(node: Any, *keys: str) -> Any:
    for key in keys:
        if not isinstance(node, dict):
            return None
        node = node.get(key)
    return node


def find_jobs(sweep_dir: Path) -> list[Path]:
    """The ``hypa diagnose`` job folders under ``sweep_dir`` (by their ``.hydra/hydra.yaml``; a
    trained extension's ``hypa train`` run inside a job is not one), in natural order (2 < 10).
    A folder whose ``hydra.yaml`` cannot be read is a job too: its summary row says why."""
    folders = []
    for path in Path(sweep_dir).rglob("hydra.yaml"):
        if path.parent.name != ".hydra":
            continue
        try:
            if job_name(path) != JOB_NAME:
                continue
        except UserError:  # a damaged or hostile file: reported in the job's row (read_log)
            pass
        folders.append(path.parent.parent)
    return sorted(folders, key=lambda p: [int(t) if t.isdigit() else t
                                          for t in re.split(r"(\d+)", _relative(p, Path(sweep_dir)))])


def labels(overrides: Sequence[Sequence[str]]) -> list[str]:
    """What tells each job from the others: its overrides that not all jobs share, unquoted
    (``data.dir=`` shown as the bare folder); a lone job is named by all its overrides."""
    common = set.intersection(*(set(o) for o in overrides)) if len(overrides) > 1 else set()
    return [" ".join(_plain(o) for o in own if o not in common) or "(no overrides)" for own in overrides]


def _plain(override: str) -> str:
    """``data.dir='/logs/run 3'`` -> ``/logs/run 3``; ``key='a b'`` -> ``key=a b``; others as typed."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        parsed = OverridesParser.create().parse_override(override)
    except HydraException:  # Hydra wrote it, so this is a hand-edited file: shown as typed
        return override
    value = parsed.value()
    if parsed.is_delete() or not isinstance(value, str):
        return override.removeprefix("data.dir=")
    return value if parsed.key_or_group == "data.dir" else f"{parsed.key_or_group}={value}"


def collect(sweep_dir: Path) -> Fleet:
    """Every job of a sweep folder, diagnosed or failed."""
    sweep_dir = Path(sweep_dir)
    folders = find_jobs(sweep_dir)
    if not folders:
        raise UserError(f"{sweep_dir} holds no hypa diagnose jobs (no .hydra/hydra.yaml of one); give the sweep "
                        "folder of a `hypa diagnose -m ...` run")
    logs = [read_log(f) for f in folders]
    names = labels([log.overrides for log in logs])
    return Fleet(sweep_dir, tuple(replace(log, label=name) for log, name in zip(logs, names)))


def percent(change: float | None) -> str:
    """A log's MSE change (:func:`hypa.reporting.numbers.change_text`), empty where it has none."""
    return "" if change is None else change_text(change)


def _spread_row(key: str, spread: Spread) -> list[str | int]:
    s = spread.stats()
    relative = "" if s["std"] is None or s["mean"] == 0 else f"{100 * s['std'] / abs(s['mean']):.1f} %"
    return [key, spread.unit, s["logs"], *(plain(s[k]) for k in ("mean", "std", "min", "max")), relative]


def markdown(fleet: Fleet) -> str:
    """fleet.md: the per-log table (one column per estimate, so a drift reads down a column) and
    the across-logs tables (how often each cause is named, the spread of each estimate)."""
    spreads, counts, diagnosed = fleet.spreads(), fleet.cause_counts(), len(fleet.diagnosed)
    trained = any(log.mse_change.get("trained") is not None for log in fleet.logs)
    lines = [f"# Fleet diagnosis: {len(fleet.logs)} logs", "",
             f"Sweep folder `{fleet.sweep_dir}`: {diagnosed} diagnosed, {len(fleet.logs) - diagnosed} failed. "
             "Each log's report is `<job>/diagnosis.md`. MSE change: validation error of the nominal model with "
             "the log's named causes applied (each output's MSE relative to its variance, averaged over the "
             "outputs), (after - before) / before" + ("; trained: the same for the trained extension." if trained
                                                      else "."),
             "", "## Per log", ""]
    head = ["job", "log", "named causes", "MSE change", *(["trained"] if trained else []),
            *(f"{k} [{s.unit}]" for k, s in spreads.items())]
    rows = []
    for log in fleet.logs:
        cells = [_relative(log.folder, fleet.sweep_dir), log.label]  # md.cell escapes a | in them
        if log.failed:
            cells += [f"**failed**: {log.error or ''}", "", *([""] if trained else []), *[""] * len(spreads)]
        else:
            cells += [", ".join(log.causes) or "none", percent(log.mse_change.get("all")),
                      *([percent(log.mse_change.get("trained"))] if trained else []),
                      *(plain(log.estimates[k].value) if k in log.estimates else "" for k in spreads)]
        rows.append(cells)
    lines += [*md.table(head, rows), "", "## Across logs", ""]
    if not diagnosed:
        return "\n".join([*lines, "No log was diagnosed.", ""])
    lines += md.table(["cause", "named in", "share"],
                      [[c, f"{n} / {diagnosed}", f"{100 * n / diagnosed:.0f} %"] for c, n in counts.items()])
    if spreads:
        lines += ["", ("Spread of each estimate over the logs that name its cause (std: sample standard deviation; "
                       "a large relative spread is a parameter that changes from log to log):"), "",
                  *md.table(["estimate", "unit", "logs", "mean", "std", "min", "max", "std / |mean|"],
                            [_spread_row(key, spread) for key, spread in spreads.items()])]
    changes = [log.mse_change["all"] for log in fleet.diagnosed if log.mse_change.get("all") is not None]
    if changes:
        change = mean_std(changes)
        lines += ["", (f"Validation MSE change with the named causes applied: mean {percent(change.mean)}, "
                       f"from {percent(change.min)} to {percent(change.max)}.")]
    return "\n".join(lines) + "\n"


def write_summary(sweep_dir: Path) -> Fleet:
    """Collect the sweep folder's jobs and write ``fleet.md`` and ``fleet.json`` into it."""
    fleet = collect(sweep_dir)
    (fleet.sweep_dir / "fleet.json").write_text(json.dumps(md.json_ready(fleet.to_dict()), indent=2, allow_nan=False))
    (fleet.sweep_dir / "fleet.md").write_text(markdown(fleet))
    return fleet


def report(fleet: Fleet) -> str:
    """The console's summary: the across-logs part of fleet.md and where the files are."""
    text = markdown(fleet)
    across = text[text.index("## Across logs"):]
    failed = len(fleet.logs) - len(fleet.diagnosed)
    failures = "" if not failed else f" ({failed} failed: see the per-log table)"
    return (f"{across}\nfleet of {len(fleet.logs)} logs{failures}: "
            f"{fleet.sweep_dir / 'fleet.md'}, {fleet.sweep_dir / 'fleet.json'}")


if __name__ == "__main__":  # `python -m hypa.diagnosis.fleet`, the spelling before `hypa fleet` (one release)
    import runpy

    print("python -m hypa.diagnosis.fleet is deprecated and goes in the next release: use `hypa fleet`",
          file=sys.stderr)
    sys.argv[1:1] = ["fleet"]
    runpy.run_module("hypa", run_name="__main__", alter_sys=True)
