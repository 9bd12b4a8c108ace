"""Anti-aliased decimation 1024 Hz -> 32 Hz: pass band kept, aliases removed, ends intact."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hypa.data import DataError, decimate, decimate_time, decimation_factor, lowpass_taps

FS, RATE = 1024.0, 32.0
Q = 32
TIME = np.arange(round(20 * FS)) / FS  # 20 s
EDGE = 32  # output samples (1 s) ignored at each end where a sine's extension is not exact


def _fit_sine(t: np.ndarray, y: np.ndarray, freq: float) -> tuple[float, float]:
    """Amplitude and phase [rad] of the least-squares sine at ``freq`` through (t, y)."""
    basis = np.column_stack([np.sin(2 * np.pi * freq * t), np.cos(2 * np.pi * freq * t)])
    (a, b), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return float(np.hypot(a, b)), float(np.arctan2(b, a))


def test_factor_must_be_an_integer():
    assert decimation_factor(1024, 32) == 32
    with pytest.raises(DataError, match="must be a positive integer"):
        decimation_factor(1024, 30)
    with pytest.raises(DataError, match="must be a positive integer"):
        decimation_factor(32, 1024)


def test_output_sample_i_is_input_sample_i_times_q():
    for n in (TIME.size, TIME.size - 5, 1000):
        t_out = decimate_time(TIME[:n], Q)
        assert decimate(np.zeros(n), Q).size == t_out.size == -(-n // Q)
        np.testing.assert_array_equal(t_out, TIME[:n:Q])


def test_sine_in_the_pass_band_keeps_amplitude_and_phase():
    phase = 0.7
    x = 1.3 * np.sin(2 * np.pi * 2.0 * TIME + phase)
    y, t = decimate(x, Q), decimate_time(TIME, Q)
    amplitude, fitted_phase = _fit_sine(t[EDGE:-EDGE], y[EDGE:-EDGE], 2.0)
    assert amplitude == pytest.approx(1.3, rel=0.01)
    shift_in_samples = (fitted_phase - phase) / (2 * np.pi * 2.0) * RATE
    assert abs(shift_in_samples) < 0.01
    # point by point, too: the decimated sine is the sine sampled at the output times
    np.testing.assert_allclose(y[EDGE:-EDGE], x[::Q][EDGE:-EDGE], atol=0.01 * 1.3)


def test_sine_above_the_output_nyquist_frequency_is_removed():
    x = np.sin(2 * np.pi * 20.0 * TIME + 0.3)
    y = decimate(x, Q)
    # plain slicing would alias it to 12 Hz with full amplitude
    assert np.max(np.abs(x[::Q])) > 0.5
    assert 20 * np.log10(np.max(np.abs(y[EDGE:-EDGE]))) < -40.0


def test_filter_meets_the_documented_pass_and_stop_band():
    taps = lowpass_taps(Q)
    assert taps.size % 2 == 1
    np.testing.assert_allclose(taps, taps[::-1])  # symmetric: linear phase
    _, passband = signal.freqz(taps, worN=np.linspace(0, 10, 50), fs=FS)
    _, stopband = signal.freqz(taps, worN=np.linspace(16, FS / 2, 400), fs=FS)
    assert np.max(np.abs(np.abs(passband) - 1)) < 1e-3
    assert 20 * np.log10(np.max(np.abs(stopband))) < -59.9


@pytest.mark.parametrize("n", [TIME.size, 3 * Q + 7, 5])
def test_constant_and_ramp_pass_unchanged_including_the_ends(n):
    t = TIME[:n]
    for x in (np.full(n, -2.75), 4.0 - 3.0 * t, 0.1 + 12.0 * t):
        np.testing.assert_allclose(decimate(x, Q), x[::Q], rtol=0, atol=1e-12)


def test_ends_of_a_slow_signal_are_not_bent():
    # zero padding would pull the first and last samples towards 0
    x = 5.0 + np.sin(2 * np.pi * 0.3 * TIME)
    y = decimate(x, Q)
    np.testing.assert_allclose(y[[0, 1, -2, -1]], x[::Q][[0, 1, -2, -1]], atol=1e-4)


def test_factor_one_is_a_copy():
    x = np.random.default_rng(0).normal(size=50)
    y = decimate(x, 1)
    np.testing.assert_array_equal(y, x)
    assert y is not x
