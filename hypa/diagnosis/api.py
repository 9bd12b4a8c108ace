"""``hypa diagnose model=M``: the diagnosis of any system, from its nominal hypa model.

Steps: (1) the nominal model free-running on the validation records; (2) the named causes
(:func:`hypa.diagnosis.search.name_causes`); (3) what remains and where it lives
(:mod:`hypa.diagnosis.structure`); (4) the extended model written as a hypa model config,
``conf/model/diagnosed.yaml`` (the named causes, fitted) and ``diagnosed_hybrid.yaml`` (the
same with a correction network, HyPA-Net style: the one to train when structure remains
unexplained), with the commands that train them; the gain on the validation records. Writes ``diagnosis.json``,
``diagnosis.md`` and figures into ``out``.
"""

from __future__ import annotations

import dataclasses
import shlex
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import yaml

from hypa.core.metrics import correlation, errors, rms
from hypa.diagnosis.catalogue import Entry
from hypa.diagnosis.coverage import ChannelCoverage, coverage, short_lines
from hypa.diagnosis.edits import frozen, set_free
from hypa.diagnosis.finding import Finding
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.result import (
    CandidateRow,
    DataSummary,
    Diagnosis,
    ErrorShares,
    Extension,
    FindingRow,
    FreeRunMetrics,
    SearchScore,
    SignalAgreement,
    SystemSummary,
    TrainedSummary,
)
from hypa.diagnosis.search import Search, name_causes
from hypa.diagnosis.structure import OutputStructure, analyze_output
from hypa.diagnosis.trained import TrainedExtension
from hypa.models.rollout import Prediction, free_run, free_run_levels, free_run_metrics
from hypa.models.spec import DIAGNOSED, ModelSpec, model_imports, read_model_file, spec_config
from hypa.reporting.figures import time_series


def with_correction(spec: ModelSpec, inputs: Sequence[str]) -> ModelSpec:
    """The model with a correction network on its outputs (HyPA-Net): the physics writes
    ``<output>_physics``, the network reads the inputs and those and adds its correction."""
    from hypa.models.spec import BlockSpec
    from hypa.physics.fmu_block import resignaled

    renamed = {o: f"{o}_physics" for o in spec.outputs}
    blocks = []
    for b in spec.blocks:
        outputs = tuple(renamed.get(s, s) for s in b.outputs)
        observe = ({**b.observe, **{renamed[s]: s for s in b.outputs if s in renamed}}
                   if b.kind in ("physics", "fmu") else {})
        moves = {s: renamed[s] for s in b.outputs if s in renamed}  # an FMU's outputs keep their variables
        rename = resignaled(b.rename, moves) if b.kind == "fmu" else b.rename
        blocks.append(dataclasses.replace(b, outputs=outputs, observe=observe, rename=rename)
                      if outputs != b.outputs else b)
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


def _metrics(runs: Sequence[Prediction], outputs: Sequence[str]) -> dict[str, FreeRunMetrics]:
    """Per output, over the predicted samples of all free runs (:func:`hypa.models.rollout.free_run_metrics`)."""
    return {o: FreeRunMetrics(m["rmse"], m["mse"], m["r2"]) for o, m in free_run_metrics(runs, outputs).items()}


def _change(before: Mapping[str, FreeRunMetrics], after: Mapping[str, FreeRunMetrics],
            outputs: Sequence[str]) -> dict[str, float]:
    """Relative change of each output's validation MSE."""
    return {o: after[o].mse / before[o].mse - 1.0 if before[o].mse > 0 else 0.0 for o in outputs}


def validation_error(metrics: Mapping[str, FreeRunMetrics], outputs: Sequence[str]) -> float:
    """The mean over outputs of 1 - R² of free-run metrics: the report's headline figure."""
    return float(np.mean([1.0 - metrics[o].r2 for o in outputs]))


def _overall(before: Mapping[str, FreeRunMetrics], after: Mapping[str, FreeRunMetrics],
             outputs: Sequence[str]) -> float:
    """Relative change of the mean over outputs of 1 - R² (:func:`validation_error`)."""
    b = validation_error(before, outputs)
    return validation_error(after, outputs) / b - 1.0 if b > 0 else 0.0


def diagnose_system(nominal: ModelSpec, problem: Problem, out: Path, train_overrides: Sequence[str] = (),
                    plot: bool = True, max_causes: int = 8, min_gain: float = 0.15,
                    progress: Callable[[str], None] = print, config_dir: Path | None = None,
                    catalogue: Sequence[Entry] | None = None,
                    train_extension: Callable[[Sequence[str]], TrainedExtension] | None = None) -> Diagnosis:
    """Steps 1-4 for the nominal model on the problem's data; returns the :class:`Diagnosis`
    (written to ``out`` as ``diagnosis.json`` and ``diagnosis.md``).

    ``train_overrides`` select the same data for ``hypa train``; ``config_dir``: the user's own
    config folder (``--config-dir``) that the train command needs too (their dataset YAML).
    ``train_extension(arguments)``: trains the written model with those ``hypa train`` arguments
    and returns its free runs over the validation records and what its networks learned
    (:mod:`hypa.diagnosis.trained`); its gain and those explanations join the report."""
    problem = problem.scaled(frozen(nominal))
    problem.require_data()  # before any step is announced: data too short are refused in one line
    out.mkdir(parents=True, exist_ok=True)
    dm, started = problem.dm, time.perf_counter()
    before, covered = _nominal_runs(nominal, problem, progress)
    fmus = [b.name for b in nominal.blocks if b.kind == "fmu"]
    if fmus:
        progress(f"          {', '.join(fmus)}: an FMU; searched around it (its inputs, outputs and parameters, an "
                 "input of it no channel feeds); causes inside it (its states' curves and limits, a missing mode, "
                 "a parameter's dependence, a channel into its derivatives) are skipped: it hides its equations")
    crossed = len(problem.folds()) > 1
    progress("step 2/4: naming the causes (" + (
        f"each candidate fitted on every other block of all records and scored on the rest, {len(problem.folds())} "
        "folds" if crossed else f"each candidate fitted on {len(dm.records('train'))} training record(s)")
        + "; each round's time is printed as it ends)")
    search = name_causes(nominal, problem, catalogue=catalogue, max_causes=max_causes, min_gain=min_gain,
                         progress=lambda text: progress("          " + text))
    progress(f"          named: {', '.join(f.cause for f in search.named) or 'none'} ({search.seconds:.0f} s)")
    progress("step 3/4: what remains (amplitude, band, correlation with the inputs)")
    after = _runs(problem, search.spec)
    structure = _what_remains(problem, search.spec, after)
    unexplained = [s for s in structure if s.unexplained]
    progress("step 4/4: the extended model as a hypa model, and its gain")
    extended, written = _write_models(out / "conf" / "model", nominal, problem, search)
    train_overrides = with_past(train_overrides, problem, extended)
    commands = {name: train_command(out / "conf", name, train_overrides, name != "diagnosed", config_dir)
                for name in written}
    metrics = {"nominal": _metrics(before, dm.output_names), "extended": _metrics(after, dm.output_names)}
    change = _change(metrics["nominal"], metrics["extended"], dm.output_names)
    # the headline's change: of the table's free runs, as the trained extension's below (the search's
    # own score restarts its free runs every stretch_s: on long records a slightly different figure)
    change["overall"] = _overall(metrics["nominal"], metrics["extended"], dm.output_names)
    error = {m: validation_error(metrics[m], dm.output_names) for m in ("nominal", "extended")}
    trained, runs = None, []
    if train_extension is not None:
        name = "diagnosed_hybrid" if unexplained else "diagnosed"
        progress(f"          training {name} with hypa train (progress below)")
        extension = train_extension(train_arguments(out / "conf", name, train_overrides, name != "diagnosed",
                                                    config_dir))
        runs = list(extension.predictions)
        metrics["trained"] = _metrics(runs, dm.output_names)
        gain = {**_change(metrics["nominal"], metrics["trained"], dm.output_names),
                "overall": _overall(metrics["nominal"], metrics["trained"], dm.output_names)}
        trained = TrainedSummary(name, str(extension.run), metrics["trained"], {"all": gain},
                                 list(extension.explanations))
        error["trained"] = validation_error(metrics["trained"], dm.output_names)
    evidence = problem.evidence()
    named = {f.key for f in search.named}
    first_round = search.rounds[0] if search.rounds else []
    signals = signal_agreement(after)
    result = Diagnosis(
        causes=[f.cause for f in search.named],
        cause=search.named[0].cause if search.named else "none",  # the first named (the schema of old reports)
        estimate=dict(search.named[0].values) if search.named else {},
        system=SystemSummary(nominal.name, list(dm.input_names), list(dm.output_names), list(dm.scheduling_names)),
        named=[FindingRow.from_dict(f.to_dict()) for f in search.named],
        dropped=[FindingRow.from_dict(f.to_dict()) for f in search.dropped],
        candidates=[_candidate(f, search.nominal_score) for f in search.named]
        + [_candidate(f, search.nominal_score) for f in first_round if f.key not in named],
        rounds=[[FindingRow.from_dict(f.to_dict()) for f in r] for r in search.rounds],
        score=SearchScore(search.nominal_score, search.final_score),
        error=ErrorShares(error["nominal"], error["extended"], change["overall"], error.get("trained")),
        metrics=metrics, gain={"all": change}, too_short=list(search.too_short), generic=list(search.generic),
        standin=search.standin, coverage=list(covered), not_covered=short_lines(dm, covered), unexplained=unexplained,
        structure={s.output: s for s in structure},
        extended=Extension({k: str(v) for k, v in written.items()}, commands, signals, trained),
        data=DataSummary(dm.dt, len(dm.records("train")), len(dm.records("val")), search.folds, search.blocks,
                         evidence.seconds, evidence.windows, evidence.stretches, problem.time_scales.stretch_s,
                         problem.time_scales.to_dict()),
        seconds=time.perf_counter() - started,
    )
    if plot:
        result.figures = _figures(out, before, after, dm, runs, list(signals))
    result.to_json(out / "diagnosis.json")
    units = {n: (c.display_unit, c.display_factor) for n, c in dm.channels.items()}
    (out / "diagnosis.md").write_text(result.markdown(units, min_gain))
    return result


def _nominal_runs(nominal: ModelSpec, problem: Problem,
                  progress: Callable[[str], None]) -> tuple[list[Prediction], list[ChannelCoverage]]:
    """Step 1: the nominal model's free runs over the validation records, with a warning for a level
    no cause can explain and a line for validation data that cover a part of the operating range;
    returns the runs and the coverage."""
    dm = problem.dm
    progress(f"step 1/4: the nominal model {nominal.name!r} free-running on {len(dm.records('val'))} "
             "validation record(s)")
    before = _runs(problem, frozen(nominal))
    units = {n: dm.channels[n].unit for n in dm.output_names}
    for line in free_run_levels(before, dm.output_names, problem.build(frozen(nominal)), units):
        progress(f"          warning: {line}")  # a level no cause can explain: a state the data do not start
    covered, crossed = coverage(dm), len(problem.folds()) > 1
    for line in short_lines(dm, covered):
        progress(f"          validation data: {line}: "
                 + ("the validation figures cover a part of the operating range" if crossed else
                    "candidates are judged on a part of the operating range"))
    return before, covered


def _what_remains(problem: Problem, spec: ModelSpec, after: Sequence[Prediction]) -> list[OutputStructure]:
    """Step 3: each output's residual after the named causes (amplitude, band, correlation with every
    measured channel but the outputs; those the extended model does not read are named as such)."""
    dm = problem.dm
    used = {s for b in spec.blocks for s in (*b.inputs, *b.scheduling.values())}
    held = {r.name: r for r in dm.records("val")}
    channels = [c for c in dm.channels if c not in dm.output_names
                and all(c in r.inputs or c in held[r.record].channels for r in after)]
    return [analyze_output(o, dm.channels[o].unit, [r.measured[o][r.first:] for r in after],
                           [r.predicted[o][r.first:] for r in after],
                           {c: [r.inputs[c][r.first:] if c in r.inputs else _record(dm, r, c) for r in after]
                            for c in channels}, problem.time_scales, unused=set(channels) - used)
            for o in dm.output_names]


def _write_models(conf: Path, nominal: ModelSpec, problem: Problem,
                  search: Search) -> tuple[ModelSpec, dict[str, Path]]:
    """Step 4: the extended model (``diagnosed``), its hybrid with a correction network
    (``diagnosed_hybrid``) and, where a cause lets a network learn a block, that model
    (``diagnosed_learned``), written into ``conf`` as hypa models; returns the extended model and
    the files by name."""
    conf.mkdir(parents=True, exist_ok=True)
    # the written models keep the hold they were diagnosed with (their fitted values belong to it)
    extended = dataclasses.replace(refittable(search.spec, nominal, search.named), name="diagnosed",
                                   hold=nominal.hold or problem.hold)
    # the hybrid is written whatever remains (the benchmark's hybrid row trains it); it is the one to
    # train when the residual analysis leaves something unexplained
    hybrid = dataclasses.replace(with_correction(extended, problem.dm.input_names), name="diagnosed_hybrid")
    written = {"diagnosed": _write(conf / "diagnosed.yaml", extended, search.named),
               "diagnosed_hybrid": _write(conf / "diagnosed_hybrid.yaml", hybrid, search.named)}
    learned = [b for f in search.named if f.candidate for b in f.candidate.learn]
    if learned:
        written["diagnosed_learned"] = _write(conf / "diagnosed_learned.yaml",
                                              with_networks(extended, learned), search.named)
    return extended, written


def _record(dm, run: Prediction, channel: str) -> np.ndarray:
    record = next(r for r in dm.records("val") if r.name == run.record)
    return record[channel][run.first:]


def _candidate(f: Finding, nominal_score: float) -> CandidateRow:
    """A row of ``candidates``: cause, score = share of the nominal error it explains, estimate
    (fitted values [SI]), evidence (one line in units)."""
    return CandidateRow(f.cause, f.target, f.gain, f.values, f.describe(), f.alternatives)


def _write(path: Path, spec: ModelSpec, named: Sequence[Finding]) -> Path:
    header = ["# @package model", "# Written by hypa diagnose: the nominal model extended by the named causes:"]
    header += [f"#   {f.describe()}" for f in named] or ["#   (none named)"]
    path.write_text("\n".join(header) + "\n" + yaml.safe_dump(spec_config(spec), sort_keys=False))
    return path


def with_past(overrides: Sequence[str], problem: Problem, spec: ModelSpec) -> list[str]:
    """``overrides`` with ``data.past`` raised where the extended model estimates states (a cause
    that added some, e.g. the slips of tire relaxation) from fewer past samples than it needs:
    :meth:`~hypa.models.ComposedModel.suggested_past`."""
    model = problem.build(spec)
    needed = model.past_needed()
    if not needed or problem.dm.past >= max(needed.values()):
        return list(overrides)
    past = model.suggested_past()
    return [*(o for o in overrides if o.split("=", 1)[0].lstrip("+~") != "data.past"), f"data.past={past}"]


def train_arguments(written: Path, model: str, overrides: Sequence[str], with_ann: bool,
                    config_dir: Path | None = None) -> list[str]:
    """``hypa train`` arguments that train a written model on the same data: the model is
    read as data (``model_file=``, through the model schema only), so following the command from a
    diagnosis folder someone sent runs none of its YAML as configuration; a user's own
    ``--config-dir`` (their dataset) still applies. The user's own systems that the model names
    are trusted by name (``trust=[...]``): they came from the user's own configuration."""
    path = written / "model" / f"{model}.yaml"
    imports = sorted(set(model_imports(read_model_file(path, ("*",))).values())) if path.is_file() else []
    return [*(["--config-dir", str(config_dir)] if config_dir else []), f"model_file={path}",
            *([f"trust=[{','.join(imports)}]"] if imports else []), *overrides, *(["ann=lstm"] if with_ann else [])]


def train_command(written: Path, model: str, overrides: Sequence[str], with_ann: bool,
                  config_dir: Path | None = None) -> str:
    """The shell command of :func:`train_arguments` (``python -m hypa train ...``: it runs with any
    environment's Python, as the launched commands' lines do)."""
    return " ".join(["python -m hypa train",
                     *(shlex.quote(w) for w in train_arguments(written, model, overrides, with_ann, config_dir))])


def signal_agreement(runs: Sequence[Prediction]) -> dict[str, SignalAgreement]:
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
        out[channel] = SignalAgreement(correlation(m, r), errors(r, m)["rmse"], rms(m))
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

