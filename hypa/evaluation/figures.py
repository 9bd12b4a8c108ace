"""Evaluation figures in the paper's style: the yaw transfer function (Fig. 5) and the rear-wheel
angle over time (Fig. 4). They take arrays / estimates and return figures; they compute nothing
beyond unit conversion and masking for display.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from hypa.evaluation.transfer import TransferEstimate
from hypa.reporting.figures import subplots


def _masked(values: np.ndarray, coherence: np.ndarray, coherence_min: float | None) -> np.ndarray:
    """NaN where γ² < coherence_min: there the estimate is mostly noise, and a gap says so."""
    if coherence_min is None:
        return values
    return np.where(coherence >= coherence_min, values, np.nan)


def bode(
    estimates: Mapping[str, TransferEstimate],
    reference: str | None = "measured",
    f_range: tuple[float, float] = (0.1, 5.0),
    coherence_min: float | None = 0.5,
    gain_unit: str = "1/s",
    title: str = "",
) -> Figure:
    """Gain |H| [gain_unit] and phase [deg] over frequency [Hz, log], as in the paper's Fig. 5.

    ``estimates[reference]`` (the measurement) is dashed black, every other entry solid; with
    a reference, a third small panel shows its coherence γ² and the ``coherence_min`` line.
    Each curve is hidden where its own γ² < coherence_min (None: show everything), and only
    f_range [Hz] is drawn. The gain of yaw rate per steering-wheel angle is in 1/s, which is
    the same number as (deg/s)/deg.
    """
    if reference is not None and reference not in estimates:
        raise KeyError(f"reference {reference!r} not among the estimates {list(estimates)}")
    n_panels = 2 if reference is None else 3
    ratios = [3, 2] if reference is None else [3, 2, 1]
    fig, axes = subplots(n_panels, 1, sharex=True, figsize=(7, 2.2 * n_panels + 0.6),
                             gridspec_kw={"height_ratios": ratios})
    gain_ax, phase_ax = axes[0], axes[1]
    models = [name for name in estimates if name != reference]
    # models first, then the reference on top so the dashed line stays visible
    for name in models + ([reference] if reference is not None else []):
        est = estimates[name].band(*f_range)
        style = {"color": "k", "ls": "--", "lw": 1.2} if name == reference else {"ls": "-", "lw": 1.0}
        gain_ax.plot(est.frequency_hz, _masked(est.magnitude, est.coherence, coherence_min), label=name, **style)
        phase_ax.plot(est.frequency_hz, _masked(est.phase_deg, est.coherence, coherence_min), label=name, **style)
    gain_ax.set_ylabel(f"gain [{gain_unit}]")
    phase_ax.set_ylabel("phase [deg]")
    if reference is not None:
        coh_ax = axes[2]
        est = estimates[reference].band(*f_range)
        coh_ax.plot(est.frequency_hz, est.coherence, "k--", lw=1.0)
        if coherence_min is not None:
            coh_ax.axhline(coherence_min, color="0.5", lw=0.8, ls=":")
        coh_ax.set_ylim(0.0, 1.05)
        coh_ax.set_ylabel("γ²")
    for ax in axes:
        ax.set_xscale("log")
        ax.grid(alpha=0.3, which="both")
    axes[-1].set_xlim(*f_range)
    # plain decimal ticks: the default 2×10⁻¹ minor labels overlap on a one-decade axis
    ticks = [v for v in (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500)
             if f_range[0] <= v <= f_range[1]]
    axes[-1].set_xticks(ticks, [f"{v:g}" for v in ticks])
    axes[-1].xaxis.set_minor_formatter(NullFormatter())
    axes[-1].set_xlabel("frequency [Hz]")
    gain_ax.legend(fontsize=8, loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def rear_steer(
    time: np.ndarray,
    measured: np.ndarray | None,
    learned: Mapping[str, np.ndarray],
    title: str = "",
) -> Figure:
    """Rear-wheel angle δr over time [s], drawn in degrees from inputs in rad (paper Fig. 4).

    ``measured`` (None when the record has no rear-wheel sensor) is dashed black on top; each
    learned or modelled angle is solid.
    """
    fig, ax = subplots(figsize=(9, 3))
    for name, angle in learned.items():
        ax.plot(time, np.degrees(angle), lw=1.0, label=name)
    if measured is not None:
        ax.plot(time, np.degrees(measured), "k--", lw=1.0, label="measured")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("rear-wheel angle [deg]")
    ax.grid(alpha=0.3)
    if learned or measured is not None:
        ax.legend(fontsize=8, loc="upper right")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig
