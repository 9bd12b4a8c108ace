"""Figures. Plot functions take arrays and return matplotlib figures; they compute nothing."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")  # headless: figures go to files and TensorBoard, never to a screen
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402



def time_series(
    time: np.ndarray,
    measured: Mapping[str, np.ndarray],
    predicted: Mapping[str, Mapping[str, np.ndarray]],
    units: Mapping[str, str] | None = None,
    scale: Mapping[str, float] | None = None,
    title: str = "",
    spans: Sequence[tuple[str, float, float]] = (),
) -> Figure:
    """One panel per channel: the measurement (dashed black) and each prediction.

    ``predicted`` maps a model name to its channels; ``scale`` multiplies a channel for display
    (e.g. rad -> deg) and ``units`` labels it; ``spans`` shades named time intervals.
    """
    units, scale = units or {}, scale or {}
    channels = list(measured)
    fig, axes = plt.subplots(len(channels), 1, sharex=True, figsize=(11, 2.6 * len(channels)), squeeze=False)
    for ax, channel in zip(axes[:, 0], channels):
        k = scale.get(channel, 1.0)
        for name, series in predicted.items():
            if channel in series:
                ax.plot(time, k * series[channel], lw=1.0, label=name)
        ax.plot(time, k * measured[channel], "k--", lw=0.8, label="measured")
        ax.set_ylabel(f"{channel}\n[{units.get(channel, '')}]")
        ax.grid(alpha=0.3)
        for i, (label, start, end) in enumerate(spans):
            ax.axvspan(start, end, color=f"C{i % 10}", alpha=0.06)
            if ax is axes[0, 0]:
                ax.text(start, 1.0, f" {label}", transform=ax.get_xaxis_transform(), va="bottom", fontsize=7)
    axes[0, 0].legend(loc="upper right", fontsize=8, ncol=len(predicted) + 1)
    axes[-1, 0].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
