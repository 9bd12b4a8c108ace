"""``hypa.diagnose model=M``: the diagnosis of any system, from its nominal hypa model.

Steps: (1) the nominal model free-running on the validation records; (2) the named causes
(:func:`hypa.diagnosis.engine.name_causes`); (3) what remains and where it lives
(:mod:`hypa.diagnosis.structure`); (4) the extended model written as a hypa model config,
``conf/model/diagnosed.yaml`` (the named causes, fitted) and ``diagnosed_hybrid.yaml`` (the
same with a correction network, HyPA-Net style: the one to train when structure remains
unexplained), with the commands that train them; the gain on the validation records. Writes ``diagnosis.json``,
``diagnosis.md`` and figures into ``out``.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import yaml

from hypa import markdown as md
from hypa.diagnosis.catalogue import Entry
from hypa.diagnosis.coverage import coverage, short_lines
from hypa.diagnosis.edits import frozen, set_free
from hypa.diagnosis.engine import Finding, Problem, Search, name_causes
from hypa.diagnosis.problem import format_change
from hypa.diagnosis.scales import Scales, duration
from hypa.diagnosis.structure import OutputStructure, analyze_output
from hypa.diagnosis.trained import TrainedExtension
from hypa.metrics import correlation, errors, rms
from hypa.models.rollout import Prediction, free_run, free_run_metrics
from hypa.models.spec import DIAGNOSED, ModelSpec, spec_config
from hypa.plots import time_series



def with_correction(spec: ModelSpec, inputs: Sequence[str]) -> ModelSpec:
    """The model with a correction network on its outputs (HyPA-Net): the physics writes
    ``<output>_physics``, the network reads the inputs and those and adds its correction."""
    from hypa.models.spec import BlockSpec

    renamed = {o: f"{o}_physics" for o in spec.outputs}
    blocks = []
    for b in spec.blocks:
        outputs = tuple(renamed.get(s, s) for s in b.outputs)
        observe = {**b.observe, **{renamed[s]: s for s in b.outputs if s in renamed}} if b.kind == "physics" else {}
        blocks.append(dataclasses.replace(b, outputs=outputs, observe=observe) if outputs != b.outputs else b)
    correction = BlockSpec(name="correction", kind="ann", inputs=(*inputs, *renamed.values()),
                           outputs=tuple(spec.outputs), residual_of=tuple(renamed.values()))
    from hypa.models.spec import StageSpec

    stages = (StageSpec("physics", train=tuple(b.name for b in blocks if b.trainable), bypass=("correction",)),
              StageSpec("correction", train=("correction",))) if any(b.trainable for b in blocks) else ()
    return dataclasses.replace(spec, name=f"{spec.name}_hybrid", blocks=(*blocks, correction), stages=stages)


def with_networks(spec: ModelSpec, blocks: Sequence[str]) -> ModelSpec:
    """``diagnosed_learned``: the diagnosed model with ``blocks`` (inserted by named causes whose
    catalogue entry lists them under ``learn``) learned by networks with the same inputs and
    outputs, and every physical value frozen at its diagnosed value, so that the network learns the
    subsystem and not the physics' other errors (V1's idea on corrected physics; ``hypa.explain``
    then says what it learned)."""
    from hypa.models.spec import BlockSpec

    swapped = tuple(BlockSpec(name=b.name, kind="ann", inputs=b.inputs, outputs=b.outputs, scale_as=b.scale_as)
                    if b.name in blocks else b for b in frozen(spec).blocks)
    return dataclasses.replace(spec, name="diagnosed_learned", blocks=swapped, stages=())


def refittable(spec: ModelSpec, nominal: ModelSpec, named: Sequence[Finding]) -> ModelSpec:
    """The extended model with what training may refine set free: the nominal's uncertain
    parameters and every knob of the named causes (an inserted block's, ``<block>/<name>``, and a
    swapped system's own, such as a stiffening spring's hardening), starting from the fitted values."""
    nominal_free = {b.name: tuple(b.trainable) for b in nominal.blocks}
    base = dataclasses.replace(spec, blocks=tuple(dataclasses.replace(b, trainable=nominal_free.get(b.name, ()))
                                                  for b in spec.blocks))
    knobs = [k for f in named if f.candidate is not None and f.candidate.fit == "gradient" for k in f.candidate.knobs]
    return set_free(base, knobs)


def _runs(problem: Problem, spec: ModelSpec) -> list[Prediction]:
    model = problem.build(spec)
    return [free_run(model, problem.dm, r) for r in problem.dm.records("val")]


def _change(before: Mapping[str, dict], after: Mapping[str, dict], outputs: Sequence[str]) -> dict[str, float]:
    """Relative change of each output's validation MSE."""
    return {o: after[o]["mse"] / before[o]["mse"] - 1.0 if before[o]["mse"] > 0 else 0.0 for o in outputs}


def validation_error(metrics: Mapping[str, dict], outputs: Sequence[str]) -> float:
    """The mean over outputs of 1 - R² of free-run metrics: the report's headline figure."""
    return float(np.mean([1.0 - metrics[o]["r2"] for o in outputs]))


def _overall(before: Mapping[str, dict], after: Mapping[str, dict], outputs: Sequence[str]) -> float:
    """Relative change of the mean over outputs of 1 - R² (:func:`validation_error`)."""
    b = validation_error(before, outputs)
    return validation_error(after, outputs) / b - 1.0 if b > 0 else 0.0


def headline(result: Mapping) -> dict[str, str]:
    """The headline figures as printed, for diagnosis.md and the command's last line alike (one
    place, so the two cannot disagree): ``nominal``, ``extended`` (``trained``) as shares of the
    output variance, and ``change``, extended against nominal."""
    error = result["error"]
    out = {m: f"{100 * error[m]:.3g} %" for m in ("nominal", "extended", "trained") if m in error}
    out["change"] = format_change(error["change"])
    return out


def diagnose_system(nominal: ModelSpec, problem: Problem, out: Path, train_overrides: Sequence[str] = (),
                    plot: bool = True, max_causes: int = 8, min_gain: float = 0.15,
                    progress: Callable[[str], None] = print, config_dir: Path | None = None,
                    catalogue: Sequence[Entry] | None = None,
                    train_extension: Callable[[Sequence[str]], TrainedExtension] | None = None) -> dict:
    """Steps 1-4 for the nominal model on the problem's data; returns diagnosis.json's content.

    ``train_overrides`` select the same data for ``hypa.train``; ``config_dir``: the user's own
    config folder (``--config-dir``) that the train command needs too (their dataset YAML).
    ``train_extension(arguments)``: trains the written model with those ``hypa.train`` arguments
    and returns its free runs over the validation records and what its networks learned
    (:mod:`hypa.diagnosis.trained`); its gain and those explanations join the report."""
    problem = problem.scaled(frozen(nominal))
    problem.require_data()  # before any step is announced: data too short are refused in one line
    out.mkdir(parents=True, exist_ok=True)
    dm, started = problem.dm, time.perf_counter()
    progress(f"step 1/4: the nominal model {nominal.name!r} free-running on {len(dm.records('val'))} "
             "validation record(s)")
    covered, crossed = coverage(dm), len(problem.folds()) > 1
    for line in short_lines(dm, covered):
        progress(f"          validation data: {line}: "
                 + ("the validation figures cover a part of the operating range" if crossed else
                    "candidates are judged on a part of the operating range"))
    progress("step 2/4: naming the causes (" + (
        f"each candidate fitted on every other block of all records and scored on the rest, {len(problem.folds())} "
        "folds" if crossed else f"each candidate fitted on {len(dm.records('train'))} training record(s)")
        + "; seconds to a minute)")
    search = name_causes(nominal, problem, catalogue=catalogue, max_causes=max_causes, min_gain=min_gain,
                         progress=lambda text: progress("          " + text))
    progress(f"          named: {', '.join(f.cause for f in search.named) or 'none'} ({search.seconds:.0f} s)")
    progress("step 3/4: what remains (amplitude, band, correlation with the inputs)")
    before, after = _runs(problem, frozen(nominal)), _runs(problem, search.spec)
    # every measured channel but the outputs; those the extended model does not read are named as such
    used = {s for b in search.spec.blocks for s in (*b.inputs, *b.scheduling.values())}
    held = {r.name: r for r in dm.records("val")}
    channels = [c for c in dm.channels if c not in dm.output_names
                and all(c in r.inputs or c in held[r.record].channels for r in after)]
    structure = [analyze_output(o, dm.channels[o].unit, [r.measured[o][r.first:] for r in after],
                                [r.predicted[o][r.first:] for r in after],
                                {c: [r.inputs[c][r.first:] if c in r.inputs else _record(dm, r, c) for r in after]
                                 for c in channels}, problem.time_scales, unused=set(channels) - used)
                 for o in dm.output_names]
    unexplained = [s for s in structure if s.unexplained]
    progress("step 4/4: the extended model as a hypa model, and its gain")
    conf = out / "conf" / "model"
    conf.mkdir(parents=True, exist_ok=True)
    # the written models keep the hold they were diagnosed with (their fitted values belong to it)
    extended = dataclasses.replace(refittable(search.spec, nominal, search.named), name="diagnosed",
                                   hold=nominal.hold or problem.hold)
    # the hybrid is written whatever remains (the benchmark's hybrid row trains it); it is the one to
    # train when the residual analysis leaves something unexplained
    hybrid = dataclasses.replace(with_correction(extended, dm.input_names), name="diagnosed_hybrid")
    written = {"diagnosed": _write(conf / "diagnosed.yaml", extended, search.named),
               "diagnosed_hybrid": _write(conf / "diagnosed_hybrid.yaml", hybrid, search.named)}
    learned = [b for f in search.named if f.candidate for b in f.candidate.learn]
    if learned:
        written["diagnosed_learned"] = _write(conf / "diagnosed_learned.yaml",
                                              with_networks(extended, learned), search.named)
    train_overrides = with_past(train_overrides, problem, extended)
    commands = {name: train_command(out / "conf", name, train_overrides, name != "diagnosed", config_dir)
                for name in written}
    metrics = {"nominal": free_run_metrics(before, dm.output_names),
               "extended": free_run_metrics(after, dm.output_names)}
    change = _change(metrics["nominal"], metrics["extended"], dm.output_names)
    # the headline's change: of the table's free runs, as the trained extension's below (the search's
    # own score restarts its free runs every stretch_s: on long records a slightly different figure)
    change["overall"] = _overall(metrics["nominal"], metrics["extended"], dm.output_names)
    error = {m: validation_error(metrics[m], dm.output_names) for m in ("nominal", "extended")}
    trained = None
    if train_extension is not None:
        name = "diagnosed_hybrid" if unexplained else "diagnosed"
        progress(f"          training {name} with hypa.train (progress below)")
        extension = train_extension(train_arguments(out / "conf", name, train_overrides, name != "diagnosed",
                                                    config_dir))
        runs = list(extension.predictions)
        metrics["trained"] = free_run_metrics(runs, dm.output_names)
        trained = {"model": name, "run": str(extension.run), "metrics": metrics["trained"],
                   "gain": {"all": {**_change(metrics["nominal"], metrics["trained"], dm.output_names),
                                    "overall": _overall(metrics["nominal"], metrics["trained"], dm.output_names)}},
                   "explained": extension.explanations}
        error["trained"] = validation_error(metrics["trained"], dm.output_names)
    error["change"] = change["overall"]
    evidence = problem.evidence()
    result = {
        "cause": search.named[0].cause if search.named else "none",  # the first named (the schema of old reports)
        "estimate": dict(search.named[0].values) if search.named else {},
        "system": {"model": nominal.name, "inputs": list(dm.input_names), "outputs": list(dm.output_names),
                   "scheduling": list(dm.scheduling_names)},
        "causes": [f.cause for f in search.named],
        "named": [f.to_dict() for f in search.named],
        "dropped": [f.to_dict() for f in search.dropped],
        "candidates": [_candidate(f, search.nominal_score) for f in search.named]
        + [_candidate(f, search.nominal_score) for f in (search.rounds[0] if search.rounds else [])
           if f.key not in {n.key for n in search.named}],
        "rounds": [[f.to_dict() for f in r] for r in search.rounds],
        "score": {"nominal": search.nominal_score, "extended": search.final_score},
        "error": error,
        "metrics": metrics,
        "gain": {"all": change},
        "too_short": list(search.too_short),
        "generic": [{"score": g.score, "gain": g.gain, "numbers": g.numbers} for g in search.generic],
        "standin": search.standin,
        "coverage": [c.to_dict() for c in covered],
        "not_covered": short_lines(dm, covered),
        "unexplained": [s.to_dict() for s in unexplained],
        "structure": {s.output: s.to_dict() for s in structure},
        "extended": {"config": {k: str(v) for k, v in written.items()}, "train_command": commands,
                     "signals": signal_agreement(after), **({"trained": trained} if trained else {})},
        "data": {"dt": dm.dt, "train_records": len(dm.records("train")), "val_records": len(dm.records("val")),
                 "folds": search.folds, "blocks": search.blocks,
                 "train_s": evidence.seconds, "train_windows": evidence.windows, "train_stretches": evidence.stretches,
                 "stretch_s": problem.time_scales.stretch_s, "scales": problem.time_scales.to_dict()},
        "seconds": time.perf_counter() - started,
    }
    figures = _figures(out, before, after, dm, runs if trained else (), list(result["extended"]["signals"])) \
        if plot else {}
    result["figures"] = figures
    (out / "diagnosis.json").write_text(json.dumps(result, indent=2, default=float))
    (out / "diagnosis.md").write_text(markdown(result, search, structure, dm, min_gain, problem.time_scales))
    return result


def _record(dm, run: Prediction, channel: str) -> np.ndarray:
    record = next(r for r in dm.records("val") if r.name == run.record)
    return record[channel][run.first:]


def _candidate(f: Finding, nominal_score: float) -> dict:
    """A row of ``candidates`` (the schema the fleet summary reads): cause, score = share of the
    nominal error it explains, estimate (fitted values [SI]), evidence (one line in units)."""
    return {"cause": f.cause, "target": f.target, "score": f.gain, "estimate": f.values, "evidence": f.describe(),
            "alternatives": f.alternatives}


def _write(path: Path, spec: ModelSpec, named: Sequence[Finding]) -> Path:
    header = ["# @package model", "# Written by hypa.diagnose: the nominal model extended by the named causes:"]
    header += [f"#   {f.describe()}" for f in named] or ["#   (none named)"]
    path.write_text("\n".join(header) + "\n" + yaml.safe_dump(spec_config(spec), sort_keys=False))
    return path


WRITTEN = {"diagnosed": "the named causes at their fitted values, the uncertain ones trainable",
           "diagnosed_hybrid": "the same with a correction network on the outputs",
           "diagnosed_learned": ("the subsystems the named causes stand in for learned by networks in the frozen "
                                 "physics; then `python -m hypa.explain run=<its run>` says what they learned")}
PAST_MARGIN = 4  # an estimated start sees this many times as many measured values as the block has states


def with_past(overrides: Sequence[str], problem: Problem, spec: ModelSpec) -> list[str]:
    """``overrides`` with ``data.past`` raised where the extended model estimates states (a cause
    that added some, e.g. the slips of tire relaxation) from fewer past samples than it needs:
    :data:`PAST_MARGIN` times the fewest that determine them."""
    needed = problem.build(spec).past_needed()
    if not needed or problem.dm.past >= max(needed.values()):
        return list(overrides)
    past = PAST_MARGIN * (max(needed.values()) + 1) - 1
    return [*(o for o in overrides if o.split("=", 1)[0].lstrip("+~") != "data.past"), f"data.past={past}"]


def train_arguments(written: Path, model: str, overrides: Sequence[str], with_ann: bool,
                    config_dir: Path | None = None) -> list[str]:
    """``python -m hypa.train`` arguments that train a written model on the same data: the
    written folder joins Hydra's search path, so a user's own ``--config-dir`` (their dataset)
    still applies."""
    return [*(["--config-dir", str(config_dir)] if config_dir else []), f"hydra.searchpath=[file://{written}]",
            f"model={model}", *overrides, *(["ann=lstm"] if with_ann else [])]


def train_command(written: Path, model: str, overrides: Sequence[str], with_ann: bool,
                  config_dir: Path | None = None) -> str:
    """The shell command of :func:`train_arguments`."""
    return " ".join(["python -m hypa.train",
                     *(shlex.quote(w) for w in train_arguments(written, model, overrides, with_ann, config_dir))])


def signal_agreement(runs: Sequence[Prediction]) -> dict[str, dict[str, float]]:
    """Where the data measure what a diagnosed block recovers (its internal signal
    ``diagnosed_<channel>`` and a measured ``<channel>``, e.g. the rear-wheel angle on the test
    bench, evaluation only): correlation, RMS error and the measured RMS [SI] over the records."""
    out = {}
    names = {n for r in runs for n in r.signals if n.startswith(DIAGNOSED)}
    for name in sorted(names):
        channel = name[len(DIAGNOSED):]
        pairs = [(r.measured[channel], r.signal_on_grid(name)) for r in runs if channel in r.measured
                 and name in r.signals]
        if not pairs:
            continue
        measured, recovered = (np.concatenate(x) for x in zip(*pairs))
        ok = np.isfinite(recovered) & np.isfinite(measured)
        if ok.sum() < 3 or np.std(measured[ok]) == 0 or np.std(recovered[ok]) == 0:
            continue
        m, r = measured[ok], recovered[ok]
        out[channel] = {"correlation": correlation(m, r), "rmse": errors(r, m)["rmse"], "measured_rms": rms(m)}
    return out


def _figures(out: Path, before: Sequence[Prediction], after: Sequence[Prediction], dm,
             trained: Sequence[Prediction] = (), signals: Sequence[str] = ()) -> dict:
    """Per validation record: measured vs the free runs (nominal, extended, trained); per
    recovered signal that the data measure: the two over the first record."""
    def save(fig, name: str) -> str:
        fig.savefig(out / name, dpi=100)
        return name

    units = {n: dm.channels[n].display_unit for n in (*dm.output_names, *signals)}
    scale = {n: dm.channels[n].display_factor for n in (*dm.output_names, *signals)}
    names: dict[str, list[str]] = {"time_series": [], "signals": []}
    for k, (b, a) in enumerate(zip(before, after)):
        runs = {"nominal": b.predicted, "extended (named causes)": a.predicted}
        if k < len(trained):
            runs["trained extension"] = trained[k].predicted
        fig = time_series(b.time, {n: b.measured[n] for n in dm.output_names}, runs, units=units, scale=scale,
                          title=f"measured vs free run over {b.record}")
        names["time_series"].append(save(fig, f"time_series_{Path(b.record).stem}.png"))
    for channel in signals:
        run = after[0]
        fig = time_series(run.time, {channel: run.measured[channel]},
                          {f"recovered ({DIAGNOSED}{channel})": {channel: run.signal_on_grid(DIAGNOSED + channel)}},
                          units=units, scale=scale, title=f"{channel}: measured (never trained on) vs recovered "
                          f"over {run.record}")
        names["signals"].append(save(fig, f"signal_{channel}.png"))
    return names


def markdown(result: dict, search: Search, structure: Sequence[OutputStructure], dm, min_gain: float,
             scales: Scales) -> str:
    """diagnosis.md: the engineer's report (``scales``: the time scales the search ran at)."""
    lines = [f"# Diagnosis of `{result['system']['model']}`", ""]
    lines += [f"Inputs {', '.join(result['system']['inputs'])}; outputs {', '.join(result['system']['outputs'])}"
              + (f"; scheduling {', '.join(result['system']['scheduling'])}" if result["system"]["scheduling"] else "")
              + f". {result['data']['train_records']} training and {result['data']['val_records']} validation "
              f"record(s) at {1 / dm.dt:.4g} Hz. Free-run error on the validation records, as a share of each "
              "output's variance (1 − R², the table \"Per output\"), averaged over the outputs:", ""]
    figures = headline(result)

    def per_output(model: str) -> str:
        return ", ".join(f"{o} {100 * (1 - result['metrics'][model][o]['r2']):.3g} %" for o in dm.output_names)

    lines.append(f"- nominal model: **{figures['nominal']}** ({per_output('nominal')})")
    lines.append(f"- with the named causes: **{figures['extended']}** ({per_output('extended')})")
    if "trained" in figures:
        lines.append(f"- the trained extension: **{figures['trained']}** ({per_output('trained')})")
    lines.append(f"- change with the named causes: **{figures['change']}**")
    crossed = search.folds > 1
    error = "cross-validated error" if crossed else "validation error"
    if result.get("not_covered"):
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
        lines += [f"- {line}." for line in result["not_covered"]]
    stretch = duration(result["data"]["stretch_s"])
    lines += ["", "## Named causes", "",
              (f"The gains below are cross-validated: every record, training and validation, cut into "
               f"{search.blocks} blocks of {stretch}; each candidate fitted on every other block and scored on the "
               f"others (free runs started from the data at each block), then the other way round, the "
               f"{search.folds} halves' errors pooled. Its values are the mean of the {search.folds} fits (each "
               "fit's in `diagnosis.json`, `named[].folds`), so the validation figures above are not held out. "
               if crossed else
               "The gains below are the search's own score: free runs over the validation records restarted from "
               f"the data every {stretch} (on longer records a little different from the figures above). ")
              + f"Time scales from the nominal model and the data: {scales.describe()}.", ""]
    if not search.named:
        lines.append(f"None: no catalogue cause lowers the {error} by {100 * min_gain:.0f} % or more"
                     + (" among those the data could support (see \"Too little data\")." if search.too_short else "."))
    previous = search.nominal_score
    for k, f in enumerate(search.named, 1):
        share = (previous - f.score) / search.nominal_score if search.nominal_score > 0 else 0.0
        lines.append(f"{k}. **{f.cause}** on `{f.target}`: "
                     + (f.describe().split(": ", 1)[1] if ": " in f.describe() else "no value")
                     + f". {error.capitalize()} {100 * f.gain:.2g} % lower than before it; "
                     f"{100 * share:.2g} % of the nominal error."
                     + (f" Small (below the {100 * min_gain:.0f} % floor), but {f.z:.0f} standard errors from zero."
                        if f.small else "")
                     + (f" A generic linear filter from the inputs in its place: {100 * f.generic:.2g} % lower."
                        if f.generic is not None else ""))
        if f.alternatives:
            lines.append(f"   The data cannot tell it from: {'; '.join(f.alternatives)}.")
        previous = f.score
    if search.standin:
        lines.append(f"- Not named: {search.standin}.")
    for f in search.dropped:
        lines.append(f"- Named, then dropped: **{f.cause}** on `{f.target}`; {f.note}.")
    if search.too_short:
        lines += ["", "## Too little data", "",
                  ("What the training records are too short to fit or to judge (a fit needs more training windows "
                   "without overlap than the numbers it fits; an offset's standard error needs more training "
                   "stretches than the offsets fitted with it):"), ""]
        lines += [f"- {line}." for line in search.too_short]
    models = [m for m in ("nominal", "extended", "trained") if m in result["metrics"]]
    output_rows = []
    for o in dm.output_names:
        ch = dm.channels[o]
        scores = [result["metrics"][m][o] for m in models]
        output_rows.append([o, *(f"{r['rmse'] * ch.display_factor:.3g} {ch.display_unit}" for r in scores),
                            *(f"{r['r2']:.4f}" for r in scores)])
    lines += ["", "## Per output (validation, free run)", "",
              *md.table(["output", *(f"{m} RMS" for m in models), *(f"{m} R²" for m in models)], output_rows)]
    trained = result["extended"].get("trained")
    if trained:
        lines += ["", f"The trained extension is `{trained['model']}` trained by hypa.train (run `{trained['run']}`): "
                  f"validation error {format_change(trained['gain']['all']['overall'])} against the nominal model."]
        if trained["explained"]:
            lines += ["", "What its networks learned (hypa.explain; fitted on the training records, R² on the "
                      f"validation records; report `{trained['explained'][0]['report']}`):", ""]
            lines += [f"- `{e['block']}`, {e['signal']}: {e['description']}" for e in trained["explained"]]
    if result["extended"]["signals"]:
        recovered = []
        for channel, a in result["extended"]["signals"].items():
            ch = dm.channels[channel]
            recovered.append([channel, f"{a['correlation']:.3f}",
                              f"{a['rmse'] * ch.display_factor:.3g} {ch.display_unit}",
                              f"{a['measured_rms'] * ch.display_factor:.3g} {ch.display_unit}"])
        lines += ["", "## Recovered signals against their measurement", "",
                  "What a diagnosed block recovers, compared with a channel the data measure but that was "
                  "never trained on:", "", *md.table(["signal", "correlation", "RMS error", "measured RMS"], recovered)]
    lines += ["", "## What remains", ""]
    for s in structure:
        if s.unexplained:
            text = "**unexplained structure**: " + "; ".join(s.where)
        elif s.where:
            text = "too little to matter (under 0.2 % of the variance); seen: " + "; ".join(s.where)
        else:
            text = "no structure: what is left looks like noise"
        lines.append(f"- `{s.output}`: {100 * s.share:.3g} % of its variance left; {text}.")
    lines += ["", "## The extended model", ""]
    for name, path in result["extended"]["config"].items():
        lines.append(f"- `{path}` ({WRITTEN.get(name, name)}): train it with "
                     f"`{result['extended']['train_command'][name]}`")
    candidates = []
    for f in search.rounds[0] if search.rounds else []:
        fitted = (f.describe().split(": ", 1)[1] if ": " in f.describe() else "") or (f.error or "–")
        if f.steps and f.steps[0] < f.steps[1]:
            fitted += f" (stopped after {f.steps[0]} of {f.steps[1]} steps, behind others: gain at least this)"
        if f.too_short and not f.error:
            fitted += " (standard error not judged: too few training stretches)"
        if f.screened:
            fitted += " (first fold only: far behind that fold's best)"
        gain = "–" if f.too_short and f.error else f"{100 * f.gain:+.1f} %"
        candidates.append([f.cause, f.target, fitted, gain])
    lines += ["", "## Every candidate of the first round", "", *md.table(["cause", "on", "fitted", "gain"], candidates)]
    for name in [*result.get("figures", {}).get("time_series", []), *result.get("figures", {}).get("signals", [])]:
        lines += ["", f"![{name}]({name})"]
    return "\n".join(lines) + "\n"
