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
as the nearest catalogue entry. The measures are hypa's one residual analysis
(:mod:`hypa.explain.residual`, which also tells what an explained form leaves of a learned block).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass
from itertools import pairwise

import numpy as np

from hypa.diagnosis.scales import Scales, duration
from hypa.explain.residual import band_power, correlation_peak, quartiles, spectra, unexplained_share

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
    share = unexplained_share(y, err)
    kernel = np.ones(envelope) / envelope
    distance = np.concatenate([np.sqrt(np.convolve((m - y.mean()) ** 2, kernel, mode="same")) for m in measured])
    edges, rmse, _ = quartiles(distance, err)
    ratio = rmse[3] / rmse[0] if rmse[0] > 0 else float("inf")
    bands = list(pairwise(scales.band_edges_hz))
    errors = [m - p for m, p in zip(measured, predicted)]
    per_record = [(e, m) for e, m in zip(errors, measured) if len(m) >= 16]
    e_pow = band_power(spectra([e for e, _ in per_record], dt, scales.segment), scales.band_edges_hz)
    y_pow = band_power(spectra([m - m.mean() for _, m in per_record], dt, scales.segment), scales.band_edges_hz)
    band_share = [e / p if p > 0 else 0.0 for e, p in zip(e_pow, y_pow)]
    # a band where the output has (almost) no power says nothing about the model: sensor noise
    carries = [p >= 0.01 * sum(y_pow) for p in y_pow]
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
