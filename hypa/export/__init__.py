"""A trained hypa model as one step, exported: ``hypa export run=RUN`` (:mod:`hypa.commands.export`).

``ModelStep`` is the step (physics and networks together, SI in and out), ``export_run``
writes ``model.onnx``, ``reference.csv`` and ``export.json`` and checks the ONNX step with
onnxruntime against hypa's own free run (``check_onnx``); ``format=fmu`` adds an FMI 2.0
co-simulation FMU (``build_fmu``, checked with fmpy: ``run_fmu``), ``format=statespace`` a
physics-only model's composed linear state space (``linear_model``, ``statespace.mat``,
``statespace.json``, read back by ``load_statespace`` as a python-control ``StateSpace``),
``format=c`` the step compiled to C99 (``c_step``) in a source-code FMI 2.0 FMU for
co-simulation and model exchange (``build_native_fmu``, checked with fmpy: ``run_fmu``,
``run_native_me``).
"""

from hypa.export.api import Export, build_step, export_run, formats_to_build
from hypa.export.blocks import ExportError, StateSlot
from hypa.export.ccode import CStep, c_step
from hypa.export.fmu import build_fmu, run_fmu
from hypa.export.native import build_native_fmu, run_native_me
from hypa.export.onnx import Check, check_onnx, export_onnx, run_onnx
from hypa.export.reference import Reference, reference_run
from hypa.export.statespace import LinearModel, linear_model, load_statespace
from hypa.export.step import ModelStep, scheduled_squarings

__all__ = ["CStep", "Check", "Export", "ExportError", "LinearModel", "ModelStep", "Reference", "StateSlot",
           "build_fmu", "build_native_fmu", "build_step", "c_step", "check_onnx", "export_onnx", "export_run",
           "formats_to_build", "linear_model", "load_statespace", "reference_run", "run_fmu", "run_native_me",
           "run_onnx", "scheduled_squarings"]
