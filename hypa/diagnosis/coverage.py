"""Whether the validation records cover the operating range the training records span.

The diagnosis judges every candidate on the validation records. Where those see only a part of
what the training saw (a slow-down into the pits, a test at half the amplitude), a cause that
matters elsewhere can look useless there, and a stand-in can look right. Per measured channel
(outputs, inputs, scheduling channels), over the records of each split:

- **range**: the span between the 1st and the 99th percentile; the validation's span must
  overlap at least ``COVERED`` of the training's;
- **amplitude**: the RMS about the training's mean; the validation's must be at least
  ``AMPLITUDE`` times the training's.

A channel that fails either is reported (``diagnosis.json`` ``coverage``, a section of
``diagnosis.md`` and a printed line); nothing is changed by it: the user decides whether to
choose other validation records (``data.splits``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from hypa.core.metrics import rms
from hypa.data import HypaDataModule

COVERED = 0.7  # share of the training's 1-99 % span the validation's must overlap
AMPLITUDE = 0.5  # the validation's RMS about the training mean, at least this share of the training's


@dataclass(frozen=True)
class ChannelCoverage:
    """One channel's range and amplitude in each split [SI] and what the validation covers."""

    channel: str
    role: str  # output | input | scheduling
    train: tuple[float, float]  # 1st, 99th percentile
    val: tuple[float, float]
    covered: float  # share of the training's span inside the validation's
    amplitude: float  # the validation's RMS about the training mean / the training's

    @property
    def short(self) -> bool:
        return self.covered < COVERED or self.amplitude < AMPLITUDE

    def describe(self, factor: float = 1.0, unit: str = "") -> str:
        """``vx: the validation records span 0.5–12 m/s of the training's 0.2–31 m/s (38 %), ...``."""
        def span(lo_hi: tuple[float, float]) -> str:
            return f"{lo_hi[0] * factor:.3g}–{lo_hi[1] * factor:.3g} {unit}".rstrip()

        return (f"{self.channel} ({self.role}): the validation records span {span(self.val)} of the training's "
                f"{span(self.train)} ({100 * self.covered:.0f} % of it), at {self.amplitude:.2g}× its amplitude")

    def to_dict(self) -> dict:
        return {**asdict(self), "short": self.short}


def coverage(dm: HypaDataModule) -> list[ChannelCoverage]:
    """Every measured channel's coverage (outputs, inputs, then scheduling channels)."""
    out = []
    roles = [*((n, "output") for n in dm.output_names), *((n, "input") for n in dm.input_names),
             *((n, "scheduling") for n in dm.scheduling_names)]
    for name, role in roles:
        train, val = (_values(dm.records(split), name) for split in ("train", "val"))
        if train.size < 2 or val.size < 2:
            continue
        t_lo, t_hi = (float(v) for v in np.percentile(train, [1, 99]))
        v_lo, v_hi = (float(v) for v in np.percentile(val, [1, 99]))
        width = t_hi - t_lo
        covered = max(0.0, min(t_hi, v_hi) - max(t_lo, v_lo)) / width if width > 0 else 1.0
        mean = float(train.mean())
        spread = rms(train - mean)
        amplitude = rms(val - mean) / spread if spread > 0 else 1.0
        out.append(ChannelCoverage(name, role, (t_lo, t_hi), (v_lo, v_hi), covered, amplitude))
    return out


def short_lines(dm: HypaDataModule, channels: Sequence[ChannelCoverage]) -> list[str]:
    """One line per channel the validation records do not cover, in its display unit."""
    return [c.describe(dm.channels[c.channel].display_factor, dm.channels[c.channel].display_unit)
            for c in channels if c.short]


def _values(records, name: str) -> np.ndarray:
    arrays = [np.asarray(r[name], dtype=float) for r in records]
    return np.concatenate(arrays) if arrays else np.zeros(0)
