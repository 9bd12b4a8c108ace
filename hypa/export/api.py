"""Exporting a trained run: the one-step model, its reference record, ``export.json``, and the checks.

    model.onnx          the step (``hypa.export.step``): state, u [SI] -> next_state, y [SI] (every format)
    reference.csv       the first validation record's time, inputs, scheduling signals and hypa's free run
    export.json         names, units, dt, the state layout, the initial state, the checks' figures
    model.fmu           format=fmu: the step as an FMI 2.0 co-simulation FMU (``hypa.export.fmu``)
    native.fmu          format=c: the step compiled to C99 (``hypa.export.ccode``) as a source-code FMI 2.0
                        FMU, co-simulation and model exchange, with its linux64 binary (``hypa.export.native``)
    reference_float64.csv  format=c: hypa's free run of the reference record in float64, the C step's reference
    statespace.mat      format=statespace, physics-only models: A, B, C, D, Ad, Bd, Cd, Dd, Ts
    statespace.json     the same, for ``load_statespace`` (python-control) (``hypa.export.statespace``)

The export reports success only when each format, run step by step over the reference record
from the initial state (onnxruntime; fmpy; the discrete state space in numpy), reproduces hypa's
free run to ``tolerance`` of each output's σ. The C step computes in float64 and is checked
against hypa's free run in float64 (the float32 run's own rounding is the larger difference).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import platform
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from hypa.core.errors import one_line
from hypa.export.blocks import ExportError, PhysicsStep
from hypa.export.ccode import CStep, c_step
from hypa.export.onnx import OPSET, Check, check_onnx, compare, export_onnx
from hypa.export.reference import Reference, reference_run
from hypa.export.step import ModelStep, scheduled_squarings

if TYPE_CHECKING:
    from hypa.data import HypaDataModule
    from hypa.evaluation.runs import TrainedRun

FORMATS = ("onnx", "fmu", "c", "statespace", "all")
FORMAT_VERSION = 1
STIFF_SQUARINGS = 10  # a scheduled hold this many squarings deep amplifies rounding ~1000 times


@dataclass
class Export:
    """What an export wrote (``files``: name -> path) and its check."""

    folder: Path
    files: dict[str, Path]
    check: Check  # the ONNX step's
    state_size: int
    checks: dict[str, Check] = dataclasses.field(default_factory=dict)  # format -> its check, ONNX's included
    skipped: dict[str, str] = dataclasses.field(default_factory=dict)  # format -> why it was not written
    native: dict = dataclasses.field(default_factory=dict)  # format=c: the C step's figures (export.json's "c")

    def sizes(self) -> dict[str, int]:
        return {name: path.stat().st_size for name, path in self.files.items()}


def formats_to_build(name: str) -> tuple[str, ...]:
    """The formats ``format=name`` asks for; an unknown one is one line."""
    if name not in FORMATS:
        raise ExportError(f"format={name} is not one of {', '.join(FORMATS)}")
    return tuple(f for f in FORMATS[:-1] if name in (f, "all"))


def build_step(run: TrainedRun, dm: HypaDataModule, record_index: int = 0,
               dtype: torch.dtype = torch.float32) -> tuple[ModelStep, Reference]:
    """The step of ``run``'s model and its reference: the ``record_index``-th validation record, both in
    ``dtype`` (float64: a copy of the model, the run's own stays as it is)."""
    model = run.module.model.eval().float() if dtype == torch.float32 else \
        copy.deepcopy(run.module.model).eval().to(dtype)
    records = dm.records("val")
    if not records:
        raise ExportError("the run's data have no validation record to check the export against")
    if not 0 <= record_index < len(records):
        raise ExportError(f"record={record_index}: the validation split has records 0..{len(records) - 1}")
    record = records[record_index]
    units = {n: c.unit for n, c in dm.channels.items()}
    schedule = torch.as_tensor(record.stack(dm.scheduling_names), dtype=torch.float32) if dm.scheduling_names else None
    squarings = scheduled_squarings(model, schedule) if schedule is not None else {}
    step = ModelStep(model, units, squarings, dtype).eval()
    return step, reference_run(step, dm, record)


def export_run(run: TrainedRun, dm: HypaDataModule, out: Path, format: str = "onnx", record_index: int = 0,
               tolerance: float = 1e-5) -> Export:
    """Export ``run`` into ``out`` (see the module's docstring); ``ExportError`` when it cannot or a check fails.

    ``format=all`` writes every format the model allows and names the ones skipped (``Export.skipped``)."""
    from hypa.export.statespace import refusal

    wanted = formats_to_build(format)
    skipped = {}
    why = refusal(run.module.model) if "statespace" in wanted else None
    if why and format == "statespace":
        raise ExportError(f"format=statespace: {why}")
    if why:
        skipped["statespace"] = why
        wanted = tuple(f for f in wanted if f != "statespace")
    out.mkdir(parents=True, exist_ok=True)
    step, reference = build_step(run, dm, record_index)
    native = None
    if "c" in wanted:  # compiled first: a model without a C form is refused (or skipped) before anything is written
        try:
            native = _compile_c(run, dm, record_index, out)
        except ExportError as error:
            if format == "c":
                raise
            skipped["c"] = one_line(error)
            wanted = tuple(f for f in wanted if f != "c")
    files = {"model.onnx": export_onnx(step, out / "model.onnx", reference),
             "reference.csv": reference.write_csv(out / "reference.csv")}
    checks = {"onnx": check_onnx(files["model.onnx"], reference, tolerance)}
    description = describe(run, dm, step, reference, checks["onnx"])
    if checks["onnx"].passed:
        if "statespace" in wanted:
            checks["statespace"] = _statespace(step, dm, reference, out, files, tolerance)
        if "fmu" in wanted:
            checks["fmu"] = _fmu(step, reference, description, out, files, tolerance)
        if native is not None:
            checks["c"], description["c"] = _native(native, reference, description, out, files, tolerance)
    description["checks"] = {name: check.as_dict() for name, check in checks.items()}
    description["skipped"] = skipped
    description["files"] = sorted({*files, "export.json"})
    files["export.json"] = out / "export.json"
    files["export.json"].write_text(json.dumps(description, indent=2) + "\n")
    for name, check in checks.items():
        if not check.passed:
            _refuse(name, check, step, reference, files["export.json"])
    return Export(out, files, checks["onnx"], step.state_size, checks, skipped, description.get("c", {}))


def _refuse(name: str, check: Check, step: ModelStep, reference: Reference, description: Path) -> None:
    worst = max(check.outputs, key=lambda n: check.outputs[n].relative)
    stiff = [f"{block} needs {form.squarings} squarings of its hold per step, stiff enough that float32 rounding, "
             "hypa's own free run's included, is amplified 2^squarings times" for block, form in step.forms.items()
             if isinstance(form, PhysicsStep) and form.squarings >= STIFF_SQUARINGS]
    what = {"onnx": "the ONNX step", "fmu": "the FMU (fmpy)", "c": "the C FMU (fmpy)",
            "statespace": "the discrete state space"}[name]
    raise ExportError(f"{what} does not reproduce hypa's free run of {reference.record}: {worst} is off by "
                      f"{check.outputs[worst].relative:.3g} of its σ (tolerance {check.tolerance:g}); "
                      + (f"{'; '.join(stiff)}; " if stiff else "") + f"see {description}")


def _statespace(step: ModelStep, dm: HypaDataModule, reference: Reference, out: Path, files: dict[str, Path],
                tolerance: float) -> Check:
    """Write ``statespace.mat`` and ``statespace.json`` and check the discrete system against hypa's free run."""
    import time

    from hypa.export.statespace import discrete_initial_state, linear_model, write_statespace

    system = linear_model(step.model, {n: c.unit for n, c in dm.channels.items()}, dm.dt)
    x0 = discrete_initial_state(step.model, reference)
    files["statespace.mat"], files["statespace.json"] = write_statespace(system, x0, out)
    started = time.perf_counter()
    y = system.simulate(x0, reference.u[reference.first :])
    seconds = (time.perf_counter() - started) / max(len(y), 1)
    return compare(y, reference, tolerance, seconds, "state space (numpy)")


def _fmu(step: ModelStep, reference: Reference, description: dict, out: Path, files: dict[str, Path],
         tolerance: float) -> Check:
    """Write ``model.fmu`` and check it with fmpy against hypa's free run."""
    from hypa.export.fmu import build_fmu, run_fmu

    model = step.model
    parameters = {n: (v, model.parameters_.specs[n].unit) for n, v in model.parameters_.as_floats().items()}
    files["model.fmu"] = build_fmu(files["model.onnx"], out / "model.fmu", description, reference, step.slots,
                                   parameters)
    y, seconds = run_fmu(files["model.fmu"], reference)
    return compare(y, reference, tolerance, seconds, "FMU (fmpy)")


@dataclass(frozen=True)
class _Native:
    """The C step of a run, compiled from its float64 step, and that step's reference (float64)."""

    code: CStep
    step: ModelStep
    reference: Reference


def _compile_c(run: TrainedRun, dm: HypaDataModule, record_index: int, out: Path) -> _Native:
    """The float64 step of ``run`` as C (``hypa.export.ccode``; ``ExportError`` where it has no C form or the
    machine no C compiler)."""
    import tempfile

    from hypa.export.native import c_compiler, platform_folder

    platform_folder(), c_compiler()

    step, reference = build_step(run, dm, record_index, torch.float64)
    with tempfile.TemporaryDirectory(dir=out) as folder:
        code = c_step(export_onnx(step, Path(folder) / "step64.onnx", reference), block_labels(step.model))
    return _Native(code, step, reference)


def block_labels(model) -> dict[str, str]:
    """What each block of a ``ComposedModel`` is, for one-line refusals: 'LSTMBlock network', 'physics block'."""
    return {b.name: f"{type(model.blocks[b.name]).__name__} network" if b.kind == "ann" else f"{b.kind} block"
            for b in model.order}


def _native(native: _Native, reference32: Reference, description: dict, out: Path, files: dict[str, Path],
            tolerance: float) -> tuple[Check, dict]:
    """Write ``native.fmu`` and ``reference_float64.csv``; check the FMU with fmpy (co-simulation and model
    exchange) against hypa's float64 free run. Its check, and the C step's figures for ``export.json``."""
    from hypa.export.fmu import run_fmu
    from hypa.export.native import build_native_fmu, compile_check, run_native_me, time_c_step, validate

    reference, step = native.reference, native.step
    model = step.model
    parameters = {n: (v, model.parameters_.specs[n].unit) for n, v in model.parameters_.as_floats().items()}
    files["reference_float64.csv"] = reference.write_csv(out / "reference_float64.csv")
    path = build_native_fmu(native.code.source, out / "native.fmu", {**description, "initial_state":
                            reference.initial_state.tolist()}, reference, step.slots, parameters)
    files["native.fmu"] = path
    validate(path)
    compile_check(path)
    y, seconds = run_fmu(path, reference)
    check = compare(y, reference, tolerance, seconds, "C FMU (fmpy)", "hypa float64")
    y_me, seconds_me = run_native_me(path, reference)
    exchanged = compare(y_me, reference, tolerance, seconds_me, "C FMU model exchange (fmpy)", "hypa float64")
    float32 = compare(y, reference32, tolerance, seconds)
    rows = reference.u[reference.first :]
    figures = {"file": "native.fmu", "dtype": "float64", "reference": "reference_float64.csv",
               "statements": native.code.statements, "bare_seconds_per_step": time_c_step(native.code.source,
                                                                                   reference.initial_state, rows),
               "initial_state": reference.initial_state.tolist(),
               "model_exchange": exchanged.as_dict(),
               "float32_free_run": {n: c.relative for n, c in float32.outputs.items()}}
    worse = exchanged if not exchanged.passed else check
    return worse, figures


def describe(run: TrainedRun, dm: HypaDataModule, step: ModelStep, reference: Reference, check: Check) -> dict:
    """The contents of ``export.json``."""
    import onnxruntime

    units = {n: c.unit for n, c in dm.channels.items()}
    model = step.model
    signal = lambda name, role: {"name": name, "unit": units.get(name, ""), "role": role}  # noqa: E731
    return {
        "format_version": FORMAT_VERSION,
        "model": model.spec.name,
        "run": str(run.folder),
        "checkpoint": str(run.checkpoint),
        "dt": dm.dt,
        "hold": model.hold,
        "onnx": {"file": "model.onnx", "opset": OPSET, "dtype": "float32",
                 "inputs": {"state": [step.state_size], "u": [len(reference.input_names)]},
                 "outputs": {"next_state": [step.state_size], "y": [len(reference.output_names)]}},
        "inputs": [signal(n, "input") for n in model.input_names]
                  + [signal(n, "scheduling") for n in model.scheduling_names],
        "outputs": [signal(n, "output") for n in reference.output_names],
        "state": [{"index": i, "block": s.block, "name": s.name, "kind": s.kind, "unit": s.unit}
                  for i, s in enumerate(step.slots)],
        "step": ("y[k], state[k+1] = step(state[k], u[k]): u[k] the inputs and scheduling signals of sample k, y[k] "
                 "the outputs hypa predicts at sample k; the first step is sample first_sample, from initial_state"),
        "initial_state": reference.initial_state.tolist(),
        "reference": {"file": "reference.csv", "record": reference.record, "samples": len(reference.time),
                      "first_sample": reference.first, "first_time": float(reference.time[reference.first]),
                      "scheduling_range": {n: [float(reference.u[:, i].min()), float(reference.u[:, i].max())]
                                           for i, n in enumerate(reference.input_names)
                                           if n in model.scheduling_names}},
        "scheduled_squarings": {name: {"squarings": form.squarings, "exact_while": "the 1-norm of the block's hold "
                                       f"generator stays <= {0.5 * 2 ** form.squarings:g} (4x the largest seen)"}
                                for name, form in step.forms.items() if isinstance(form, PhysicsStep)
                                and form.block.scheduled},
        "check": check.as_dict(),
        "versions": {"torch": torch.__version__, "onnxruntime": onnxruntime.__version__,
                     "python": platform.python_version()},
    }
