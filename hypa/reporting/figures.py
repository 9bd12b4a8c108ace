"""Figures. Plot functions take arrays and return matplotlib figures; they compute nothing.

Every figure of hypa is made by :func:`subplots`: a ``matplotlib.figure.Figure`` outside
pyplot, so importing hypa chooses no matplotlib backend (a notebook keeps its own), a figure
needs no ``plt.close`` (it is freed with its last reference) and saving it (``savefig``,
TensorBoard's ``add_figure``) works on a machine without a screen.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure


def subplots(nrows: int = 1, ncols: int = 1, figsize: tuple[float, float] | None = None,
             **kwargs: Any) -> tuple[Figure, Any]:
    """A figure and its axes, as ``pyplot.subplots`` gives them, without pyplot."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)



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
    fig, axes = subplots(len(channels), 1, sharex=True, figsize=(11, 2.6 * len(channels)), squeeze=False)
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
