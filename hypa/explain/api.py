"""Explain the learned blocks of a trained run: ``hypa explain run=RUN [block=NAME]``.

The trained model is driven (free run, :func:`hypa.models.rollout.free_run`) over the run's
training and validation records; each output of an ANN block is the explained signal, the
block's inputs the regressors, and by default the other measured outputs and the scheduling
channels the extra signals (as the model itself simulates them). The ladder of forms
(:func:`hypa.explain.explain`) is fitted on the training records and scored on the validation
records. Where the records measure the block's output (an evaluation-only channel of the same
name), the learned block, the explained form and the measurement are
compared on the validation records.

Writes (:mod:`hypa.explain.result`) ``explanation.md``, ``explanation.json`` and per explained signal three figures (the
signal over time, the frequency response, the static curve) into ``out``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from hypa.core.errors import UserError
from hypa.core.metrics import correlation, errors, rms
from hypa.data import HypaDataModule
from hypa.evaluation.runs import TrainedRun
from hypa.explain.figures import write_figures
from hypa.explain.forms import explain, frequency_response, predict
from hypa.explain.problem import (
    FIT_SPLIT,
    PAIRS,
    SCORE_SPLIT,
    BlockExplanation,
    ExplainedSignal,
    Settings,
    gain_unit,
)
from hypa.explain.replace import replace_and_score, validation_errors, writable_form
from hypa.explain.result import write_json, write_report
from hypa.explain.signals import Recording
from hypa.models import ComposedModel
from hypa.models.rollout import Prediction, free_run
from hypa.models.spec import DIAGNOSED, BlockSpec, ModelSpec

# --- which blocks, which signals --------------------------------------------------------------

def ann_blocks(spec: ModelSpec) -> list[BlockSpec]:
    """The model's network blocks, in the order of its configuration."""
    return [b for b in spec.blocks if b.kind == "ann"]


def select_blocks(spec: ModelSpec, name: str | None) -> list[BlockSpec]:
    """The ANN block ``name`` (all ANN blocks for None); one-line errors for a wrong name or a model
    without networks."""
    blocks = ann_blocks(spec)
    if not blocks:
        raise UserError(f"model {spec.name!r} has no ANN block: nothing learned to explain "
                        f"(its blocks: {', '.join(b.name for b in spec.blocks)})")
    if name is None:
        return blocks
    names = [b.name for b in blocks]
    if name in names:
        return [blocks[names.index(name)]]
    what = "is not an ANN block" if name in [b.name for b in spec.blocks] else "does not exist"
    raise UserError(f"block {name!r} {what} in model {spec.name!r}; its ANN blocks: {', '.join(names)}")


def signal_unit(name: str, dm: HypaDataModule, spec: ModelSpec, depth: int = 0) -> str:
    """SI unit of a signal: a measured channel's, else that of the channel its block scales it as
    (``scale_as``, ``residual_of``), else that of the output a network adds to it (it is in a
    ``residual_of``), else ``"-"``."""
    if name in dm.channels:
        return dm.channels[name].unit
    for block in spec.blocks:
        if name in block.outputs and depth < 8:
            like = block.scale_as or block.residual_of
            if like:
                i = block.outputs.index(name)
                return signal_unit(like[min(i, len(like) - 1)], dm, spec, depth + 1)
    for block in spec.blocks:  # physics that a network corrects: the unit of the corrected output
        if name in block.residual_of and depth < 8:
            i = block.residual_of.index(name)
            return signal_unit(block.outputs[min(i, len(block.outputs) - 1)], dm, spec, depth + 1)
    return "-"


def problems(spec: ModelSpec, dm: HypaDataModule, blocks: Sequence[BlockSpec],
             extra: Sequence[str] | None = None) -> list[ExplainedSignal]:
    """One problem per output of each block. ``extra`` None: the measured outputs and scheduling
    channels that are neither the block's inputs nor its outputs."""
    out = []
    for block in blocks:
        own = {*block.inputs, *block.outputs}
        chosen = [n for n in (*dm.output_names, *dm.scheduling_names) if n not in own] if extra is None else \
            [n for n in extra if n not in own]
        for i, output in enumerate(block.outputs):
            units = {n: signal_unit(n, dm, spec) for n in (output, *block.inputs, *chosen)}
            corrects = None
            if block.residual_of:
                corrects = (output, block.residual_of[min(i, len(block.residual_of) - 1)])
                units[f"{output}_correction"] = units[output]
                output = f"{output}_correction"
            measured = None if corrects else measuring_channel(output, dm)
            if measured and units[output] == "-":
                units[output] = dm.channels[measured].unit
            for like in block.scale_as:  # scaled like the output: the same quantity, the same unit
                if units.get(like) == "-":
                    units[like] = units[output]
            out.append(ExplainedSignal(block.name, output, tuple(block.inputs), tuple(chosen), units, corrects,
                                       measured))
    return out


def measuring_channel(signal: str, dm: HypaDataModule) -> str | None:
    """The channel that measures a model's signal: its own name, or for what a diagnosis inserted
    (``diagnosed_<channel>``, e.g. ``diagnosed_rear_wheel_angle``) that channel; None if neither."""
    for name in (signal, signal.removeprefix(DIAGNOSED)):
        if name in dm.channels:
            return name
    return None


# --- the model's signals over the records -------------------------------------------------------

def free_runs(model: ComposedModel, dm: HypaDataModule, split: str) -> list[Prediction]:
    """The model over every record of a split, its scheduling channels added to the inputs."""
    runs = []
    for record in dm.records(split):
        prediction = free_run(model, dm, record)
        scheduling = {n: np.asarray(record[n], dtype=float) for n in dm.scheduling_names}
        runs.append(replace(prediction, inputs={**prediction.inputs, **scheduling}))
    return runs


def recordings(predictions: Sequence[Prediction], problem: ExplainedSignal) -> list[Recording]:
    """The problem's signals of each free run, on the stretch where all of them exist; the
    measurement of the output (where the record has one) as ``measured:<output>``. A correction
    is the total output less the physics signal it corrects (nothing measures it)."""
    out = []
    for prediction in predictions:
        if problem.corrects:
            total, physics = problem.corrects
            names = [*dict.fromkeys((total, physics, *problem.inputs, *problem.extra))]
            recording = Recording.from_prediction(prediction, names)
            signals = {n: recording[n] for n in problem.names[1:]}
            signals[problem.output] = recording[total] - recording[physics]
            out.append(Recording(recording.name, signals, recording.start))
            continue
        recording = Recording.from_prediction(prediction, list(problem.names))
        truth = prediction.measured.get(problem.measured) if problem.measured else None
        if truth is not None:
            n = len(recording[problem.output])
            signals = {**recording.signals, f"measured:{problem.output}": truth[recording.start: recording.start + n]}
            recording = Recording(recording.name, signals, recording.start)
        out.append(recording)
    return out


def compare(reference: np.ndarray, other: np.ndarray) -> dict[str, float]:
    """Correlation, RMS of the difference [signal unit] and the share of the reference's variance
    that ``other`` explains (1 - Σ(ref - other)² / Σ(ref - mean)², R²)."""
    ok = np.isfinite(reference) & np.isfinite(other)  # each signal where the model has it
    e = errors(other[ok], reference[ok])
    return {"corr": correlation(reference[ok], other[ok]), "rms": e["rmse"], "share": e["r2"],
            "samples": int(ok.sum())}


# --- the explanation ----------------------------------------------------------------------------

def explain_problem(problem: ExplainedSignal, train: Sequence[Prediction], val: Sequence[Prediction], dt: float,
                    settings: Settings = Settings()) -> tuple[BlockExplanation, list[Recording], list[Recording]]:
    """The ladder fitted on ``train``, scored on ``val``, and the comparison with the measurement."""
    rec_train, rec_val = recordings(train, problem), recordings(val, problem)
    try:
        explanation = explain(rec_train, rec_val, dt, problem.output, problem.inputs, problem.extra, problem.units,
                              penalty=settings.penalty, margin=settings.margin, max_lag=settings.max_lag,
                              max_delay=settings.max_delay)
    except UserError as error:
        raise UserError(f"block {problem.block!r}: {error}") from error
    comparison = None
    truth = f"measured:{problem.output}"
    if rec_val and all(truth in r.signals for r in rec_val):
        explained = predict(explanation, rec_val)
        series = {"measured": np.concatenate([r[truth] for r in rec_val]),
                  "learned": np.concatenate([r[problem.output] for r in rec_val]),
                  "explained": np.concatenate(explained)}
        comparison = {pair: compare(series[a], series[b]) for pair, (a, b) in PAIRS.items()}
        comparison["measured_rms"] = {"rms": rms(series["measured"])}
    return BlockExplanation(problem, explanation, comparison), rec_train, rec_val


def explain_run(run: TrainedRun, dm: HypaDataModule, out: Path, block: str | None = None,
                settings: Settings = Settings(), progress: Callable[[str], None] = lambda text: None,
                baseline: TrainedRun | None = None) -> list[BlockExplanation]:
    """Explain the ANN blocks of a run (or the one named ``block``); writes the report, the json and
    the figures. Each network is also replaced by its explanation and the validation error of that
    model compared with the run's (and with ``baseline``'s, another run on the same data)."""
    model = run.module.model
    spec = model.spec
    chosen = problems(spec, dm, select_blocks(spec, block), settings.extra)
    missing = sorted({n for p in chosen for n in p.extra if n not in (*dm.output_names, *dm.scheduling_names,
                                                                     *dm.input_names) and n not in _signal_names(spec)})
    if missing:
        raise UserError(f"extra signals {missing} are neither measured channels nor signals of model {spec.name!r}")
    progress(f"driving {run.label} over the {FIT_SPLIT} and {SCORE_SPLIT} records")
    train, val = free_runs(model, dm, FIT_SPLIT), free_runs(model, dm, SCORE_SPLIT)
    if not train or not val:
        raise UserError(f"the run's data have {len(train)} {FIT_SPLIT} and {len(val)} {SCORE_SPLIT} records; "
                        "the explanation needs both")
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for problem in chosen:
        progress(f"fitting the ladder to {problem.block} ({', '.join(problem.inputs)} -> {problem.output})")
        started = time.perf_counter()
        result, rec_train, rec_val = explain_problem(problem, train, val, dm.dt, settings)
        result.seconds = time.perf_counter() - started
        result.notes += hold_note(model, problem.block, dm.dt)
        replace_block(result, run, dm, val, out, progress, baseline)
        if settings.plot:
            result.figures, notes = write_figures(result, rec_train, rec_val, val, dm, out)
            result.notes += notes
        results.append(result)
    write_json(run, results, out / "explanation.json")
    write_report(run, results, out / "explanation.md")
    return results


def hold_note(model: ComposedModel, block: str, dt: float) -> list[str]:
    """A warning where a network feeds physics that holds its inputs constant between samples
    (``zoh``): the physics then sees every input half a sample late, and a network beside a
    physics input path learns to make up for it (measured on a test bench whose rear-steering
    law is a known ratio and lag: with ``zoh`` V1's explained lag read 120 ms for 70 ms, with
    ``foh`` 72 ms)."""
    outputs = next(b.outputs for b in model.spec.blocks if b.name == block)
    feeds = [b.name for b in model.spec.blocks if b.kind == "physics" and set(b.inputs) & set(outputs)]
    if model.hold != "zoh" or not feeds:
        return []
    return [(f"the run's physics ({', '.join(feeds)}) holds its inputs constant between samples (zero-order "
            f"hold): it sees them {1000 * dt / 2:.3g} ms late, and part of what {block} learned may make up "
            "for that; train with physics.hold=foh to explain the law itself")]


def replace_block(result: BlockExplanation, run: TrainedRun, dm: HypaDataModule, val: Sequence[Prediction],
                  out: Path, progress: Callable[[str], None] = lambda text: None,
                  baseline: TrainedRun | None = None) -> None:
    """The network replaced by its explanation (:mod:`hypa.explain.replace`): the model YAML and
    the validation errors beside the trained model's, into ``result.replacement`` (or a note why not)."""
    p, e = result.problem, result.explanation
    block = next(b for b in run.module.model.spec.blocks if b.name == p.block)
    fitted, note = writable_form(e.forms, e.chosen, block, p.inputs, p.corrects)
    if note:
        result.notes.append(("not replaced: " if fitted is None else "") + note)
    if fitted is None:
        return
    progress(f"replacing {p.block} by its {fitted.form.name} and free-running the validation records")
    result.replacement = replace_and_score(run, dm, p.block, fitted, val, out)
    if baseline is not None:
        runs = [free_run(baseline.module.model, dm, record) for record in dm.records(SCORE_SPLIT)]
        result.replacement["baseline"] = {"run": str(baseline.folder), "label": baseline.label,
                                          **validation_errors(runs, dm.output_names)}


def _signal_names(spec: ModelSpec) -> set[str]:
    return {n for b in spec.blocks for n in (*b.inputs, *b.outputs)}


__all__ = [
    "FIT_SPLIT",
    "PAIRS",
    "SCORE_SPLIT",
    "BlockExplanation",
    "ExplainedSignal",
    "Settings",
    "ann_blocks",
    "compare",
    "explain_problem",
    "explain_run",
    "free_runs",
    "frequency_response",
    "gain_unit",
    "problems",
    "recordings",
    "select_blocks",
    "signal_unit",
]


def __getattr__(name: str) -> Any:
    """``Problem``, the name of :class:`ExplainedSignal` before it (one release, with a warning)."""
    if name == "Problem":
        import warnings

        warnings.warn("hypa.explain's Problem is ExplainedSignal now (the diagnosis's Problem is another thing)",
                      DeprecationWarning, stacklevel=2)
        return ExplainedSignal
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
