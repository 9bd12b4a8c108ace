"""Frequency responses: the H1 estimate from input/output records, and the analytic LTI response.

The paper's Fig. 5 (yaw transfer function) is the response of the yaw rate ψ̇ [rad/s] to the
steering-wheel angle δsw [rad], so its gain is in 1/s (the same number as (deg/s)/deg).

H1 estimate (Bendat & Piersol, Random Data, ch. 9), Welch averages over n_d Hann segments:

    H1(f) = S_uy(f) / S_uu(f),        γ²(f) = |S_uy(f)|² / (S_uu(f) S_yy(f))

Noise on the output y is uncorrelated with u, so it averages out of S_uy and H1 is unbiased
(noise on the input would bias it low). The random error of the estimate shrinks with the
number of averages and with the coherence:

    ε(|H1|) ≈ std(arg H1) [rad] ≈ sqrt(1 - γ²) / (|γ| sqrt(2 n_d))

so at γ² = 0.9 and n_d ≈ 70 (10 min of data, 16 s segments, 50 % overlap) |H1| is good to
~3 % and the phase to ~1.6° (1 σ). The bias of the estimate comes from the segment's frequency
resolution 1 / segment_s (0.0625 Hz for 16 s): negligible when the system's resonances are
much wider than that, as the well-damped yaw mode of a car (~1 Hz wide) is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal


@dataclass(frozen=True)
class TransferEstimate:
    """A frequency response over frequency_hz [Hz] (1-D, increasing).

    ``response``: complex gain in output units per input unit (1/s for yaw rate per
    steering-wheel angle); ``coherence``: γ² in [0, 1] (all ones for an analytic response);
    ``n_averages``: the number of Welch segments behind an estimate (None when analytic).
    """

    frequency_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    n_averages: int | None = None

    def __post_init__(self) -> None:
        shapes = {np.shape(self.frequency_hz), np.shape(self.response), np.shape(self.coherence)}
        if len(shapes) != 1 or np.ndim(self.frequency_hz) != 1:
            raise ValueError(f"frequency_hz, response and coherence must be 1-D of one length, got {shapes}")

    @classmethod
    def analytic(cls, frequency_hz: np.ndarray, response: np.ndarray) -> TransferEstimate:
        """A noise-free response (γ² = 1), e.g. from ``frequency_response`` for an overlay."""
        frequency_hz = np.asarray(frequency_hz, dtype=float)
        return cls(frequency_hz, np.asarray(response, dtype=complex), np.ones_like(frequency_hz))

    @property
    def magnitude(self) -> np.ndarray:
        """|H| in the response's units."""
        return np.abs(self.response)

    @property
    def phase_deg(self) -> np.ndarray:
        """arg H in degrees, unwrapped along frequency (continuous through ±180°)."""
        return np.degrees(np.unwrap(np.angle(self.response)))

    def band(self, f_min: float, f_max: float) -> TransferEstimate:
        """The estimate on f_min ≤ f ≤ f_max [Hz] (the phase is re-unwrapped on the band)."""
        if not f_min <= f_max:
            raise ValueError(f"need f_min <= f_max, got {f_min} > {f_max}")
        keep = (self.frequency_hz >= f_min) & (self.frequency_hz <= f_max)
        return TransferEstimate(self.frequency_hz[keep], self.response[keep], self.coherence[keep], self.n_averages)


def h1_estimate(
    u: np.ndarray,
    y: np.ndarray,
    sample_rate_hz: float,
    segment_s: float = 16.0,
    overlap: float = 0.5,
) -> TransferEstimate:
    """H1 = S_uy / S_uu and γ² from u (input) and y (output) sampled together at sample_rate_hz.

    Spectral densities by Welch: Hann window of segment_s seconds, ``overlap`` fraction shared
    by neighbouring segments, each segment's mean removed (detrend 'constant'). The 0 Hz bin is
    dropped: detrending empties it. The frequency resolution is 1 / segment_s [Hz].

    Raises ValueError for mismatched or non-finite signals and for records shorter than two
    segments: with a single segment γ² ≡ 1 whatever the noise, so nothing could be judged.
    """
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    if u.ndim != 1 or y.ndim != 1:
        raise ValueError(f"u and y must be 1-D, got shapes {u.shape} and {y.shape}")
    if u.shape != y.shape:
        raise ValueError(f"u and y lengths differ: {u.size} vs {y.size}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise ValueError("u and y must be finite (no NaN or inf)")
    if not sample_rate_hz > 0 or not 0.0 <= overlap < 1.0:
        raise ValueError(f"need sample_rate_hz > 0 and 0 <= overlap < 1, got {sample_rate_hz}, {overlap}")
    nperseg = int(round(segment_s * sample_rate_hz))
    if nperseg < 4:
        raise ValueError(f"segment_s = {segment_s} s gives only {nperseg} samples per segment")
    noverlap = int(round(overlap * nperseg))
    n_averages = (u.size - noverlap) // (nperseg - noverlap)
    if n_averages < 2:
        need = 2 * nperseg - noverlap
        raise ValueError(
            f"signal too short: {u.size} samples ({u.size / sample_rate_hz:.1f} s) give {n_averages} "
            f"Welch segments of {segment_s} s; need at least 2 ({need / sample_rate_hz:.1f} s)")
    if np.ptp(u) == 0:
        raise ValueError("u is constant: it excites no frequency")
    kw = {"fs": sample_rate_hz, "window": "hann", "nperseg": nperseg, "noverlap": noverlap, "detrend": "constant"}
    f, s_uu = signal.welch(u, **kw)
    _, s_yy = signal.welch(y, **kw)
    _, s_uy = signal.csd(u, y, **kw)  # scipy: conj(U) Y, so S_uy / S_uu is the gain u -> y
    f, s_uu, s_yy, s_uy = f[1:], s_uu[1:], s_yy[1:], s_uy[1:]
    with np.errstate(divide="ignore", invalid="ignore"):  # 0/0 only where u has no power
        response = s_uy / s_uu
        coherence = np.nan_to_num(np.abs(s_uy) ** 2 / (s_uu * s_yy), nan=0.0)
    return TransferEstimate(f, response, np.clip(coherence, 0.0, 1.0), int(n_averages))


def frequency_response(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    frequency_hz: np.ndarray,
    dt: float | None = None,
) -> np.ndarray:
    """Complex response H(f) = C (λ I - A)⁻¹ B + D of an LTI system, shape (F, p, m).

    Continuous (dt None): λ = j 2π f for dx/dt = A x + B u. Discrete (dt [s]): λ = exp(j 2π f dt)
    for x[k+1] = A x[k] + B u[k]. Matrices may be numpy arrays or CPU tensors; a system
    without states (A of shape (0, 0)) is the static gain D.
    """
    a, b, c, d = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (a, b, c, d))
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    if frequency_hz.ndim != 1:
        raise ValueError(f"frequency_hz must be 1-D, got shape {frequency_hz.shape}")
    n = a.shape[0] if a.size else 0
    p, m = d.shape
    if n == 0:
        return np.broadcast_to(d.astype(complex), (frequency_hz.size, p, m)).copy()
    if a.shape != (n, n) or b.shape != (n, m) or c.shape != (p, n):
        raise ValueError(f"inconsistent shapes A {a.shape}, B {b.shape}, C {c.shape}, D {d.shape}")
    if dt is None:
        lam = 2j * np.pi * frequency_hz
    elif dt > 0:
        lam = np.exp(2j * np.pi * frequency_hz * dt)
    else:
        raise ValueError(f"dt must be positive or None, got {dt}")
    resolvent_b = np.linalg.solve(lam[:, None, None] * np.eye(n) - a, np.broadcast_to(b, (lam.size, n, m)))
    return c @ resolvent_b + d  # (F, p, m)
