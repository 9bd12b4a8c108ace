"""Anti-aliased, zero-phase decimation of measured records (the paper: 1024 Hz -> 32 Hz).

Plain slicing (``x[::q]``) would fold everything between the new Nyquist frequency and the
old one back into the band the model sees. Instead each channel is low-pass filtered by a
linear-phase FIR filter whose delay is removed exactly, and then every ``q``-th sample is
kept, so output sample ``i`` lies at the time of input sample ``i * q``.

Filter (``f_N = rate_hz / 2``, the Nyquist frequency after decimation; 16 Hz for 32 Hz):

* pass band ``0 .. 0.625 f_N`` (0 .. 10 Hz at 32 Hz): gain 1 within 0.1 %;
* transition ``0.625 f_N .. f_N`` (10 .. 16 Hz);
* stop band ``>= f_N`` (>= 16 Hz): attenuated by at least 60 dB, so nothing that aliases
  lands in the output with more than 1e-3 of its amplitude.

The paper's steering excitation rolls off above 1 Hz and ends at 5 Hz, well inside the
pass band. Kaiser-window design (``scipy.signal.kaiserord`` / ``firwin``); for 1024 -> 32 Hz
the filter has about 690 taps (0.34 s each side).

Record ends: the signal is extended by point reflection about its first and last sample
(``2 x[0] - x[k]``), which continues constants and ramps exactly and keeps the slope at
the ends, so the filter neither pulls the ends towards zero (zero padding) nor kinks them.

The same filter, designed for a ratio that need not be an integer, is :func:`lowpass`: it
anti-aliases a channel that is resampled onto a slower, unrelated time base (an MDF channel
recorded faster than the rate it is read at, :mod:`hypa.data.mdf`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import signal

from hypa.data.errors import DataError

PASS_BAND_FRACTION = 0.625  # pass-band edge as a fraction of the output Nyquist frequency
STOP_BAND_ATTENUATION_DB = 60.0  # guaranteed; the design aims higher, since a Kaiser
_DESIGN_ATTENUATION_DB = 66.0  # design overshoots its target ripple by about 20 %


def decimation_factor(sample_rate_hz: float, rate_hz: float) -> int:
    """Integer factor ``q = sample_rate_hz / rate_hz``; a non-integer ratio is an error."""
    if not (sample_rate_hz > 0 and rate_hz > 0):
        raise DataError(
            f"rates must be positive, got sample_rate_hz={sample_rate_hz}, rate_hz={rate_hz}"
        )
    ratio = sample_rate_hz / rate_hz
    q = round(ratio)
    if q < 1 or abs(ratio - q) > 1e-9 * ratio:
        raise DataError(
            f"sample_rate_hz / rate_hz = {sample_rate_hz} / {rate_hz} = {ratio:g} must be a "
            f"positive integer for decimation; choose rate_hz among the integer divisors of "
            f"{sample_rate_hz:g} Hz"
        )
    return int(q)


@lru_cache(maxsize=8)
def lowpass_taps(q: int) -> np.ndarray:
    """Linear-phase FIR low-pass for decimation by ``q`` (odd length, unit DC gain).

    Frequencies are relative to the input rate: pass-band edge ``0.625 / (2 q)``, stop-band
    edge ``1 / (2 q)`` of the input sample rate (see the module docstring).
    """
    if q < 2:
        raise ValueError(f"a low-pass is needed only for q >= 2, got {q}")
    return _design(1.0 / q)


@lru_cache(maxsize=16)
def _design(stop: float) -> np.ndarray:
    """The Kaiser FIR with its stop-band edge at ``stop`` (a fraction of the input Nyquist
    frequency: the output Nyquist) and its pass-band edge at ``PASS_BAND_FRACTION * stop``."""
    passband = PASS_BAND_FRACTION * stop
    numtaps, beta = signal.kaiserord(_DESIGN_ATTENUATION_DB, stop - passband)
    numtaps |= 1  # odd length: a symmetric filter with an integer delay of (numtaps - 1) / 2
    taps = signal.firwin(numtaps, 0.5 * (passband + stop), window=("kaiser", beta))
    taps.setflags(write=False)  # shared by the cache
    return taps


def lowpass(x: np.ndarray, ratio: float) -> np.ndarray:
    """Zero-phase anti-aliasing low-pass of a 1-D signal about to be resampled at ``1 / ratio``
    of its rate (``ratio > 1``, any real number); same length and time base as ``x``.

    The pass band, transition and stop band are those of :func:`decimate` for ``q = ratio``
    (stop band from the new Nyquist frequency on), and the ends are extended the same way,
    so for an integer ratio ``lowpass(x, q)[::q]`` equals ``decimate(x, q)``.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"lowpass expects a 1-D signal, got shape {x.shape}")
    if not ratio > 1.0:
        raise ValueError(f"a low-pass is needed only for a ratio > 1, got {ratio}")
    if x.size == 0:
        return x.copy()
    taps = _design(1.0 / float(ratio))
    delay = (taps.size - 1) // 2
    padded = np.pad(x, (delay, delay), mode="reflect", reflect_type="odd")
    return signal.oaconvolve(padded, taps, mode="valid")


def decimate(x: np.ndarray, q: int) -> np.ndarray:
    """Low-pass filter and downsample a 1-D signal by the integer factor ``q``.

    Returns ``ceil(len(x) / q)`` samples; sample ``i`` belongs to the time of ``x[i * q]``.
    Zero phase: a sine inside the pass band keeps its amplitude and phase. ``q == 1``
    returns a copy.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"decimate expects a 1-D signal, got shape {x.shape}")
    if q == 1:
        return x.copy()
    if x.size == 0:
        return x.copy()
    taps = lowpass_taps(q)
    delay = (taps.size - 1) // 2
    # upfirdn evaluates only every q-th output of the convolution; output j is centred on
    # padded sample j*q - delay. Choosing the left pad so that (left + delay) is a multiple
    # of q puts x[0] exactly on an output sample, with no fractional shift.
    left = delay + (-2 * delay) % q
    right = delay + q
    padded = np.pad(x, (left, right), mode="reflect", reflect_type="odd")
    filtered = signal.upfirdn(taps, padded, up=1, down=q)
    first = (left + delay) // q
    count = -(-x.size // q)  # ceil
    return filtered[first : first + count]


def decimate_time(time: np.ndarray, q: int) -> np.ndarray:
    """Time base after decimation: plain slicing, so ``out[i] == time[i * q]`` [s]."""
    return np.asarray(time, dtype=np.float64)[::q].copy()
