"""Evaluate a trained run: windowed and free-run metrics per output, transfer functions, figures.

Metrics (MAE, MSE, floored MAPE, R², per output and overall) windowed (N steps from each
window start, as in training) and free-running over whole records, each for the whole record
and for the named segments of the data set's ``dataset.json`` (on the test bench: the
stochastic part and the deterministic maneuvers training never saw); H1 transfer functions
from every input to every output, measured vs model; each internal model signal that the files
measure for evaluation (an implicitly learned rear-wheel angle) against the measurement.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hypa.core.errors import UserError
from hypa.core.metrics import correlation, errors, state_metrics
from hypa.data import HypaDataModule
from hypa.evaluation.figures import bode
from hypa.evaluation.result import Evaluation, RunMetrics, SignalMetrics, SplitMetrics, segments
from hypa.evaluation.runs import TrainedRun, windowed
from hypa.evaluation.transfer import TransferEstimate, h1_estimate
from hypa.models.rollout import Prediction, free_run, free_run_levels
from hypa.reporting.figures import time_series

log = logging.getLogger(__name__)
MANEUVERS = "maneuvers"


def run_datamodule(run: TrainedRun) -> HypaDataModule:
    """The run's data, scaled with the statistics stored in its checkpoint."""
    from hypa.data import datamodule_from_config
    from hypa.data.from_config import data_dir_from_config

    recorded = run.data_dir is not None and run.data_dir.is_dir()
    data_dir = run.data_dir if recorded else data_dir_from_config(run.settings)
    dm = datamodule_from_config(run.settings.data, data_dir, normalization=run.module.hparams.normalization)
    dm.setup()
    check_data_files(run, dm, data_dir)
    return dm


def check_data_files(run: TrainedRun, dm: HypaDataModule, data_dir: Path) -> list[str]:
    """Warn (one log line) when the files ``dm`` read differ from those the run was trained on.

    Evaluating on other data is allowed (new measurements of the same system), so it is no
    error, but it must not pass unnoticed: the run's ``run.json`` holds the checksums of its
    files (:mod:`hypa.core.metadata`). Returns the differences; none for a run without checksums.
    """
    from hypa.core.metadata import data_differences

    recorded = run.info.get("data_files")
    if recorded is None:
        return []
    differences = data_differences(recorded, dm.files, data_dir)
    if differences:
        log.warning("the data differ from those %s was trained on (%s; in %s): its metrics are on other data",
                    run.folder, "; ".join(differences), data_dir)
    return differences


def segments_of(dm: HypaDataModule, record: str, duration_s: float,
                start_s: float = 0.0) -> list[tuple[str, float, float]]:
    """Named time intervals of a record from the data set's ``dataset.json`` (else one: ``all``,
    from ``start_s``: a record cut out of a longer file starts at its time in that file)."""
    described = dm.metadata.get("files", {}).get(record, {}).get("segments") or []
    return [(s["name"], float(s["start_s"]), float(s["end_s"])) for s in described] or [("all", start_s, duration_s)]


def _segment_masks(time: np.ndarray, segments: Sequence[tuple[str, float, float]]) -> dict[str, np.ndarray]:
    masks = {name: (time >= start) & (time < end) for name, start, end in segments}
    maneuvers = [m for name, m in masks.items() if name not in ("stochastic", "all")]
    if maneuvers:
        masks[MANEUVERS] = np.any(maneuvers, axis=0)
    return masks


def evaluate_split(run: TrainedRun, dm: HypaDataModule, split: str, subset: Sequence[int] | None = None,
                   w: dict[str, np.ndarray] | None = None) -> tuple[SplitMetrics, list[Prediction]]:
    """Windowed and free-run metrics of one split (or of the records ``subset`` of it, one test
    set of several), overall and per segment; ``w``: the split's ``windowed`` result if known."""
    names = dm.output_names
    result = {"windowed": {}, "free_run": {}}  # mode -> segment -> output -> metric -> value
    w = windowed(run.module, dm, split) if w is None else w
    split_records = dm.records(split)
    chosen = range(len(split_records)) if subset is None else subset
    keep = np.isin(w["record"].astype(int), list(chosen))
    w = {k: v[keep] for k, v in w.items()}
    pred, target = w["pred"], w["target"]
    records = [split_records[i] for i in chosen]
    if not np.isfinite(pred).all():
        window, _, output = (int(i[0]) for i in np.nonzero(~np.isfinite(pred)))
        rec = split_records[int(w["record"][window])]
        raise UserError(f"{run.label} ({run.checkpoint}) predicts non-finite {names[output]} in the {split} windows "
                        f"(first in {rec.name} at {rec.time[int(w['start'][window])]:.3g} s): the model diverges on "
                        "these data; evaluate another checkpoint or retrain it")
    result["windowed"]["all"] = state_metrics(pred.reshape(-1, len(names)), target.reshape(-1, len(names)), names)
    window_time = {}  # (record, start) -> time span, for per-segment windowed metrics
    for i, rec in zip(chosen, records):
        masks = _segment_masks(rec.time, segments_of(dm, rec.file, rec.duration_s))
        for name, mask in masks.items():
            inside = [k for k in range(len(w["record"])) if int(w["record"][k]) == i
                      and mask[int(w["start"][k]):int(w["start"][k]) + pred.shape[1] + 1].all()]
            window_time.setdefault(name, []).extend(inside)
    for name, idx in window_time.items():
        if idx and name != "all":
            result["windowed"][name] = state_metrics(pred[idx].reshape(-1, len(names)),
                                                     target[idx].reshape(-1, len(names)), names)
    predictions = [free_run(run.module.model, dm, rec) for rec in records]
    for p in predictions:
        for name in names:
            bad = np.nonzero(~np.isfinite(p.predicted[name]))[0]
            if bad.size:
                raise UserError(f"{run.label} ({run.checkpoint}) diverges in its free run over {p.record}: {name} is "
                                f"not finite from {p.time[bad[0]]:.3g} s on; evaluate another checkpoint or retrain it")
    stacked = lambda values: np.stack([np.concatenate(v) for v in values], axis=-1)  # noqa: E731
    p_all = stacked([[p.predicted[n][p.first:] for p in predictions] for n in names])
    t_all = stacked([[p.measured[n][p.first:] for p in predictions] for n in names])
    result["free_run"]["all"] = state_metrics(p_all, t_all, names)
    by_segment: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for p, rec in zip(predictions, records):
        for name, mask in _segment_masks(p.time, segments_of(dm, rec.file, rec.duration_s)).items():
            mask = mask.copy()
            mask[: p.first] = False  # the samples that started the model
            if name != "all" and mask.any():
                by_segment.setdefault(name, []).append(
                    (np.stack([p.predicted[n][mask] for n in names], -1),
                     np.stack([p.measured[n][mask] for n in names], -1)))
    for name, parts in by_segment.items():
        result["free_run"][name] = state_metrics(np.concatenate([a for a, _ in parts]),
                                                 np.concatenate([b for _, b in parts]), names)
    signals = {}
    for name in compared_signals(predictions):
        with_it = [p for p in predictions if name in p.signals and name in p.measured]
        learned = np.concatenate([p.signal_on_grid(name) for p in with_it])
        measured = np.concatenate([p.measured[name] for p in with_it])
        ok = np.isfinite(learned)  # the model's signal where it has one
        signals[name] = SignalMetrics(correlation(learned[ok], measured[ok]),
                                      errors(learned[ok], measured[ok])["rmse"])
    return SplitMetrics(segments(result["windowed"]), segments(result["free_run"]), signals), predictions


def compared_signals(predictions: Sequence[Prediction]) -> list[str]:
    """Internal model signals the files also measure (for evaluation only): learned vs measured."""
    return sorted({n for p in predictions for n in p.signals if n in p.measured})


def transfer_estimates(prediction: Prediction, input_name: str, output_name: str,
                       segment: tuple[str, float, float] | None, rate_hz: float) -> dict[str, TransferEstimate]:
    """H1 estimates input -> output, measured and predicted, on one segment of one record."""
    mask = np.ones_like(prediction.time, dtype=bool) if segment is None else \
        (prediction.time >= segment[1]) & (prediction.time < segment[2])
    mask[: prediction.first] = False
    u = prediction.inputs[input_name][mask]
    segment_s = min(16.0, u.size / rate_hz / 4)  # 16 s segments (1/16 Hz resolution) where the record allows
    return {"measured": h1_estimate(u, prediction.measured[output_name][mask], rate_hz, segment_s),
            "model": h1_estimate(u, prediction.predicted[output_name][mask], rate_hz, segment_s)}


def evaluate_run(run: TrainedRun, out_dir: Path, tensorboard: bool = True) -> Evaluation:
    """Everything above for one run; the metrics, figures and report are written to ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    dm = run_datamodule(run)
    units = {n: c.display_unit for n, c in dm.channels.items()}
    scale = {n: c.display_factor for n, c in dm.channels.items()}
    metrics = RunMetrics(run.label, str(run.checkpoint), units={n: c.unit for n, c in dm.channels.items()})
    figures, primary, learned, warnings = {}, {}, {}, []
    for split in ("val", "test"):
        if not dm.records(split):
            continue
        sets = dm.test_sets() if split == "test" else {}
        if list(sets) not in ([], ["test"]):  # named test sets (they may overlap): each on its own
            w, first_index = windowed(run.module, dm, split), 0
            for name, records in sets.items():
                subset = range(first_index, first_index + len(records))
                metrics.splits[f"test/{name}"], _ = evaluate_split(run, dm, split, subset, w)
                first_index += len(records)
            continue
        metrics.splits[split], predictions = evaluate_split(run, dm, split)
        if split != "val":
            continue
        # a free run at a level the data never reach (a 0 V cell): one line naming the output and the state
        warnings = free_run_levels(predictions, dm.output_names, run.module.model,
                                   {n: dm.channels[n].unit for n in dm.output_names})
        first = predictions[0]
        segments = segments_of(dm, dm.records(split)[0].file, float(first.time[-1]), float(first.time[first.first]))
        stochastic = next((s for s in segments if s[0] == "stochastic"), None)
        rate = 1 / dm.dt  # shown: 0.1-5 Hz at the test bench's 32 Hz, the same share of the band elsewhere
        for input_name in dm.input_names:
            for output_name in dm.output_names:
                try:
                    estimates = transfer_estimates(first, input_name, output_name, stochastic, rate)
                except ValueError as error:  # e.g. a record too short for the spectral averages
                    log.warning("no transfer function %s -> %s: %s", input_name, output_name, error)
                    continue
                primary = primary or estimates
                gain_unit = f"{dm.channels[output_name].unit} / {dm.channels[input_name].unit}"
                figures[f"transfer_{input_name}_{output_name}"] = bode(
                    {"measured": estimates["measured"], run.label: estimates["model"]}, reference="measured",
                    f_range=(rate / 320, rate / 6.4), gain_unit=gain_unit, title=f"{input_name} -> {output_name}")
        shown = slice(first.first, None)
        figures["free_run"] = time_series(first.time[shown], {n: first.measured[n][shown] for n in dm.output_names},
                                          {run.label: {n: first.predicted[n][shown] for n in dm.output_names}},
                                          units=units, scale=scale,
                                          title=f"{run.label}: free run over {first.record}", spans=segments)
        for name in compared_signals([first]):
            learned[name] = (first.time, first.measured.get(name), first.signal_on_grid(name))
            figures[name] = time_series(first.time, {name: first.measured[name]},
                                        {f"{run.label} (learned)": {name: first.signal_on_grid(name)}},
                                        units=units, scale=scale, title=f"implicitly learned {name}")
    evaluation = Evaluation(metrics, primary, learned, run.module.model.spec.blocks, units, scale, warnings)
    evaluation.to_json(out_dir / "metrics.json")
    metrics.write_csv(out_dir / "metrics.csv")
    for name, fig in figures.items():
        fig.savefig(out_dir / f"{name}.png", dpi=110)
    report = evaluation.markdown([f"{n}.png" for n in figures])
    identified = run.folder / "identification.md"  # how the run's physics were identified (hypa.identification)
    if identified.is_file():
        report += "\n" + identified.read_text()
    (out_dir / "summary.md").write_text(report)
    if tensorboard and (run.folder / "tensorboard").is_dir():
        from torch.utils.tensorboard import SummaryWriter

        with SummaryWriter(str(run.folder / "tensorboard")) as writer:
            for name, fig in figures.items():
                writer.add_figure(f"evaluation/{name}", fig, close=True)
    return evaluation

