"""Figures of the diagnosis (step 1: where a person would look). They take arrays and return
figures; the time series, transfer function and rear angle reuse ``hypa.plots`` and
``hypa.evaluation.plots``. Angles in rad are drawn in degrees."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from hypa.vehicle.display import DISPLAY_UNITS  # noqa: E402

UNITS = {name: DISPLAY_UNITS[name] for name in ("yaw_rate", "side_slip")}  # the states


def error_vs_ay(edges: np.ndarray, rmse: Mapping[str, Mapping[str, Sequence[float | None]]],
                counts: np.ndarray) -> Figure:
    """RMSE per state [deg/s, deg] in bins of |a_y| [m/s²]: ``rmse[model][state]`` per bin."""
    states = list(next(iter(rmse.values())))
    fig, axes = plt.subplots(1, len(states), figsize=(10, 3.4), squeeze=False)
    labels = [f"{lo:g}–{hi:g}" if np.isfinite(hi) else f"≥{lo:g}" for lo, hi in zip(edges[:-1], edges[1:])]
    x = np.arange(len(labels))
    width = 0.8 / len(rmse)
    for ax, state in zip(axes[0], states):
        for j, (model, per_state) in enumerate(rmse.items()):
            values = np.array([np.nan if v is None else v for v in per_state[state]], dtype=float)
            ax.bar(x + (j - (len(rmse) - 1) / 2) * width, np.degrees(values), width, label=model)
        ax.set_xticks(x, [f"{label}\nn={int(n)}" for label, n in zip(labels, counts)], fontsize=7)
        ax.set_xlabel("|lateral acceleration| [m/s²]")
        ax.set_ylabel(f"RMSE {state} [{UNITS.get(state, '')}]")
        ax.grid(alpha=0.3, axis="y")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("free-run error against amplitude (n: validation samples per bin)")
    fig.tight_layout()
    return fig


def correlations(auto: Mapping[str, tuple[np.ndarray, np.ndarray]], cross: Mapping[str, tuple[np.ndarray, np.ndarray]],
                 bound: float, dt: float) -> Figure:
    """Residual autocorrelation ρ_ee and input–residual cross-correlation ρ_ue per state over the
    lag [s], with the ±``bound`` confidence band (dotted)."""
    states = list(auto)
    fig, axes = plt.subplots(2, len(states), figsize=(10, 5.5), squeeze=False)
    for j, state in enumerate(states):
        panels = (("autocorrelation ρ_ee", auto), ("cross-correlation ρ_ue (δsw, e)", cross))
        for i, (kind, data) in enumerate(panels):
            lags, rho = data[state]
            ax = axes[i, j]
            ax.axhline(0.0, color="0.6", lw=0.6)
            ax.vlines(lags * dt, 0.0, rho, lw=1.0)
            for sign in (1, -1):
                ax.axhline(sign * bound, color="r", ls=":", lw=1.0)
            ax.set_title(f"{kind}: {state}", fontsize=9)
            ax.set_xlabel("lag [s]")
            ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def mean_error(means: Mapping[str, Mapping[str, float]]) -> Figure:
    """Mean error ŷ - y per state [deg/s, deg] for each model ``means[model][state]``."""
    states = list(next(iter(means.values())))
    fig, axes = plt.subplots(1, len(states), figsize=(7, 3), squeeze=False)
    for ax, state in zip(axes[0], states):
        models = list(means)
        ax.bar(models, [np.degrees(means[m][state]) for m in models], color=[f"C{i}" for i in range(len(models))])
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel(f"mean error {state} [{UNITS.get(state, '')}]")
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle("mean error per channel (a sensor offset or a static gain error shows here)")
    fig.tight_layout()
    return fig
