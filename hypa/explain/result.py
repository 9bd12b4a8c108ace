"""What ``hypa explain`` writes: ``explanation.json`` (:func:`to_dict`, documented in the
docs/explain.md) and ``explanation.md``, an engineer's report with rounded numbers and units, and the
one-line summary of a replacement."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

from hypa.evaluation.runs import TrainedRun
from hypa.explain.problem import FIT_SPLIT, SCORE_SPLIT, BlockExplanation
from hypa.reporting import markdown as md
from hypa.reporting.numbers import significant


def replacement_line(rp: dict) -> str:
    """``replaced by its lag: y RMS 0.0104 -> 0.0116 V; ...`` per output (and the baseline's)."""
    parts = []
    for name, learned in rp["learned"].items():
        unit, base = rp["units"][name], rp.get("baseline", {}).get(name)
        parts.append(f"{name} RMS {significant(learned['rms'])} -> {significant(rp['explained'][name]['rms'])} {unit}"
                     + (f" (baseline {significant(base['rms'])})" if base else ""))
    return f"replaced by its {rp['form']} (validation, trained -> explained): " + "; ".join(parts)


def to_dict(run: TrainedRun, results: Sequence[BlockExplanation]) -> dict:
    """The json: the run, and per explained signal its block, signals, units, the core's
    :meth:`Explanation.to_dict`, the comparison with the measurement and the figures."""
    return _finite({
        "run": str(run.folder), "checkpoint": str(run.checkpoint), "model": run.module.model.spec.name,
        "label": run.label, "fit_split": FIT_SPLIT, "score_split": SCORE_SPLIT,
        "blocks": [{"block": r.problem.block, "output": r.problem.output, "inputs": list(r.problem.inputs),
                    "extra": list(r.problem.extra), "units": dict(r.problem.units),
                    "corrects": list(r.problem.corrects) if r.problem.corrects else None,
                    "measured": r.problem.measured,
                    "description": r.explanation.describe(), "explanation": r.explanation.to_dict(),
                    "comparison": r.comparison, "figures": {k: v.name for k, v in r.figures.items()},
                    "replacement": r.replacement, "seconds": r.seconds,
                    "notes": r.notes} for r in results]})


def write_json(run: TrainedRun, results: Sequence[BlockExplanation], path: Path) -> None:
    path.write_text(json.dumps(to_dict(run, results), indent=2, ensure_ascii=False) + "\n")


def _finite(value):
    """NaN and infinities as null: the json stays standard."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_report(run: TrainedRun, results: Sequence[BlockExplanation], path: Path) -> None:
    """``explanation.md``: an engineer's report, rounded numbers with units."""
    lines = [f"# What the learned blocks of {run.label} learned", "",
             (f"Run `{run.folder}` (checkpoint `{run.checkpoint.name}`). The trained model ran free over the "
             f"{FIT_SPLIT} and {SCORE_SPLIT} records; each form was fitted on the {FIT_SPLIT} records and "
             f"scored on the {SCORE_SPLIT} records (R², less a penalty per parameter; the simplest form "
             "within the margin of the best score is chosen)."), ""]
    for r in results:
        lines += _report_block(r)
    path.write_text("\n".join(lines) + "\n")


def _report_block(r: BlockExplanation) -> list[str]:
    p, e = r.problem, r.explanation
    u = p.units
    lines = [f"## {p.block}: {', '.join(p.inputs)} → {p.output}", "",
             f"**{e.describe()}**", ""]
    if p.corrects:
        lines += [f"The block corrects the physics: {p.output} = {p.corrects[0]} − {p.corrects[1]}, what it adds.", ""]
    lines += [f"Signals: output {p.output} [{u[p.output]}]; inputs "
              + ", ".join(f"{n} [{u[n]}]" for n in p.inputs)
              + (f"; extra {', '.join(f'{n} [{u[n]}]' for n in p.extra)}" if p.extra else "; no extra signals")
              + f". Sample time {1000 * e.dt:.3g} ms;"
              + f" validation std of the output {significant(e.output_std)} {u[p.output]}.",
              "", *md.table(["rung", "form", "parameters", "R² train", "R² validation", "score", ""],
                            [[f.form.rung, f.form.name, f.n_parameters, f"{f.r2_train:.3f}", f"{f.r2_val:.3f}",
                              f"{f.score:.3f}", "**chosen**" if i == e.chosen else ""]
                             for i, f in enumerate(e.forms)], align="rlrrrrl")]
    unresolved = e.unresolved()
    lines += ["", f"Chosen: {e.best.form.name} (penalty {e.penalty:g} per parameter, margin {e.margin:g})."
              + (f" {unresolved[0].upper()}{unresolved[1:]}." if unresolved else ""), "",
              *md.table(["value", "signal", "estimate", "1σ", "unit"],
                        [[v.kind, v.signal or "", significant(v.value), significant(v.std), v.unit]
                         for v in e.best.values],
                        align="llrrl")]
    rest = e.remainder
    lines += ["", f"What remains: {rest.describe()}.", "",
              *md.table(["band [Hz]", "share of the remainder", "unexplained share of the output there"],
                        [[f"{band.low:.3g}-{band.high:.3g}", f"{100 * band.share:.0f} %",
                          "-" if not math.isfinite(band.unexplained) else f"{100 * band.unexplained:.0f} %"]
                         for band in rest.bands], align="lrr")]
    unit = "" if rest.amplitude_unit == "-" else f" {rest.amplitude_unit}"
    lines += ["", *md.table([f"abs({rest.amplitude_signal}){unit}", f"RMS error [{u[p.output]}]",
                             "share of the remainder"],
                            [[f"{significant(a.low)}-{significant(a.high)}", significant(a.rms_error),
                              f"{100 * a.share:.0f} %"]
                             for a in rest.amplitudes], align="lrr")]
    if r.comparison:
        c, unit = r.comparison, u[p.output]
        pairs = (("learned_vs_measured", "learned block vs measured"),
                 ("explained_vs_measured", "explained form vs measured"),
                 ("explained_vs_learned", "explained form vs learned block"))
        lines += ["", (f"Against the measured {p.measured} (validation records; never seen in training; "
                      f"RMS of the measurement {significant(c['measured_rms']['rms'])} {unit}):"), "",
                  *md.table(["", "correlation", f"RMS difference [{unit}]", "share of the variance explained"],
                            [[label, f"{c[pair]['corr']:.3f}", significant(c[pair]['rms']),
                              f"{100 * c[pair]['share']:.0f} %"] for pair, label in pairs], align="lrrr")]
    else:
        lines += ["", f"The records hold no measurement of {p.output}: no comparison with the truth."
                  if not p.corrects else "A correction has no measurement to compare with."]
    if r.replacement:
        rp = r.replacement
        header = ["output", "trained model RMS", "R²", "with the explanation RMS", "R²"]
        if "baseline" in rp:
            header += [f"{rp['baseline']['label']} (baseline) RMS", "R²"]
        rows = []
        for name, learned in rp["learned"].items():
            explained, unit = rp["explained"][name], rp["units"][name]
            cells = [name, f"{significant(learned['rms'])} {unit}", f"{learned['r2']:.4f}",
                     f"{significant(explained['rms'])} {unit}", f"{explained['r2']:.4f}"]
            if "baseline" in rp:  # the baseline ran on the same outputs; "-" where one is missing
                base = rp["baseline"].get(name)
                cells += [f"{significant(base['rms'])} {unit}", f"{base['r2']:.4f}"] if base else ["-", "-"]
            rows.append(cells)
        lines += ["", (f"Replaced by its {rp['form']} (`{rp['config']}`: physics blocks with the fitted values; "
                  "the rest of the model as trained), free-running over the validation records:"), "",
                  *md.table(header, rows, align="l" + "r" * (len(header) - 1))]
    captions = {"time": "learned vs explained over time (first validation record)",
                "frequency": "frequency response: the learned block (H1) and the chosen form",
                "static": f"static curve: {p.output} against {p.inputs[0]}"}
    for kind, path in r.figures.items():
        lines += ["", f"![{captions.get(kind, kind)}]({path.name})"]
    for note in r.notes:
        lines += ["", f"Note: {note}"]
    return [*lines, ""]
