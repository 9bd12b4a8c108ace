"""Steering-robot programmes: stochastic steering-wheel angle and deterministic manoeuvres.

All signals are steering-wheel angles delta_sw [rad] sampled at ``sample_rate_hz`` [Hz]
that start and end at zero, so parts can be concatenated without jumps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hypa.paper.testbench.config import (
    ExcitationConfig,
    LaneChangeConfig,
    RecordConfig,
    SineSweepConfig,
    StepSteerConfig,
    StochasticConfig,
)

# Independent random streams per record seed: the excitation must not change when the
# sensor noise settings change, and vice versa.
EXCITATION_STREAM = 0
NOISE_STREAM = 1
# Clip / band-limit passes of the crest-factor reduction; 20 reach the target within ~2 %.
CREST_ITERATIONS = 20


@dataclass(frozen=True)
class Segment:
    """A named part of a record, the half-open time interval [start_s, end_s) [s]."""

    name: str
    start_s: float
    end_s: float


def _samples(duration_s: float, sample_rate_hz: float) -> int:
    return int(round(duration_s * sample_rate_hz))


def raised_cosine_ramp(n: int) -> np.ndarray:
    """n samples rising smoothly from 0 (exclusive) to 1 (exclusive): 0.5 (1 - cos)."""
    return 0.5 * (1.0 - np.cos(np.pi * (np.arange(n) + 0.5) / n))


def _fade(signal: np.ndarray, fade_samples: int) -> np.ndarray:
    fade_samples = min(fade_samples, len(signal) // 2)
    window = np.ones(len(signal))
    if fade_samples > 0:
        ramp = raised_cosine_ramp(fade_samples)
        window[:fade_samples] = ramp
        window[-fade_samples:] = ramp[::-1]
    return signal * window


def excitation_gain(frequency_hz: np.ndarray, break_hz: float, cutoff_hz: float) -> np.ndarray:
    """Amplitude shaping |H(f)|: 1 up to the break, break/f above (PSD ~ 1/f^2), 0 above cut-off.

    The mean (f = 0) is removed: a steering robot excites around straight ahead.
    """
    f = np.asarray(frequency_hz, dtype=float)
    gain = np.where(f <= break_hz, 1.0, break_hz / np.maximum(f, break_hz))
    gain[(f > cutoff_hz) | (f == 0.0)] = 0.0
    return gain


def stochastic_steering(
    duration_s: float,
    sample_rate_hz: float,
    seed: int,
    break_hz: float,
    config: StochasticConfig,
) -> np.ndarray:
    """Band-limited random steering-wheel angle [rad], peak |delta_sw| = ``config.amplitude``.

    White Gaussian noise is shaped in the frequency domain with :func:`excitation_gain`
    (deterministic by ``seed``). A Gaussian signal's peak is ~3.5-4 times its RMS, so
    scaled to its peak it would rarely leave the linear range (a_y < 4 m/s^2). When
    ``config.crest_factor`` is set, the signal is scaled to RMS = amplitude / crest_factor
    and alternately clipped at the amplitude and band-limited again (crest-factor
    reduction: the PSD shape stays, the robot's angle range is used). Finally it is faded
    in and out and scaled to the peak amplitude.
    """
    n = _samples(duration_s, sample_rate_hz)
    rng = np.random.default_rng([seed, EXCITATION_STREAM])
    spectrum = np.fft.rfft(rng.standard_normal(n))
    frequency = np.fft.rfftfreq(n, d=1.0 / sample_rate_hz)
    gain = excitation_gain(frequency, break_hz, config.cutoff_hz)
    fade_samples = _samples(config.fade_s, sample_rate_hz)
    signal = _fade(np.fft.irfft(spectrum * gain, n), fade_samples)
    if config.crest_factor is not None:
        amplitude, in_band = config.amplitude, gain > 0.0
        signal *= amplitude / (config.crest_factor * np.std(signal))
        for _ in range(CREST_ITERATIONS):
            clipped = np.clip(signal, -amplitude, amplitude)
            signal = np.fft.irfft(np.fft.rfft(clipped) * in_band, n)
        signal = _fade(signal, fade_samples)
    return signal * (config.amplitude / np.max(np.abs(signal)))


def _place(
    duration_s: float, sample_rate_hz: float, start_s: float, part: np.ndarray, name: str
) -> np.ndarray:
    n = _samples(duration_s, sample_rate_hz)
    start = _samples(start_s, sample_rate_hz)
    if start + len(part) > n:
        raise ValueError(f"{name}: manoeuvre needs more than duration_s = {duration_s} s")
    signal = np.zeros(n)
    signal[start : start + len(part)] = part
    return signal


def lane_change(config: LaneChangeConfig, sample_rate_hz: float) -> np.ndarray:
    """ISO-3888-like double lane change [rad].

    One full sine period of steering moves the car one lane over (steer in, counter-steer
    to straighten), a straight hold, then the mirrored period brings it back.
    """
    n_change = _samples(config.change_s, sample_rate_hz)
    one = config.amplitude * np.sin(2.0 * np.pi * np.arange(n_change) / n_change)
    hold = np.zeros(_samples(config.hold_s, sample_rate_hz))
    part = np.concatenate([one, hold, -one])
    return _place(config.duration_s, sample_rate_hz, config.lead_s, part, "lane_change")


def step_steer(config: StepSteerConfig, sample_rate_hz: float) -> np.ndarray:
    """Ramped step steer [rad]: raised-cosine ramp up, hold, ramp back to zero."""
    ramp = config.amplitude * raised_cosine_ramp(_samples(config.ramp_s, sample_rate_hz))
    hold = np.full(_samples(config.hold_s, sample_rate_hz), config.amplitude)
    part = np.concatenate([ramp, hold, ramp[::-1]])
    return _place(config.duration_s, sample_rate_hz, config.lead_s, part, "step_steer")


def sine_sweep(config: SineSweepConfig, sample_rate_hz: float) -> np.ndarray:
    """Logarithmic sine sweep [rad] from ``start_hz`` to ``end_hz`` at constant amplitude.

    Instantaneous frequency f(t) = f0 (f1/f0)^(t/T) over the sweep time T, phase
    2 pi f0 T / ln(f1/f0) ((f1/f0)^(t/T) - 1); the amplitude fades in and out.
    """
    sweep_s = config.duration_s - 2.0 * config.lead_s
    if sweep_s <= 2.0 * config.fade_s:
        raise ValueError("sine_sweep: duration_s too short for lead_s and fade_s")
    t = np.arange(_samples(sweep_s, sample_rate_hz)) / sample_rate_hz
    growth = np.log(config.end_hz / config.start_hz)
    phase = 2.0 * np.pi * config.start_hz * sweep_s / growth * np.expm1(growth * t / sweep_s)
    part = _fade(config.amplitude * np.sin(phase), _samples(config.fade_s, sample_rate_hz))
    return _place(config.duration_s, sample_rate_hz, config.lead_s, part, "sine_sweep")


def steering_programme(
    record: RecordConfig, excitation: ExcitationConfig, sample_rate_hz: float
) -> tuple[np.ndarray, list[Segment]]:
    """The full steering-wheel angle of one record [rad] and its segments.

    The stochastic part comes first, then each manoeuvre of ``record.maneuvers`` in order.
    """
    parts = [
        stochastic_steering(
            record.stochastic_duration_s,
            sample_rate_hz,
            record.seed,
            record.break_frequency_hz,
            excitation.stochastic,
        )
    ]
    names = ["stochastic"]
    builders = {"lane_change": lane_change, "step_steer": step_steer, "sine_sweep": sine_sweep}
    for name in record.maneuvers:
        parts.append(builders[name](getattr(excitation, name), sample_rate_hz))
        names.append(name)
    segments, start = [], 0
    for name, part in zip(names, parts):
        segments.append(Segment(name, start / sample_rate_hz, (start + len(part)) / sample_rate_hz))
        start += len(part)
    return np.concatenate(parts), segments
