"""A trained hypa model as one step, exported: ``python -m hypa.export run=RUN`` (:mod:`hypa.commands.export`).

``ModelStep`` is the step (physics and networks together, SI in and out), ``export_run``
writes ``model.onnx``, ``reference.csv`` and ``export.json`` and checks the ONNX step with
onnxruntime against hypa's own free run (``check_onnx``).
"""

from hypa.export.blocks import ExportError, StateSlot
from hypa.export.onnx import Check, check_onnx, export_onnx, run_onnx
from hypa.export.reference import Reference, reference_run
from hypa.export.run import Export, build_step, export_run, formats_to_build
from hypa.export.step import ModelStep, scheduled_squarings

__all__ = ["Check", "Export", "ExportError", "ModelStep", "Reference", "StateSlot", "build_step", "check_onnx",
           "export_onnx", "export_run", "formats_to_build", "reference_run", "run_onnx", "scheduled_squarings"]
