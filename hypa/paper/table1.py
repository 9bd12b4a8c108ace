"""The paper's Table 1 beside ours: the "Paper vs hypa" section of ``results/REPORT.md``.

The paper's figures and the curated reasons for differences are data
(``hypa/evaluation/paper_table1.yaml``); this module ranks the rows by R² in both, lists every
pair of rows the two order differently, evaluates the checks of issue 13 on our numbers and
attaches to each difference the reasons that apply, or says that none is known.

Ours are the free-run figures on the whole validation record (``free_run/all``), mean ± std over
seeds, as :func:`hypa.commands.reproduce.aggregate` returns them: a list of rows, each a dict with
``"model"`` (the Table 1 label) and ``"<mode>/<segment>/<metric>": (mean, std)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from fnmatch import fnmatch
from itertools import combinations, pairwise
from pathlib import Path
from typing import Any

import yaml

from hypa.reporting import markdown as md

PAPER_TABLE = Path(__file__).with_name("paper_table1.yaml")
R2 = "free_run/all/r2"
R2_WINDOWED = "windowed/all/r2"
MSE = "free_run/all/mse"
REAR_CORR = "rear_wheel_angle/corr"
DIVERGED_BELOW = 0.9  # free-run R² under this: the simulation has left the data
ON_PAR_R2 = 0.002  # "on par" in R²: within this or within the seed std
Stat = tuple[float, float]  # (mean, std) over seeds


@dataclass(frozen=True)
class Reason:
    """A curated cause of a difference: for pairs hypa ranks ``above`` > ``below`` (fnmatch
    patterns on the labels) where the paper ranks them the other way, and for failed ``checks``."""

    id: str
    text: str
    above: tuple[str, ...] = ()
    below: tuple[str, ...] = ()
    checks: tuple[str, ...] = ()
    diverged: tuple[str, ...] = ()  # rows whose free run leaving the data this explains

    def explains_pair(self, higher: str, lower: str) -> bool:
        """Whether this reason explains hypa ranking ``higher`` over ``lower``."""
        return _matches(higher, self.above) and _matches(lower, self.below)

    def explains_check(self, check: Check) -> bool:
        """Whether this reason explains the failed ``check`` (by its id, or a diverged row)."""
        return check.id in self.checks or any(_matches(row, self.diverged) for row in check.diverged)


def _matches(label: str, patterns: tuple[str, ...]) -> bool:
    return any(fnmatch(label, p) for p in patterns)


@dataclass(frozen=True)
class PaperTable:
    """The paper's Table 1 (``paper[label] = {"mae", "mse", "mape", "r2"}``), hypa-side notes per
    row and the curated reasons for differences."""

    paper: dict[str, dict[str, float]]
    notes: dict[str, str]
    reasons: list[Reason]
    source: str = ""
    on_s4: str = ""


@dataclass(frozen=True)
class Check:
    """One claim of the paper evaluated on our numbers; ``passed`` None: a row it needs is missing."""

    id: str
    claim: str
    passed: bool | None
    figures: str
    spread: bool = False  # failed only within the seed std: the order is not resolved
    diverged: tuple[str, ...] = ()  # the rows whose free run left the data
    reasons: list[str] = field(default_factory=list)  # the curated reasons, as *id*


@dataclass(frozen=True)
class Ours:
    """Our figures per row label, (mean, std) over seeds: free-run and windowed R², free-run MSE
    and the correlation of the learned rear-wheel angle with the measured one."""

    r2: dict[str, Stat]
    windowed: dict[str, Stat]
    mse: dict[str, Stat]
    rear: dict[str, Stat]

    @classmethod
    def from_table(cls, table: list[dict[str, Any]]) -> Ours:
        """From the rows :func:`hypa.commands.reproduce.aggregate` returns."""
        return cls(*(_ours(table, key) for key in (R2, R2_WINDOWED, MSE, REAR_CORR)))


def load_paper_table(path: Path = PAPER_TABLE) -> PaperTable:
    """Read the paper's table, the row notes and the reasons from ``path``."""
    raw = yaml.safe_load(path.read_text())
    paper = {r["label"]: {k: float(v) for k, v in r["paper"].items()} for r in raw["rows"] if r.get("paper")}
    notes = {r["label"]: " ".join(str(r["note"]).split()) for r in raw["rows"] if r.get("note")}
    reasons = [Reason(r["id"], " ".join(str(r["text"]).split()),
                      *(tuple(r.get(key) or ()) for key in ("above", "below", "checks", "diverged")))
               for r in raw["reasons"]]
    return PaperTable(paper, notes, reasons, " ".join(str(raw.get("source", "")).split()),
                      " ".join(str(raw.get("paper_text_on_s4", "")).split()))


def ranks(values: dict[str, float]) -> dict[str, int]:
    """Rank 1 = highest value; equal values share the better rank (1, 1, 3)."""
    return {label: 1 + sum(other > v for other in values.values()) for label, v in values.items()}


def ranking_line(values: dict[str, float]) -> str:
    """``"A = B > C"``: the labels from the highest value down, ties joined by ``=``."""
    ordered = sorted(values, key=lambda label: -values[label])
    line = ordered[:1]
    for prev, label in pairwise(ordered):
        line += ["=" if values[label] == values[prev] else ">", label]
    return " ".join(line)


def _ours(table: list[dict[str, Any]], key: str) -> dict[str, Stat]:
    return {row["model"]: row[key] for row in table if row.get(key) is not None}


def discordant_pairs(paper: dict[str, float], ours: dict[str, float]) -> list[tuple[str, str]]:
    """Pairs ``(higher, lower)`` ordered by ours and reversed by the paper; ties order nothing."""
    common = [label for label in paper if label in ours]
    pairs = []
    for a, b in combinations(common, 2):
        if (paper[a] - paper[b]) * (ours[a] - ours[b]) < 0:
            pairs.append((a, b) if ours[a] > ours[b] else (b, a))
    return pairs


def _within_spread(a: Stat, b: Stat) -> bool:
    return abs(a[0] - b[0]) <= max(a[1], b[1])


def _r2(value: Stat) -> str:
    return f"{value[0]:.4f}"


def _pm(value: Stat | None, digits: str) -> str:
    """``mean ± std``; in ``e`` notation the std gets one significant digit."""
    if value is None:
        return "–"
    spread = f"{value[1]:.1g}" if digits.endswith("e") else f"{value[1]:{digits}}"
    return f"{value[0]:{digits}} ± {spread}"


def _missing(needed: list[str], ours: Ours, claim: str, check_id: str) -> Check | None:
    """A check that cannot be evaluated, when a row it needs has no free-run R²."""
    absent = [label for label in needed if label not in ours.r2]
    if absent:
        return Check(check_id, claim, None, f"not evaluated: {', '.join(absent)} not run")
    return None


def _v1_rows(ours: Ours) -> list[str]:
    return [label for label in ours.r2 if label.startswith("V1 ")]


def check_physical_r2(ours: Ours) -> Check:
    """The physical baseline lands where the paper's does (0.962): R² within 0.95–0.97."""
    claim = "physical R² within 0.95–0.97 (paper 0.962)"
    if absent := _missing(["physical"], ours, claim, "physical_r2"):
        return absent
    value = ours.r2["physical"]
    return Check("physical_r2", claim, 0.95 <= value[0] <= 0.97, f"physical {_pm(value, '.4f')}")


def check_physical_below_v1(ours: Ours) -> Check:
    """Every V1 row beats the physical baseline, by R² and by MSE."""
    claim = "physical < every V1 row, by R² and by MSE"
    if absent := _missing(["physical"], ours, claim, "physical_below_v1"):
        return absent
    v1 = _v1_rows(ours)
    if not v1:
        return Check("physical_below_v1", claim, None, "not evaluated: no V1 row run")
    r2, mse = ours.r2, ours.mse
    no_mse = (float("inf"), 0.0)  # a row without an MSE cannot pass
    failed = [label for label in v1 if not (r2[label][0] > r2["physical"][0]
                                            and mse.get(label, no_mse)[0] < mse.get("physical", (0.0, 0.0))[0])]
    figures = "; ".join(f"{label} {_r2(r2[label])} / {_pm(mse.get(label), '.2e')}" for label in ["physical", *v1])
    return Check("physical_below_v1", claim, not failed,
                 f"R² / MSE: {figures}" + (f"; not above physical: {', '.join(failed)}" if failed else ""))


def check_v1_below_v3_below_v2(ours: Ours) -> Check:
    """The paper's order of the hybrids: every V1 < V3 ≤ V2 (by free-run R²)."""
    claim = "every V1 row < V3 ≤ V2, by free-run R²"
    if absent := _missing(["V2", "V3"], ours, claim, "v1_below_v3_below_v2"):
        return absent
    r2, v1 = ours.r2, _v1_rows(ours)
    best_v1 = max(v1, key=lambda label: r2[label][0]) if v1 else None
    # each pair that must be ordered: (lower, higher, whether it is)
    pairs = ([(best_v1, "V3", r2[best_v1][0] < r2["V3"][0])] if best_v1 else []) + [
        ("V3", "V2", r2["V3"][0] <= r2["V2"][0])]
    passed = all(ok for _, _, ok in pairs)
    spread = not passed and all(_within_spread(r2[a], r2[b]) for a, b, ok in pairs if not ok)
    best = f"best V1 ({best_v1}) {_pm(r2[best_v1], '.4f')}, " if best_v1 else "no V1 row run, "
    return Check("v1_below_v3_below_v2", claim, passed,
                 f"{best}V3 {_pm(r2['V3'], '.5f')}, V2 {_pm(r2['V2'], '.5f')}", spread)


def check_v2_on_par_with_lstm(ours: Ours) -> Check:
    """The paper's V2 is "on par with the end-to-end LSTM" in R²: at least the LSTM's R² less the
    larger of the seed stds and 0.002."""
    claim = ("V2 on par with or better than the end-to-end LSTM, by free-run R² "
             f"(on par: within the seed std or {ON_PAR_R2})")
    if absent := _missing(["V2", "LSTM"], ours, claim, "v2_on_par_with_lstm"):
        return absent
    v2, lstm = ours.r2["V2"], ours.r2["LSTM"]
    tolerance = max(ON_PAR_R2, v2[1], lstm[1])
    return Check("v2_on_par_with_lstm", claim, v2[0] >= lstm[0] - tolerance,
                 f"V2 {_pm(v2, '.4f')}, LSTM {_pm(lstm, '.4f')} (difference {v2[0] - lstm[0]:+.4f}, "
                 f"tolerance {tolerance:.4f})")


def check_v1_lstm_rear_corr(ours: Ours) -> Check:
    """V1 LSTM's implicitly learned rear-wheel angle follows the measured one (correlation ≥ 0.9)."""
    claim = "V1 LSTM's learned rear-wheel angle: correlation with the measured ≥ 0.9"
    if "V1 LSTM" not in ours.rear:
        return Check("v1_lstm_rear_corr", claim, None, "not evaluated: V1 LSTM not run or no measured angle")
    corr = ours.rear["V1 LSTM"]
    return Check("v1_lstm_rear_corr", claim, corr[0] >= 0.9, f"V1 LSTM {_pm(corr, '.3f')}")


def check_free_run_bounded(ours: Ours) -> Check:
    """Every row's free run stays on the data: R² above 0.9."""
    claim = f"every row's free-run R² > {DIVERGED_BELOW}"
    if not ours.r2:
        return Check("free_run_bounded", claim, None, "not evaluated: no free-run R²")
    r2 = ours.r2
    low = [label for label, v in r2.items() if v[0] <= DIVERGED_BELOW]
    worst = min(r2, key=lambda label: r2[label][0])
    diverged = [f"{label} {_pm(r2[label], '.4f')}" + (f" (windowed {_r2(ours.windowed[label])})"
                                                      if label in ours.windowed else "") for label in low]
    figures = f"diverged: {', '.join(diverged)}" if low else f"lowest: {worst} {_r2(r2[worst])}"
    return Check("free_run_bounded", claim, not low, figures, diverged=tuple(low))


CHECKS: list[Callable[[Ours], Check]] = [
    check_physical_r2, check_physical_below_v1, check_v1_below_v3_below_v2, check_v2_on_par_with_lstm,
    check_v1_lstm_rear_corr, check_free_run_bounded]


def evaluate_checks(table: list[dict[str, Any]], paper: PaperTable) -> list[Check]:
    """Every check on our numbers, each failed one with the curated reasons that name it."""
    ours = Ours.from_table(table)
    checks = []
    for check in (fn(ours) for fn in CHECKS):
        reasons = [f"*{r.id}*" for r in paper.reasons if r.explains_check(check)] if check.passed is False else []
        checks.append(Check(check.id, check.claim, check.passed, check.figures, check.spread, check.diverged,
                            reasons))
    return checks


def _remark(label: str, r2: dict[str, Stat], paper: PaperTable) -> str:
    remarks = []
    if label in r2 and r2[label][0] <= DIVERGED_BELOW:
        remarks.append(f"**diverged**: free run leaves the data: R² {_r2(r2[label])}")
    if label not in paper.paper:
        remarks.append("not in the paper")
    if label in paper.notes:
        remarks.append("see note")
    return "; ".join(remarks)


def comparison_rows(table: list[dict[str, Any]], paper: PaperTable) -> list[str]:
    """The side-by-side table: paper and hypa R² and MSE, and each row's rank by R² in both (among
    the rows both have)."""
    r2, windowed, mse = _ours(table, R2), _ours(table, R2_WINDOWED), _ours(table, MSE)
    common = [label for label in paper.paper if label in r2]
    paper_rank = ranks({label: paper.paper[label]["r2"] for label in common})
    our_rank = ranks({label: r2[label][0] for label in common})
    header = ["row", "paper R²", "hypa R² (free run)", "hypa R² (windowed)", "paper MSE", "hypa MSE (free run)",
              "rank paper", "rank hypa", "remark"]
    rows = []
    labels = list(dict.fromkeys([*(row["model"] for row in table), *paper.paper]))
    for label in labels:
        theirs = paper.paper.get(label, {})
        rows.append([label, f"{theirs['r2']:.3f}" if "r2" in theirs else "–", _pm(r2.get(label), ".4f"),
                     _pm(windowed.get(label), ".4f"), f"{theirs['mse']:.1e}" if "mse" in theirs else "–",
                     _pm(mse.get(label), ".2e"), paper_rank.get(label, "–"), our_rank.get(label, "–"),
                     _remark(label, r2, paper) if label in r2 else "not run"])
    return md.table(header, rows)


def pair_line(higher: str, lower: str, table: list[dict[str, Any]], paper: PaperTable) -> str:
    """One pair hypa orders ``higher`` > ``lower`` and the paper the other way, with its reasons:
    computed ones (seed spread, a diverged free run) first, then the curated ones."""
    r2, windowed = _ours(table, R2), _ours(table, R2_WINDOWED)
    theirs = paper.paper
    reasons = []
    if _within_spread(r2[higher], r2[lower]):
        reasons.append("the two are within one seed std of each other here: the seeds do not resolve their order")
    diverged = r2[lower][0] <= DIVERGED_BELOW
    if diverged:
        reasons.append(f"{lower}'s free run leaves the data (see the checks)")
    reasons += [f"*{r.id}*" for r in paper.reasons
                if r.explains_pair(higher, lower) or (diverged and _matches(lower, r.diverged))]
    line = (f"- **{higher} above {lower}** here ({_r2(r2[higher])} vs {_r2(r2[lower])}), below in the paper "
            f"({theirs[higher]['r2']:.3f} vs {theirs[lower]['r2']:.3f}).")
    if higher in windowed and lower in windowed and windowed[higher][0] < windowed[lower][0]:
        line += (f" The windowed R² orders them as the paper does "
                 f"({_r2(windowed[higher])} vs {_r2(windowed[lower])}).")
    return f"{line} {_because(reasons)}"


def level_line(table: list[dict[str, Any]], paper: PaperTable) -> str | None:
    """Where our free-run R² is above the paper's, with the curated reasons that name
    ``r2_levels``, and where it is not."""
    r2 = _ours(table, R2)
    common = [label for label in paper.paper if label in r2]
    if not common:
        return None
    higher = [label for label in common if r2[label][0] > paper.paper[label]["r2"]]
    lower = [f"{label} ({_r2(r2[label])} vs {paper.paper[label]['r2']:.3f}"
             + (", diverged)" if r2[label][0] <= DIVERGED_BELOW else ")") for label in common if label not in higher]
    reasons = [f"*{r.id}*" for r in paper.reasons if "r2_levels" in r.checks]
    why = f"reason: {'; '.join(reasons)}" if reasons else "reason not known"
    return (f"- **R² level**: higher here than in the paper for {len(higher)} of {len(common)} rows"
            + (f" ({why})" if higher else "")
            + (f"; not for {', '.join(lower)}" if lower else "") + ".")


def difference_lines(table: list[dict[str, Any]], paper: PaperTable, checks: list[Check]) -> list[str]:
    """Every pair ordered differently, the level of R² and every failed check, each with reasons."""
    r2 = _ours(table, R2)
    theirs = {label: v["r2"] for label, v in paper.paper.items()}
    lines = [pair_line(higher, lower, table, paper)
             for higher, lower in discordant_pairs(theirs, {label: v[0] for label, v in r2.items()})]
    for check in checks:
        if check.passed is False:
            reasons = (["the failure is within one seed std: the seeds do not resolve the order"]
                       if check.spread else []) + check.reasons
            lines.append(f"- **check failed: {check.claim}** ({check.figures}). " + _because(reasons))
    if not lines:
        lines = ["- none: every pair both have is ordered alike and every check passes."]
    level = level_line(table, paper)
    return lines + ([level] if level else [])


def _because(reasons: list[str]) -> str:
    if not reasons:
        return "Reason not known."
    return "Reason: " + "; ".join(reasons) + "."


def _mark(passed: bool | None) -> str:
    return {True: "✓", False: "✗", None: "–"}[passed]


def comparison_markdown(table: list[dict[str, Any]], paper: PaperTable | None = None) -> str:
    """The "Paper vs hypa" section: the tables side by side, the rankings, the checks and every
    difference with its reason."""
    paper = paper or load_paper_table()
    r2 = _ours(table, R2)
    common = [label for label in paper.paper if label in r2]
    checks = evaluate_checks(table, paper)
    intro = ("The paper's Table 1 beside ours, row by row. Ours: free run over the whole validation record "
             "(`free_run/all`), mean ± std over seeds; the windowed R² beside it, since the paper does not "
             "say which of the two it reports. Ranks by R² among the rows both have (1 = best). The MSE "
             "levels are not comparable: the paper states no units, ours is in SI units (rad, rad/s), "
             "mean over yaw rate and side slip; R² is free of units. "
             f"Source: {paper.source}")
    parts = ["## Paper vs hypa", "", intro, "",
             *comparison_rows(table, paper), ""]
    notes = [f"- **{label}**: {paper.notes[label]}" for label in paper.notes if label in r2]
    if notes:
        parts += ["Notes on rows:", "", *notes, *([f"- {paper.on_s4}"] if paper.on_s4 else []), ""]
    parts += ["### Ranking by R²", "",
              f"- paper: {ranking_line({label: paper.paper[label]['r2'] for label in common})}",
              f"- hypa (free run): {ranking_line({label: r2[label][0] for label in common})}"]
    extra = [label for label in r2 if label not in paper.paper]
    if extra:
        parts.append(f"- hypa, every row run (free run): {ranking_line({k: v[0] for k, v in r2.items()})}")
    parts += ["", "### Checks", "",
              *md.table(["", "check", "figures (hypa)"], [[_mark(c.passed), c.claim, c.figures] for c in checks])]
    differences = difference_lines(table, paper, checks)
    parts += ["", "### Where they differ", "", *differences, ""]
    used = [r for r in paper.reasons if any(f"*{r.id}*" in line for line in differences)]
    if used:
        parts += ["Reasons (curated in `hypa/evaluation/paper_table1.yaml`):", "",
                  *[f"- *{r.id}*: {r.text}." for r in used], ""]
    return "\n".join(parts)
