"""What a fit leaves unexplained, and where: the one residual analysis of hypa.

Both questions "what does the chosen form leave of a learned block" (:func:`remainder`, the
explanation) and "what remains after the named causes" (:mod:`hypa.diagnosis.structure`, the
diagnosis) are answered with the same measures of a residual r = y - ŷ over several records:

- **size**: Σ r² / Σ (y - ȳ)², the share of the output's variance left (1 - R²);
- **amplitude**: the residual's RMS (and share of its sum of squares) in the quartiles of a
  signal's magnitude (an input's |u|, an output's envelope);
- **band**: Welch power of the residual and of the output per frequency band, the last band
  open above (it holds Nyquist);
- **correlation**: the peak normalized cross-correlation of the residual with a signal over ±lags.

Each caller chooses its own bands, segments and signals; the measures are computed here only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy import signal

from hypa.core.metrics import rms

Spectrum = tuple[np.ndarray, np.ndarray]  # (frequencies [Hz], power spectral density [unit²/Hz])


def unexplained_share(y: np.ndarray, residual: np.ndarray) -> float:
    """Σ r² / Σ (y - ȳ)²: the share of the output's variance the residual leaves (1 - R²)."""
    return float(np.sum(residual**2) / max(np.sum((y - y.mean()) ** 2), 1e-300))


def quartiles(magnitude: np.ndarray, residual: np.ndarray) -> tuple[np.ndarray, list[float], list[float]]:
    """The quartile edges (5) of ``magnitude`` and, per quartile of it, the residual's RMS and its
    share of the residual's sum of squares (the shares sum to 1); an empty quartile has RMS 0."""
    edges = np.quantile(magnitude, [0.0, 0.25, 0.5, 0.75, 1.0])
    which = np.clip(np.searchsorted(edges, magnitude, side="right") - 1, 0, 3)
    total = max(float(np.sum(residual**2)), 1e-300)
    inside = [which == k for k in range(4)]
    return (edges, [rms(residual[i]) if np.any(i) else 0.0 for i in inside],
            [float(np.sum(residual[i] ** 2) / total) for i in inside])


def spectra(records: Sequence[np.ndarray], dt: float, segment: int, detrend: str | bool = "constant") -> list[Spectrum]:
    """Welch's power spectral density of each record [unit²/Hz] over segments of
    min(len, ``segment``) samples; ``detrend`` as scipy's (``False`` keeps the mean: an offset's
    power at 0 Hz)."""
    return [signal.welch(r, fs=1 / dt, nperseg=min(len(r), segment), detrend=detrend) for r in records]


def band_power(records: Sequence[Spectrum], edges: Sequence[float],
               weights: Sequence[float] | None = None) -> list[float]:
    """The spectra's density summed over each band [edges[i], edges[i+1]) (the last band open
    above) and over the records, each times its weight (default 1)."""
    bands = list(pairwise(edges))
    power = [0.0] * len(bands)
    for k, (f, psd) in enumerate(records):
        weight = 1.0 if weights is None else weights[k]
        for i, (lo, hi) in enumerate(bands):
            inside = (f >= lo) & (f < hi) if i < len(bands) - 1 else (f >= lo)
            power[i] += weight * float(psd[inside].sum())
    return power


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


# --- what a fitted form leaves (the explanation's report) --------------------------------------

@dataclass(frozen=True)
class Band:
    """An octave of the frequency axis and the part of the unexplained output that lies in it."""

    low: float  # [Hz]
    high: float  # [Hz]
    share: float  # of the residual's power (all bands sum to 1)
    unexplained: float  # residual power / output power in this band


@dataclass(frozen=True)
class AmplitudeBin:
    """A quartile of an input's magnitude and the error of the fit where the input is that large."""

    low: float  # |input| [input unit]
    high: float
    rms_error: float  # [output unit]
    share: float  # of the residual's sum of squares (all bins sum to 1)


@dataclass(frozen=True)
class Remainder:
    """What the chosen form leaves unexplained on the validation records, and where."""

    share: float  # of the output variance (1 - R²)
    bands: tuple[Band, ...]
    amplitude_signal: str
    amplitude_unit: str
    amplitudes: tuple[AmplitudeBin, ...]

    @property
    def worst_band(self) -> Band:
        return max(self.bands, key=lambda b: b.share)

    @property
    def worst_amplitude(self) -> AmplitudeBin:
        return max(self.amplitudes, key=lambda b: b.rms_error)

    def describe(self) -> str:
        """E.g. ``unexplained 7 %: 45 % of it at 2-4 Hz; largest error where |u| is 0.05-0.1 rad``."""
        band, amp = self.worst_band, self.worst_amplitude
        unit = "" if self.amplitude_unit == "-" else f" {self.amplitude_unit}"
        return (f"unexplained {100 * self.share:.0f} %: {100 * band.share:.0f} % of it at "
                f"{band.low:.3g}-{band.high:.3g} Hz; largest error where |{self.amplitude_signal}| "
                f"is {amp.low:.3g}-{amp.high:.3g}{unit}")


def remainder(y: list[np.ndarray], predicted: list[np.ndarray], u: list[np.ndarray], dt: float,
              name: str, unit: str, octaves: int = 6) -> Remainder:
    """The residual ``y - predicted`` of records by octave band (Welch over segments of at most
    256 samples, the mean kept, averaged over records by length) and by quartile of ``|u|``."""
    residual = [a - b for a, b in zip(y, predicted)]
    y_all, r_all = np.concatenate(y), np.concatenate(residual)
    segment = min(256, *(len(r) for r in residual))
    of_residual = spectra(residual, dt, segment, detrend=False)
    of_output = spectra([v - y_all.mean() for v in y], dt, segment, detrend=False)
    freq = of_residual[0][0]
    edges = [0.0, *(freq[-1] / 2.0 ** np.arange(octaves - 1, -1, -1))]
    edges = [e for e in edges if e == 0.0 or e > 2 * freq[1]]
    weights = [len(r) for r in residual]
    res, out = band_power(of_residual, edges, weights), band_power(of_output, edges, weights)
    total = max(sum(res), 1e-300)
    bands = tuple(Band(float(low), float(high), r / total, r / o if o > 0 else float("nan"))
                  for (low, high), r, o in zip(pairwise(edges), res, out))
    magnitude, quartile_rms, quartile_share = quartiles(np.abs(np.concatenate(u)), r_all)
    amplitudes = tuple(AmplitudeBin(float(magnitude[i]), float(magnitude[i + 1]), quartile_rms[i], quartile_share[i])
                       for i in range(4))
    return Remainder(unexplained_share(y_all, r_all), bands, name, unit, amplitudes)
