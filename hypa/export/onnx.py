"""The one-step model as ONNX (``torch.onnx``) and the check that onnxruntime reproduces hypa's free run with it.

Two exporters: torch's TorchScript-based one (``dynamo=False``) traces the step, a fixed sequence of
small tensor operations, in well under a second; where it lacks an operation (Mamba's
``rms_norm``) the dynamo exporter (``torch.export``, needs ``onnxscript``) takes over, which gives
the same numbers in several seconds.
"""

from __future__ import annotations

import contextlib
import io
import logging
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from hypa.core.errors import one_line
from hypa.export.blocks import ExportError
from hypa.export.reference import Reference
from hypa.export.step import ModelStep

OPSET = 17


def export_onnx(step: ModelStep, path: Path, reference: Reference) -> Path:
    """Write ``step`` as ONNX: inputs ``state`` (r,), ``u`` (m + q,), outputs ``next_state`` (r,),
    ``y`` (p,), in the step's dtype (float32; float64 for the C step)."""
    state = torch.as_tensor(reference.initial_state, dtype=step.dtype)
    u = torch.as_tensor(reference.u[reference.first], dtype=step.dtype)
    errors = []
    for dynamo in (False, True):
        logging.disable(logging.WARNING)  # the dynamo exporter's notes on operators of packages not installed
        try:
            with warnings.catch_warnings(), torch.no_grad(), contextlib.redirect_stdout(io.StringIO()):
                warnings.simplefilter("ignore")  # the exporters' deprecation notices, tracer warnings, progress
                torch.onnx.export(step.eval(), (state, u), str(path), input_names=["state", "u"],
                                  output_names=["next_state", "y"], opset_version=OPSET if not dynamo else None,
                                  dynamo=dynamo, **({"external_data": False} if dynamo else {}))  # one file
            return path
        except ExportError:
            raise
        except Exception as error:  # noqa: BLE001 -- the exporter's own: an operation without an ONNX form, onnxscript missing
            errors.append(f"{'dynamo' if dynamo else 'TorchScript'} exporter: {one_line(error)[:200]}")
        finally:
            logging.disable(logging.NOTSET)
    raise ExportError(f"torch.onnx cannot export the one-step model of {step.model.spec.name}: {'; '.join(errors)}")


def session(path: Path):
    """An onnxruntime session on the CPU, one thread (the step's matrices are tiny)."""
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def run_onnx(path: Path, state: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The ONNX step over u (S, m + q) [SI] from ``state`` (r,): outputs (S, p), the final state and
    the seconds per step (onnxruntime's call included)."""
    run = session(path)
    x, ys = np.asarray(state, dtype=np.float32), []
    rows = np.asarray(u, dtype=np.float32)
    started = time.perf_counter()
    for row in rows:
        x, y = run.run(["next_state", "y"], {"state": x, "u": row})
        ys.append(y)
    seconds = (time.perf_counter() - started) / max(len(rows), 1)
    return np.array(ys, dtype=float).reshape(len(rows), -1), x, seconds


@dataclass(frozen=True)
class OutputCheck:
    """One output: the largest |ONNX - hypa| [SI] over the predicted samples and the output's σ [SI]."""

    max_error: float
    std: float

    @property
    def relative(self) -> float:
        return self.max_error / self.std


@dataclass(frozen=True)
class Check:
    """The ONNX step against hypa's free run of the reference record."""

    outputs: dict[str, OutputCheck]
    tolerance: float  # of each output's σ
    samples: int
    onnx_seconds_per_step: float  # the engine's (``engine``), one step
    hypa_seconds_per_sample: float
    engine: str = "ONNX"
    against: str = "hypa"  # the free run it is checked against: "hypa", or "hypa float64" for the C step

    @property
    def passed(self) -> bool:
        return all(np.isfinite(c.relative) and c.relative <= self.tolerance for c in self.outputs.values())

    def summary(self) -> str:
        worst = ", ".join(f"{n} {c.relative:.2g}" for n, c in self.outputs.items())
        return (f"max |{self.engine} - {self.against}| / σ over {self.samples} steps: {worst} (tolerance "
                f"{self.tolerance:g}); {self.onnx_seconds_per_step * 1e6:.1f} µs per {self.engine} step, "
                f"{self.hypa_seconds_per_sample * 1e6:.1f} µs per sample of {self.against}'s free run")

    def as_dict(self) -> dict:
        return {"passed": self.passed, "tolerance": self.tolerance, "samples": self.samples,
                "outputs": {n: {"max_error": c.max_error, "std": c.std, "relative": c.relative}
                            for n, c in self.outputs.items()},
                f"{self.engine.split()[0].lower()}_seconds_per_step": self.onnx_seconds_per_step,
                "hypa_free_run_seconds_per_sample": self.hypa_seconds_per_sample, "against": self.against}


def check_onnx(path: Path, reference: Reference, tolerance: float = 1e-5,
               state: np.ndarray | None = None) -> Check:
    """Run ``path`` with onnxruntime over the reference record from its initial state (or ``state``)
    and compare each output with hypa's free run, relative to the output's training-set σ."""
    start = reference.initial_state if state is None else state
    y, _, seconds = run_onnx(path, start, reference.u[reference.first :])
    return compare(y, reference, tolerance, seconds)


def compare(y: np.ndarray, reference: Reference, tolerance: float, seconds: float, engine: str = "ONNX",
            against: str = "hypa") -> Check:
    """The check of outputs y (S, p) [SI] from sample ``first`` on, run by ``engine`` at ``seconds`` per step,
    against ``reference`` (hypa's free run, named ``against``)."""
    first = reference.first
    expected = reference.outputs[first:]
    errors = np.abs(y - expected)
    errors = np.where(np.isfinite(errors), errors, np.inf)
    outputs = {n: OutputCheck(float(errors[:, i].max()) if len(errors) else 0.0, float(reference.output_std[i]))
               for i, n in enumerate(reference.output_names)}
    return Check(outputs, tolerance, len(y), seconds, reference.free_run_seconds / len(reference.time), engine,
                 against)
