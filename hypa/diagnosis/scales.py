"""The diagnosis' time scales, read from the data and the nominal model, never assumed.

A diagnosis runs on kHz data and on data sampled every 10 s alike, so no length in it is a
constant. Every one follows from three things: the sample time ``dt``, the record lengths, and
the nominal model's own modes (:meth:`hypa.models.ComposedModel.eigenvalues`, the eigenvalues
λ of its physics blocks' linear parts at the nominal values):

- ``slowest_s``: the slowest decay time 1/|Re λ| of a mode that settles within the records. An
  integrator (λ = 0 to round-off) never settles and is left out, and so is a **drift**: a real
  mode whose time 1/|λ| is longer than the longest record (``DRIFT_SHARE``): it cannot settle
  in it. Over these records it cannot be told from an integrator (a state of charge whose
  open-circuit-voltage slope makes a fake 24 h "mode" at the mean current, a position under a
  weak spring), and taking it as the time scale would make every stretch the whole record and
  every fit window an hour long (a model without such modes uses ``dt``);
- ``period_s``: the longest period 2π/|Im λ| of an oscillating mode (none: 0);
- **stretches** (the free runs that score a candidate, restarted from the data):
  ``STRETCH_SPAN`` slowest decay times or ``STRETCH_PERIODS`` periods of the slowest
  oscillation, whichever is longer, so that the transient of each restart (a few decay times
  from an estimated state, which also absorbs a part of any offset) is a small share of the score
  and a wrong gain, time constant or resonance has settled into the error. Where all records
  together hold fewer than ``BLOCKS`` such stretches and a cross-validation fold would be fitted
  on fewer than ``FOLD_WINDOWS`` fit windows (short records of a slow system; a long training
  record beside a short validation one), ``BLOCKS`` shorter ones where they are still
  ``1 / STRETCH_SHRINK`` of that (5 decay times, a period) and give the folds more; at least ``MIN_STRETCH``
  samples, at most the longest record (then one stretch per record: the whole record's free run);
- **fit windows** (a candidate's gradient fit): ``FIT_SPAN`` slowest decay times, at least
  ``data.window`` (the user's training windows) unless that is longer and leaves a
  cross-validation fold fewer than ``FOLD_WINDOWS`` of them, and at most an eighth of the longest
  training record, so that the records still hold several windows without overlap (and at most what a
  cross-validation fold's training blocks hold, :attr:`hypa.diagnosis.problem.Problem.fit_window`);
- **residual analysis** (:mod:`hypa.diagnosis.structure`): cross-correlation lags up to
  ``LAG_SPAN`` decay times; the envelope (an oscillation's amplitude) over the longer of one
  decay time and ``ENVELOPE_PERIODS`` periods; Welch segments of ``SEGMENT_SPAN`` decay times (a
  power of two, within the record); frequency bands from the lowest frequency the segments
  resolve (and at least a tenth of the slowest mode's corner frequency 1/(2π·slowest_s)) up to
  Nyquist, in ``BANDS`` steps even in log frequency, below the first one a band of its own.

The spans are numbers of the model's own time constants, the same at every time scale; the
report (``diagnosis.json``, ``data.scales``) lists what they came to.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

STRETCH_SPAN = 50.0  # slowest decay times per scoring stretch ...
STRETCH_PERIODS = 10.0  # ... or periods of the slowest oscillation, whichever is longer
STRETCH_SHRINK = 10.0  # ... or down to 1/10 of that where the records hold fewer than BLOCKS stretches
BLOCKS = 4  # stretches wanted over all records (cross-validation: 2 folds of 2 blocks) ...
FOLD_WINDOWS = 8  # ... where a fold's training blocks would hold fewer fit windows than this (the most
                  # numbers a candidate fits, 7, and one more: the evidence one such fit needs)
FOLDS = 2  # cross-validation folds (hypa.diagnosis.problem)
MIN_STRETCH = 50  # [samples] a stretch is at least this long
FIT_SPAN = 3.0  # slowest decay times per fit window
LAG_SPAN = 3.0  # slowest decay times of cross-correlation lags
ENVELOPE_PERIODS = 3.0  # periods of the slowest oscillation per envelope
SEGMENT_SPAN = 8.0  # slowest decay times per Welch segment
MIN_SEGMENT = 64  # [samples]
BANDS = 3  # log-spaced bands from the lowest resolved frequency to Nyquist
INTEGRATOR = 1e-9  # |λ| below this share of the fastest mode's: an integrator (λ = 0 to round-off)
DRIFT_SHARE = 1.0  # a real mode slower than this share of the longest record: a drift, not a time scale


@dataclass(frozen=True)
class Scales:
    """What the rule in the module docstring gives for one model on one data set (samples, s, Hz)."""

    dt: float  # [s]
    slowest_s: float  # [s] the slowest decay time (dt if no mode decays)
    fastest_s: float  # [s] the fastest mode's time 1/|λ| (dt if no mode)
    period_s: float  # [s] the longest period of an oscillating mode (0: none)
    integrating: bool  # a mode at λ = 0, or one too slow to settle in the records: the free run drifts
    stretch: int  # [samples] of a scoring stretch's free run
    fit_window: int  # [samples] predicted by a fit window
    max_lag: int  # [samples] of the cross-correlations
    envelope: int  # [samples] of the moving RMS that reads an oscillation's amplitude
    segment: int  # [samples] per Welch segment
    band_edges_hz: tuple[float, ...]  # 0, ..., Nyquist

    @classmethod
    def of(cls, eigenvalues: Sequence[complex], dt: float, record_lengths: Sequence[int],
           train_lengths: Sequence[int], window: int) -> Scales:
        """The scales of a model with these modes [1/s] on records of these lengths [samples]."""
        modes = np.asarray(list(eigenvalues), dtype=complex)
        size = float(np.max(np.abs(modes))) if modes.size else 0.0
        longest = max(record_lengths) if record_lengths else MIN_STRETCH
        drift = DRIFT_SHARE * longest * dt  # [s] a decay time longer than this: a drift over these records
        drifting = (np.abs(modes.imag) <= 1e-12 * size) & (np.abs(modes.real) * drift <= 1.0)  # real and slow
        moving = modes[(np.abs(modes) > INTEGRATOR * size) & ~drifting] if size > 0 else modes[:0]
        decaying = moving[moving.real < 0]
        slowest = float(1.0 / np.min(-decaying.real)) if decaying.size else dt
        slowest = max(slowest, dt)
        fastest = max(1.0 / size, dt) if size > 0 else dt
        oscillating = moving[np.abs(moving.imag) > 1e-12 * size]
        period = float(2 * math.pi / np.min(np.abs(oscillating.imag))) if oscillating.size else 0.0
        longest_train = max(train_lengths) if train_lengths else longest
        span = math.ceil(FIT_SPAN * slowest / dt)
        fit_window = max(window, min(span, longest_train // 8))
        wanted = max(STRETCH_SPAN * slowest, STRETCH_PERIODS * period) / dt
        stretch = min(max(math.ceil(wanted), MIN_STRETCH), longest)
        shared = sum(record_lengths) / BLOCKS if record_lengths else wanted
        if wanted / STRETCH_SHRINK <= shared < wanted:  # a fold fitted on too little: BLOCKS shorter stretches?
            shorter = min(max(math.ceil(shared), MIN_STRETCH), longest)
            windows = [fold_windows(record_lengths, s, fit_window) for s in (stretch, shorter)]
            if windows[0] < FOLD_WINDOWS and windows[1] > windows[0]:
                stretch = shorter
        if span < fit_window and fold_windows(record_lengths, stretch, fit_window) < FOLD_WINDOWS:
            fit_window = span  # data.window is longer than the model needs and leaves a fold too few windows
        shortest = min(record_lengths) if record_lengths else longest
        max_lag = max(1, min(math.ceil(LAG_SPAN * slowest / dt), shortest // 4))
        envelope = max(3, min(round(max(slowest, ENVELOPE_PERIODS * period) / dt), max(3, shortest // 8)))
        segment = min(max(MIN_SEGMENT, 2 ** math.ceil(math.log2(max(SEGMENT_SPAN * slowest / dt, 1.0)))), longest)
        nyquist = 0.5 / dt
        low = max(1.0 / (segment * dt), 0.1 / (2 * math.pi * slowest))
        low = min(low, nyquist / 2)
        edges = [0.0, *(low * (nyquist / low) ** (k / BANDS) for k in range(BANDS)), nyquist]
        return cls(dt, slowest, fastest, period, bool(modes.size and moving.size < modes.size), stretch,
                   fit_window, max_lag, envelope, segment, tuple(float(e) for e in edges))

    @property
    def stretch_s(self) -> float:
        return self.stretch * self.dt

    def to_dict(self) -> dict:
        return {**asdict(self), "stretch_s": self.stretch_s}

    def describe(self) -> str:
        """One line: ``slowest mode 4.2 s; stretches of 42 s, fit windows of 500 samples, ...``."""
        return (f"the nominal model's slowest mode decays in {duration(self.slowest_s)}"
                + (f" (oscillates with a period of {duration(self.period_s)})" if self.period_s else "")
                + (", and it integrates" if self.integrating else "")
                + f"; scored on free runs of {duration(self.stretch_s)}, fitted on windows of "
                f"{duration(self.fit_window * self.dt)}")


def block_bounds(length: int, size: int) -> list[tuple[int, int]]:
    """A record of ``length`` samples cut into blocks of ``size`` (start, stop), a remainder shorter
    than half a block joined to the block before it."""
    starts = list(range(0, max(1, length - size // 2), size))
    return list(zip(starts, [*starts[1:], length]))


def fold_windows(record_lengths: Sequence[int], stretch: int, fit_window: int) -> int:
    """The fewest fit windows without overlap that a cross-validation fold is fitted on, with the
    records cut into blocks of ``stretch`` samples as :meth:`hypa.diagnosis.problem.Problem.blocks`
    cuts them (a remainder under half a stretch joins the block before it; ``data.past`` left out);
    with fewer blocks than folds, there is no cross-validation: the windows of all records."""
    blocks = [b - a for n in record_lengths for a, b in block_bounds(n, stretch)]
    counts = [b // max(fit_window, 1) for b in blocks]
    if len(blocks) < FOLDS:
        return sum(counts)
    return min(sum(c for i, c in enumerate(counts) if i % FOLDS != k) for k in range(FOLDS))


def duration(value: float) -> str:
    """A duration [s] rounded to 3 digits in the unit that reads best: ms, s, min or h."""
    if value >= 3600:
        return f"{value / 3600:.3g} h"
    if value >= 120:
        return f"{value / 60:.3g} min"
    return f"{value:.3g} s" if value >= 1 else f"{1e3 * value:.3g} ms"
