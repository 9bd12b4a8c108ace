"""The figures of ``hypa explain``: the learned and the explained signal over time, the
frequency response of the learned block (H1 from its own input and output) with the chosen
form's, and the static curve of the output against the input."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hypa.evaluation.transfer import TransferEstimate, h1_estimate
from hypa.explain.forms import frequency_response, predict
from hypa.explain.problem import BlockExplanation, gain_unit
from hypa.explain.signals import Recording
from hypa.reporting.figures import subplots

if TYPE_CHECKING:
    from hypa.data import HypaDataModule
    from hypa.models.rollout import Prediction

SEGMENT_S = 16.0  # [s] H1's Welch segments (shorter where the records are short)


def write_figures(result: BlockExplanation, train: Sequence[Recording], val: Sequence[Recording],
                  predictions: Sequence[Prediction], dm: HypaDataModule,
                  out: Path) -> tuple[dict[str, Path], list[str]]:
    """The three figures of one explained signal as PNG in ``out``; returns their paths and notes
    on what could not be drawn."""
    figures, notes = {}, []
    stem = result.problem.key
    first = next(p for p in predictions if p.record == val[0].name)
    fig = time_figure(result, val[0], first.time[val[0].start: val[0].start + len(val[0][result.problem.output])], dm)
    figures["time"] = _save(fig, out / f"{stem}_time.png")
    fig, note = frequency_figure(result, [*train, *val], dm.dt)
    if fig is None:
        notes.append(note)
    else:
        figures["frequency"] = _save(fig, out / f"{stem}_frequency.png")
    figures["static"] = _save(static_figure(result, val, dm), out / f"{stem}_static.png")
    return figures, notes


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=110)
    return path


def _display(name: str, unit: str, dm: HypaDataModule) -> tuple[float, str]:
    """(factor, unit) to show a signal in: the channel's display unit (rad -> deg), else SI."""
    channel = dm.channels.get(name)
    if channel is not None and channel.display_unit:
        return channel.display_factor, channel.display_unit
    return 1.0, unit


def time_figure(result: BlockExplanation, record: Recording, time: np.ndarray, dm: HypaDataModule):
    """The learned block's output, the chosen form's and the measurement (dashed black) over one record."""
    p = result.problem
    k, unit = _display(p.output, p.units[p.output], dm)
    explained = predict(result.explanation, [record])[0]
    fig, ax = subplots(figsize=(10, 3.2))
    ax.plot(time, k * record[p.output], lw=1.0, label="learned block")
    ax.plot(time, k * explained, lw=1.0, label=f"explained ({result.explanation.best.form.name})")
    truth = f"measured:{p.output}"
    if truth in record.signals:
        ax.plot(time, k * record[truth], "k--", lw=0.8, label="measured")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{p.output} [{unit}]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(f"{p.block}: {record.name}", fontsize=9)
    fig.tight_layout()
    return fig


def learned_response(records: Sequence[Recording], input_name: str, output: str,
                     dt: float) -> TransferEstimate:
    """H1 of the learned block from ``input_name`` to ``output`` over the records laid end to end
    (each record's mean removed first), Welch segments of up to 16 s."""
    u = np.concatenate([r[input_name] - r[input_name].mean() for r in records])
    y = np.concatenate([r[output] - r[output].mean() for r in records])
    segment = min(SEGMENT_S, len(u) * dt / 3.0)
    return h1_estimate(u, y, 1.0 / dt, segment_s=segment)


def frequency_figure(result: BlockExplanation, records: Sequence[Recording], dt: float):
    """Bode plot: the learned block's H1 (dashed black, with γ²) and the chosen form's response
    from the block's first input; (None, why) where the records are too short or the input constant."""
    from hypa.evaluation.figures import bode

    p = result.problem
    try:
        estimate = learned_response(records, p.inputs[0], p.output, dt)
    except ValueError as error:
        return None, f"no frequency response of {p.block}: {error}"
    f = estimate.frequency_hz
    form = TransferEstimate.analytic(f, frequency_response(result.explanation.best, p.inputs[0], f))
    f_range = (float(f[0]), float(min(f[-1], 20.0)))
    fig = bode({"learned block (H1)": estimate, f"explained ({result.explanation.best.form.name})": form},
               reference="learned block (H1)", f_range=f_range, coherence_min=0.5, gain_unit=gain_unit(p),
               title=f"{p.block}: {p.inputs[0]} → {p.output}")
    return fig, ""


def static_figure(result: BlockExplanation, records: Sequence[Recording], dm: HypaDataModule):
    """The output against the first input (validation samples) and the chosen form's static curve
    (offset + gain · (u + cubic · u³); the other inputs and the extra signals at zero)."""
    p, best = result.problem, result.explanation.best
    x_name = p.inputs[0]
    kx, ux = _display(x_name, p.units[x_name], dm)
    ky, uy = _display(p.output, p.units[p.output], dm)
    u = np.concatenate([r[x_name] for r in records])
    y = np.concatenate([r[p.output] for r in records])
    fig, ax = subplots(figsize=(5.5, 4.2))
    ax.scatter(kx * u, ky * y, s=2, alpha=0.3, label="learned block (validation)")
    if "measured:" + p.output in records[0].signals:
        truth = np.concatenate([r["measured:" + p.output] for r in records])
        ax.scatter(kx * u, ky * truth, s=2, alpha=0.2, color="k", label="measured")
    grid = np.linspace(u.min(), u.max(), 200)
    offset, gain, cubic = (best.value(kind, "" if kind == "offset" else x_name) for kind in ("offset", "gain", "cubic"))
    curve = offset.value + gain.value * (grid + (cubic.value * grid**3 if cubic else 0.0))
    ax.plot(kx * grid, ky * curve, "C1", lw=1.5, label=f"explained ({best.form.name}), static")
    ax.set_xlabel(f"{x_name} [{ux}]")
    ax.set_ylabel(f"{p.output} [{uy}]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, markerscale=4)
    ax.set_title(f"{p.block}: static curve", fontsize=9)
    fig.tight_layout()
    return fig
