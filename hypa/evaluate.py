"""Evaluate a trained run on the validation (and test) data.

    python -m hypa.evaluate run=outputs/train/v2-lstm/2026-11-22_10-00-00
    python -m hypa.evaluate run=path/to/checkpoints/best-epoch=12.ckpt

Metrics (MAE, MSE, floored MAPE, R², per state and overall) windowed (100 steps from each
measured state, as in training) and free-running over whole records, each for the whole record,
the stochastic part and the deterministic maneuvers training never saw; the yaw transfer
function (H1 estimate, measured vs model); the implicitly learned rear-wheel angle against the
measured one. Writes ``metrics.json``, ``metrics.csv``, PNG figures and ``summary.md`` into
``<run>/evaluation/`` and the figures into the run's TensorBoard log.
"""

from __future__ import annotations

import csv
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hydra
import matplotlib.pyplot as plt
import numpy as np
from omegaconf import DictConfig

from hypa.data import HypaDataModule
from hypa.evaluation.metrics import state_metrics
from hypa.evaluation.plots import bode, rear_steer
from hypa.evaluation.runs import Prediction, TrainedRun, free_run, load_run, windowed
from hypa.evaluation.transfer import TransferEstimate, h1_estimate
from hypa.plots import DEG, DISPLAY_UNITS, time_series

log = logging.getLogger(__name__)
MANEUVERS = "maneuvers"


def run_datamodule(run: TrainedRun) -> HypaDataModule:
    """The run's data, scaled with the statistics stored in its checkpoint."""
    from hypa.data import datamodule_from_config
    from hypa.entry import data_dir_from_config

    data_dir = run.data_dir if run.data_dir is not None and run.data_dir.is_dir() else data_dir_from_config(run.config)
    dm = datamodule_from_config(run.config.data, data_dir, normalization=run.module.hparams.normalization)
    dm.setup()
    return dm


def segments_of(dm: HypaDataModule, record: str, duration_s: float) -> list[tuple[str, float, float]]:
    """Named time intervals of a record from the data set's ``dataset.json`` (else one: ``all``)."""
    described = dm.metadata.get("files", {}).get(record, {}).get("segments") or []
    return [(s["name"], float(s["start_s"]), float(s["end_s"])) for s in described] or [("all", 0.0, duration_s)]


def _segment_masks(time: np.ndarray, segments: Sequence[tuple[str, float, float]]) -> dict[str, np.ndarray]:
    masks = {name: (time >= start) & (time < end) for name, start, end in segments}
    maneuvers = [m for name, m in masks.items() if name not in ("stochastic", "all")]
    if maneuvers:
        masks[MANEUVERS] = np.any(maneuvers, axis=0)
    return masks


def evaluate_split(run: TrainedRun, dm: HypaDataModule, split: str) -> tuple[dict[str, Any], list[Prediction]]:
    """Windowed and free-run metrics of one split, overall and per segment."""
    names = dm.state_names
    result: dict[str, Any] = {"windowed": {}, "free_run": {}}
    w = windowed(run.module, dm, split)
    pred, target = w["pred"], w["target"]
    result["windowed"]["all"] = state_metrics(pred.reshape(-1, len(names)), target.reshape(-1, len(names)), names)
    records = dm.records(split)
    window_time = {}  # (record, start) -> time span, for per-segment windowed metrics
    for i, rec in enumerate(records):
        masks = _segment_masks(rec.time, segments_of(dm, rec.name, rec.duration_s))
        for name, mask in masks.items():
            inside = [k for k in range(len(w["record"])) if int(w["record"][k]) == i
                      and mask[int(w["start"][k]):int(w["start"][k]) + pred.shape[1] + 1].all()]
            window_time.setdefault(name, []).extend(inside)
    for name, idx in window_time.items():
        if idx and name != "all":
            result["windowed"][name] = state_metrics(pred[idx].reshape(-1, len(names)),
                                                     target[idx].reshape(-1, len(names)), names)
    predictions = [free_run(run.module, dm, rec) for rec in records]
    stacked = lambda values: np.stack([np.concatenate(v) for v in values], axis=-1)  # noqa: E731
    p_all = stacked([[p.predicted[n][1:] for p in predictions] for n in names])
    t_all = stacked([[p.measured[n][1:] for p in predictions] for n in names])
    result["free_run"]["all"] = state_metrics(p_all, t_all, names)
    by_segment: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for p, rec in zip(predictions, records):
        for name, mask in _segment_masks(p.time, segments_of(dm, rec.name, rec.duration_s)).items():
            mask = mask.copy()
            mask[0] = False  # sample 0 is the given initial state
            if name != "all" and mask.any():
                by_segment.setdefault(name, []).append(
                    (np.stack([p.predicted[n][mask] for n in names], -1), np.stack([p.measured[n][mask] for n in names], -1)))
    for name, parts in by_segment.items():
        result["free_run"][name] = state_metrics(np.concatenate([a for a, _ in parts]),
                                                 np.concatenate([b for _, b in parts]), names)
    rear = [p for p in predictions if "rear_wheel_angle" in p.signals and "rear_wheel_angle" in p.measured]
    if rear:
        learned = np.concatenate([p.signal_on_grid("rear_wheel_angle") for p in rear])
        measured = np.concatenate([p.measured["rear_wheel_angle"] for p in rear])
        ok = np.isfinite(learned)
        result["rear_wheel_angle"] = {"corr": float(np.corrcoef(learned[ok], measured[ok])[0, 1]),
                                      "rmse_deg": float(np.sqrt(np.mean((learned[ok] - measured[ok]) ** 2)) * DEG)}
    return result, predictions


def yaw_transfer(prediction: Prediction, segment: tuple[str, float, float] | None, rate_hz: float) -> dict[str, TransferEstimate]:
    """H1 estimates steering-wheel angle -> yaw rate, measured and predicted, on one segment."""
    mask = np.ones_like(prediction.time, dtype=bool) if segment is None else \
        (prediction.time >= segment[1]) & (prediction.time < segment[2])
    u = prediction.inputs["steering_wheel_angle"][mask]
    return {"measured": h1_estimate(u, prediction.measured["yaw_rate"][mask], rate_hz),
            "model": h1_estimate(u, prediction.predicted["yaw_rate"][mask], rate_hz)}


@dataclass
class Evaluation:
    """What ``evaluate_run`` found: the metrics, and the curves to overlay across models."""

    metrics: dict[str, Any]
    transfer: dict[str, TransferEstimate]  # "measured" and "model", steering -> yaw rate (val)
    rear: tuple[np.ndarray, np.ndarray | None, np.ndarray] | None  # time, measured, model [rad]
    model_blocks: tuple = ()  # the model's BlockSpecs (which signals a network learns)


def evaluate_run(run: TrainedRun, out_dir: Path, tensorboard: bool = True) -> Evaluation:
    """Everything above for one run; the metrics, figures and report are written to ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    dm = run_datamodule(run)
    metrics: dict[str, Any] = {"model": run.label, "checkpoint": str(run.checkpoint), "splits": {}}
    figures, estimates, rear = {}, {}, None
    for split in ("val", "test"):
        if not dm.records(split):
            continue
        metrics["splits"][split], predictions = evaluate_split(run, dm, split)
        if split != "val":
            continue
        first = predictions[0]
        segments = segments_of(dm, first.record, float(first.time[-1]))
        stochastic = next((s for s in segments if s[0] == "stochastic"), None)
        if "steering_wheel_angle" in first.inputs and "yaw_rate" in first.predicted:
            try:
                estimates = yaw_transfer(first, stochastic, 1 / dm.dt)
                figures["yaw_transfer"] = bode({"measured": estimates["measured"], run.label: estimates["model"]},
                                               reference="measured", gain_unit="1/s")
            except ValueError as error:  # e.g. a record too short for the spectral averages
                log.warning("no yaw transfer function: %s", error)
        figures["free_run"] = time_series(first.time, {n: first.measured[n] for n in dm.state_names},
                                          {run.label: {n: first.predicted[n] for n in dm.state_names}},
                                          units=DISPLAY_UNITS,
                                          scale={n: DEG for n in dm.state_names},
                                          title=f"{run.label}: free run over {first.record}", spans=segments)
        if "rear_wheel_angle" in first.signals:
            rear = (first.time, first.measured.get("rear_wheel_angle"), first.signal_on_grid("rear_wheel_angle"))
            figures["rear_wheel_angle"] = rear_steer(first.time, first.measured.get("rear_wheel_angle"),
                                                     {run.label: first.signal_on_grid("rear_wheel_angle")},
                                                     title="implicitly learned rear-wheel angle")
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
    _write_csv(metrics, out_dir / "metrics.csv")
    for name, fig in figures.items():
        fig.savefig(out_dir / f"{name}.png", dpi=110)
        if not tensorboard:
            plt.close(fig)
    (out_dir / "summary.md").write_text(summary(metrics, [f"{n}.png" for n in figures]))
    if tensorboard and (run.folder / "tensorboard").is_dir():
        from torch.utils.tensorboard import SummaryWriter

        with SummaryWriter(str(run.folder / "tensorboard")) as writer:
            for name, fig in figures.items():
                writer.add_figure(f"evaluation/{name}", fig, close=True)
    return Evaluation(metrics, estimates, rear, run.module.model.spec.blocks)


def _rows(metrics: dict[str, Any]):
    for split, modes in metrics["splits"].items():
        for mode, segments in modes.items():
            if mode == "rear_wheel_angle":
                for key, value in segments.items():
                    yield split, "free_run", "all", "rear_wheel_angle", key, value
                continue
            for segment, channels in segments.items():
                for channel, values in channels.items():
                    for key, value in values.items():
                        yield split, mode, segment, channel, key, value


def _write_csv(metrics: dict[str, Any], path: Path) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["model", "split", "mode", "segment", "channel", "metric", "value"])
        for row in _rows(metrics):
            writer.writerow([metrics["model"], *row])


def summary(metrics: dict[str, Any], figures: Sequence[str]) -> str:
    """A short markdown report of one run."""
    lines = [f"# Evaluation of {metrics['model']}", "", f"checkpoint: `{metrics['checkpoint']}`", "",
             "MAPE is floored: |error| / max(|y|, 10 % of the channel's RMS), so zero crossings do not explode it.", ""]
    for split, modes in metrics["splits"].items():
        lines += [f"## {split}", "", "| mode | segment | channel | MAE | MSE | MAPE [%] | R² |", "|---|---|---|---|---|---|---|"]
        for mode in ("windowed", "free_run"):
            for segment, channels in modes.get(mode, {}).items():
                for channel, m in channels.items():
                    lines.append(f"| {mode} | {segment} | {channel} | {m['mae']:.3g} | {m['mse']:.3g} | "
                                 f"{m['mape']:.3g} | {m['r2']:.4f} |")
        if "rear_wheel_angle" in modes:
            r = modes["rear_wheel_angle"]
            lines += ["", f"Model vs measured rear-wheel angle (free run; learned for V1/V2, a fixed ratio for "
                      f"physical/V3): correlation {r['corr']:.3f}, "
                      f"RMSE {r['rmse_deg']:.3f} deg"]
        lines.append("")
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


@hydra.main(config_path="../conf", config_name="evaluate", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from hydra.utils import get_original_cwd

    path = Path(str(cfg.run))
    run = load_run(path if path.is_absolute() else Path(get_original_cwd()) / path)
    out = Path(str(cfg.out)) if cfg.out else run.folder / "evaluation"
    metrics = evaluate_run(run, out, tensorboard=bool(cfg.tensorboard)).metrics
    for split, modes in metrics["splits"].items():
        for mode in ("windowed", "free_run"):
            r2 = ", ".join(f"{k} {v['r2']:.4f}" for k, v in modes[mode]["all"].items())
            print(f"{run.label} {split} {mode}: R2 {r2}; MSE overall {modes[mode]['all']['overall']['mse']:.3g}")
    print(f"report: {out / 'summary.md'}")


if __name__ == "__main__":
    main()
