"""What remains after the named causes: is there structure no catalogue entry explains, and where?

For each output, over the validation free runs of the extended model, four tests:

- **size**: the error left, as a share of the output's variance (1 - R²);
- **amplitude**: the error's RMS in the quartiles of the measured output's envelope (its RMS
  about the mean over the scales' ``envelope`` samples: an oscillation's amplitude, not its phase); a ratio
  of the top to the bottom quartile far from 1 means the physics' gain depends on the amplitude
  (a stiffening spring, a saturating tire);
- **band**: the error's power against the output's power in frequency bands (Welch, bands and
  segments from :class:`~hypa.diagnosis.scales.Scales`); the band
  where the model misses the largest share of the output (among bands holding at least 1 % of
  the output's power: above that, the error is sensor noise);
- **inputs**: the peak normalized cross-correlation of the error with each input and
  scheduling channel over ±``max_lag`` samples (the scales'), against the white-noise bound 2 / √N: a
  correlated error is a dynamic effect of that input the model lacks.

A significant remainder is reported as **unexplained**, with where it lives, rather than named
as the nearest catalogue entry.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy import signal

from hypa.diagnosis.scales import Scales, duration
from hypa.metrics import rms

SIGNIFICANT = 0.002  # error share of the output variance above which a remainder is worth explaining
AMPLITUDE_RATIO = 2.0  # top/bottom quartile error RMS beyond which the error depends on amplitude


@dataclass
class OutputStructure:
    """The remaining error of one output and where it lives (SI units, frequencies in Hz)."""

    output: str
    unit: str
    share: float  # error energy / output variance (1 - R²)
    amplitude_edges: list[float]  # quartile edges of the output's envelope (moving RMS about its mean)
    amplitude_rmse: list[float]  # error RMS per quartile
    amplitude_ratio: float  # top / bottom quartile
    bands_hz: list[tuple[float, float]]
    band_share: list[float]  # error power / output power per band
    worst_band_hz: tuple[float, float]
    correlated: dict[str, dict[str, float]]  # channel -> {"rho", "lag_s", "bound"}
    unexplained: bool
    where: list[str]  # human-readable findings

    def to_dict(self) -> dict:
        return asdict(self)


def correlation_peak(error: np.ndarray, channel: np.ndarray, max_lag: int) -> tuple[float, int]:
    """Peak |ρ| of the normalized cross-correlation over lags -max_lag..max_lag (channel leading > 0)."""
    e = (error - error.mean()) / (error.std() or 1.0)
    c = (channel - channel.mean()) / (channel.std() or 1.0)
    n = len(e)
    best, at = 0.0, 0
    for lag in range(-max_lag, max_lag + 1):
        rho = float(np.dot(e[lag:], c[: n - lag]) / n) if lag >= 0 else float(np.dot(e[:lag], c[-lag:]) / n)
        if abs(rho) > abs(best):
            best, at = rho, lag
    return best, at


def analyze_output(name: str, unit: str, measured: Sequence[np.ndarray], predicted: Sequence[np.ndarray],
                   channels: Mapping[str, Sequence[np.ndarray]], scales: Scales,
                   unused: Collection[str] = ()) -> OutputStructure:
    """The four tests for one output over several records (each record's arrays aligned), at the
    model's and the data's time scales (``scales``: lags, envelope, Welch segments and bands).
    ``unused``: the channels the model does not read (a correlation with one is an effect of a
    signal the model lacks, reported as unexplained, not absorbed into a bias)."""
    dt, max_lag, envelope = scales.dt, scales.max_lag, scales.envelope
    y = np.concatenate(measured)
    err = y - np.concatenate(predicted)
    share = float(np.sum(err**2) / max(np.sum((y - y.mean()) ** 2), 1e-300))
    kernel = np.ones(envelope) / envelope
    distance = np.concatenate([np.sqrt(np.convolve((m - y.mean()) ** 2, kernel, mode="same")) for m in measured])
    edges = np.quantile(distance, [0.0, 0.25, 0.5, 0.75, 1.0])
    bins = np.clip(np.searchsorted(edges, distance, side="right") - 1, 0, 3)
    rmse = [rms(err[bins == k]) if np.any(bins == k) else 0.0 for k in range(4)]
    ratio = rmse[3] / rmse[0] if rmse[0] > 0 else float("inf")
    nyquist = 0.5 / dt
    bands = list(zip(scales.band_edges_hz[:-1], scales.band_edges_hz[1:]))
    band_share, band_power = [], []
    errors = [m - p for m, p in zip(measured, predicted)]
    per_record = [(e, m) for e, m in zip(errors, measured) if len(m) >= 16]
    for lo, hi in bands:
        e_pow = y_pow = 0.0
        for e_r, y_r in per_record:
            f, pe = signal.welch(e_r, fs=1 / dt, nperseg=min(len(e_r), scales.segment))
            _, py = signal.welch(y_r - y_r.mean(), fs=1 / dt, nperseg=min(len(y_r), scales.segment))
            inside = (f >= lo) & (f < hi) if hi < nyquist else (f >= lo)
            e_pow += float(pe[inside].sum())
            y_pow += float(py[inside].sum())
        band_share.append(e_pow / y_pow if y_pow > 0 else 0.0)
        band_power.append(y_pow)
    # a band where the output has (almost) no power says nothing about the model: sensor noise
    carries = [p >= 0.01 * sum(band_power) for p in band_power]
    judged = [share_ if ok else 0.0 for share_, ok in zip(band_share, carries)]
    worst = bands[int(np.argmax(judged))]
    correlated = {}
    for channel, arrays in channels.items():
        peaks = [correlation_peak(e, c, min(max_lag, len(e) // 4)) for e, c in zip(errors, arrays) if len(e) > 8]
        if not peaks:
            continue
        weights = [len(e) for e in errors if len(e) > 8]
        rho = float(np.average([p[0] for p in peaks], weights=weights))
        lag = int(round(np.average([p[1] for p in peaks], weights=weights)))
        correlated[channel] = {"rho": rho, "lag_s": lag * dt, "bound": 2.0 / np.sqrt(len(err))}
    where = []
    if ratio > AMPLITUDE_RATIO:
        where.append(f"grows with amplitude: error RMS {ratio:.1f}× larger where the {name} amplitude (RMS) > "
                     f"{edges[3]:.3g} {unit} than below {edges[1]:.3g} {unit}")
    elif ratio < 1 / AMPLITUDE_RATIO:
        where.append(f"largest at small amplitude ({name} RMS < {edges[1]:.3g} {unit}): error RMS "
                     f"{1 / ratio:.1f}× the large-amplitude one")
    if judged and max(judged) > 2 * share:
        where.append(f"in {worst[0]:.3g}–{worst[1]:.3g} Hz the model misses {100 * max(judged):.3g} % "
                     f"of the output's power there (overall {100 * share:.3g} %)")
    for channel, c in correlated.items():
        if abs(c["rho"]) > max(0.2, 3 * c["bound"]):
            what = f"{channel}, a measured channel the model does not use" if channel in unused else channel
            lag = ("-" if c["lag_s"] < 0 else "") + duration(abs(c["lag_s"]))
            where.append(f"correlated with {what}: ρ = {c['rho']:.2f} at {lag}")
    unexplained = share > SIGNIFICANT and bool(where)
    return OutputStructure(name, unit, share, [float(e) for e in edges], rmse, float(ratio), bands, band_share,
                           worst, correlated, unexplained, where)
