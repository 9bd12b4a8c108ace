"""A physics model at its configured values, untrained, against measured data (``hypa simulate``).

Any physics-only model of any system runs the way training and evaluation run it (one engine:
``ComposedModel`` over ``hypa.physics``), two ways on each validation record:

- **windowed**: every validation window from its measured (or estimated) start, as in training;
- **free-running**: the whole record from its start, never seeing a measured output after it.

Metrics per output: RMSE and mean error (SI in ``simulation.json``, display units in the
printed report), R² and NRMSE (RMSE / standard deviation of the measurement).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hypa.core.errors import UserError
from hypa.core.metrics import errors
from hypa.data import HypaDataModule
from hypa.evaluation.runs import windowed
from hypa.models import ModelSpec, parse_model_spec
from hypa.models.rollout import free_run
from hypa.training.module import HybridModule

log = logging.getLogger(__name__)


def nominal_module(model: ModelSpec | Mapping[str, Any], physical_values: Mapping[str, float] | None,
                   dm: HypaDataModule, hold: str | None) -> HybridModule:
    """The model ``model`` (parsed, or its config) built on ``dm``'s channels with its configured parameter
    values (``physical_values`` for the parameter group's names, else the systems' nominal ones).
    ``hold``: the run's ``physics.hold``, for a model whose spec fixes no ``hold:`` of its own
    (``None``: the spec's, else ``zoh``; a different one than the spec's is a ``ModelSpecError``).

    Raises ``UserError`` for a model with networks: untrained, they would simulate nothing.
    """
    spec = model if isinstance(model, ModelSpec) else parse_model_spec(dict(model))
    networks = [b.name for b in spec.blocks if b.kind == "ann"]  # a dead time or a limit is physics too
    if networks:
        raise UserError(f"hypa simulate runs physics only; model {spec.name} has the network blocks "
                        f"{', '.join(networks)}: train it (hypa train) and evaluate the run instead")
    module = HybridModule.from_data(dm, spec, physical_values=physical_values, hold=hold)
    return module.eval()


def channel_metrics(measured: np.ndarray, simulated: np.ndarray) -> dict[str, float]:
    """RMSE, mean error (SI), R² = 1 - SSE/SST and NRMSE = RMSE / σ(measured) of one channel
    (``hypa.core.metrics.errors``)."""
    e = errors(simulated, measured)
    return {k: e[k] for k in ("rmse", "mean_error", "r2", "nrmse")}


def simulate_nominal(module: HybridModule, dm: HypaDataModule, out: Path, plot: bool = True) -> dict:
    """Windowed and free-run metrics of ``module`` on ``dm``'s validation records; writes
    ``simulation.json`` (SI units) and, with ``plot``, ``free_run_<record>.png`` into ``out``.

    Returns {label: {output: metrics}}, labels ``windowed (N steps)`` and ``free-run <record>``.
    """
    from hypa.reporting.figures import time_series

    outputs = dm.output_names
    windows = windowed(module, dm, "val")
    label = f"windowed ({windows['pred'].shape[1]} steps)"
    results = {label: {n: channel_metrics(windows["target"][..., i].ravel(), windows["pred"][..., i].ravel())
                       for i, n in enumerate(outputs)}}
    units = {n: dm.channels[n].display_unit for n in outputs}
    scale = {n: dm.channels[n].display_factor for n in outputs}
    for record in dm.records("val"):
        run = free_run(module.model, dm, record)
        results[f"free-run {record.name}"] = {
            n: channel_metrics(run.measured[n][run.first:], run.predicted[n][run.first:]) for n in outputs}
        if plot:
            fig = time_series(record.time, {n: run.measured[n] for n in outputs},
                              {"physics": {n: run.predicted[n] for n in outputs}}, units=units, scale=scale,
                              title=f"{module.model.spec.name} free-running over {record.name}")
            path = out / f"free_run_{Path(record.name).stem}.png"
            fig.savefig(path, dpi=110)
            log.info("figure: %s", path)
    (out / "simulation.json").write_text(json.dumps(results, indent=2))
    return results


def report(results: Mapping[str, Mapping[str, Mapping[str, float]]], dm: HypaDataModule, title: str) -> str:
    """The metrics as a table, errors in each output's display unit."""
    wide = max(len(label) for label in results) + 2
    names = max((len(name) for r in results.values() for name in r), default=6) + 2
    lines = [title, f"{'':<{wide}}{'output':<{names}}{'RMSE':>16}{'mean error':>16}{'R²':>8}{'NRMSE':>8}"]
    for label, metrics in results.items():
        for name, m in metrics.items():
            channel = dm.channels[name]
            unit, k = channel.display_unit, channel.display_factor
            lines.append(f"{label:<{wide}}{name:<{names}}{m['rmse'] * k:>9.4g} {unit:<6}{m['mean_error'] * k:>9.3g} "
                         f"{unit:<6}{m['r2']:>8.3f}{m['nrmse']:>8.3f}")
    return "\n".join(lines)
