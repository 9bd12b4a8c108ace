"""Figures of a test-bench record. They take arrays (SI units) and return figures."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

_DEG = 180.0 / np.pi
_SEGMENT_COLOURS = ("#f2f2f2", "#dde8f3", "#f3e6dd", "#e2f0dc", "#efe0f0")


def plot_record(
    time: np.ndarray,
    steering_wheel_angle: np.ndarray,
    yaw_rate: np.ndarray,
    side_slip: np.ndarray,
    lateral_acceleration: np.ndarray,
    rear_wheel_angle: np.ndarray,
    segments: Sequence[tuple[str, float, float]] = (),
    title: str = "",
) -> Figure:
    """Stacked time histories (angles shown in deg), segments [s] shaded and named."""
    panels = (
        (steering_wheel_angle * _DEG, "steering wheel\nangle [deg]"),
        (yaw_rate * _DEG, "yaw rate\n[deg/s]"),
        (side_slip * _DEG, "side slip\n[deg]"),
        (lateral_acceleration, "lateral acc.\n[m/s$^2$]"),
        (rear_wheel_angle * _DEG, "rear wheel\nangle [deg]"),
    )
    fig = Figure(figsize=(12, 9), layout="constrained")
    axes = fig.subplots(len(panels), 1, sharex=True)
    for ax, (values, label) in zip(axes, panels):
        for i, (_name, start, end) in enumerate(segments):
            ax.axvspan(start, end, color=_SEGMENT_COLOURS[i % len(_SEGMENT_COLOURS)], lw=0)
        ax.plot(time, values, lw=0.6, color="C0")
        ax.set_ylabel(label)
        ax.grid(True, lw=0.3)
    for name, start, end in segments:
        axes[0].text(
            0.5 * (start + end),
            1.02,
            name,
            transform=axes[0].get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=8,
        )
    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(time[0], time[-1])
    if title:
        fig.suptitle(title)
    return fig


def plot_spectrum(
    frequency_hz: np.ndarray,
    psd: dict[str, np.ndarray],
    break_frequency_hz: float | None = None,
    cutoff_hz: float | None = None,
) -> Figure:
    """Power spectral densities [unit^2/Hz] over frequency [Hz], log-log, marks at f_b, f_c."""
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.subplots()
    keep = frequency_hz > 0
    for label, values in psd.items():
        ax.loglog(frequency_hz[keep], values[keep], lw=0.8, label=label)
    for f, name in ((break_frequency_hz, "break"), (cutoff_hz, "cut-off")):
        if f is not None:
            ax.axvline(f, color="k", ls="--", lw=0.6)
            ax.text(f, 1.01, f" {name} {f:g} Hz", transform=ax.get_xaxis_transform(), fontsize=8)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("PSD [unit$^2$/Hz]")
    ax.grid(True, which="both", lw=0.3)
    ax.legend()
    return fig


def plot_axle_characteristics(slip_angle: np.ndarray, forces: dict[str, np.ndarray]) -> Figure:
    """Lateral axle forces [N] over the slip angle [rad] (shown in deg), one line per entry."""
    fig = Figure(figsize=(7, 5), layout="constrained")
    ax = fig.subplots()
    for label, values in forces.items():
        ax.plot(slip_angle * _DEG, values, label=label)
    ax.set_xlabel("slip angle [deg]")
    ax.set_ylabel("lateral axle force [N]")
    ax.grid(True, lw=0.3)
    ax.legend()
    return fig
