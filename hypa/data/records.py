"""Containers for measured records and data sets (SI units, standard channel names)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hypa.data.decimation import decimate, decimate_time, decimation_factor

SPLITS: tuple[str, ...] = ("train", "val", "test")


@dataclass(frozen=True)
class Record:
    """One measured run: a time base and named channels of equal length, all SI.

    ``time`` [s] (strictly increasing), ``channels`` maps standard names to 1-D float64
    arrays in SI units (rad, rad/s, m/s^2, m/s), ``sample_rate_hz`` [Hz] is the rate of
    ``time``. ``path`` is the file the record was read from.
    """

    path: Path
    time: np.ndarray
    channels: dict[str, np.ndarray]
    sample_rate_hz: float

    def __post_init__(self) -> None:
        for name, values in self.channels.items():
            if values.shape != self.time.shape:
                raise ValueError(
                    f"{self.path.name}: channel {name!r} has shape {values.shape}, "
                    f"time has {self.time.shape}"
                )

    @property
    def name(self) -> str:
        """File name of the record (e.g. ``train_01.csv``)."""
        return self.path.name

    def __len__(self) -> int:
        return int(self.time.size)

    def __getitem__(self, channel: str) -> np.ndarray:
        return self.channels[channel]

    def __contains__(self, channel: object) -> bool:
        return channel in self.channels

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.channels)

    @property
    def duration_s(self) -> float:
        """Covered time span ``len / sample_rate_hz`` [s]."""
        return len(self) / self.sample_rate_hz

    def stack(self, names: Iterable[str]) -> np.ndarray:
        """Channels ``names`` side by side: (len, len(names)) float64."""
        names = list(names)
        if not names:
            return np.zeros((len(self), 0))
        return np.stack([self.channels[name] for name in names], axis=-1)

    def decimated(self, rate_hz: float) -> Record:
        """The record at ``rate_hz`` (anti-aliased, see :mod:`hypa.data.decimation`)."""
        q = decimation_factor(self.sample_rate_hz, rate_hz)
        return Record(
            path=self.path,
            time=decimate_time(self.time, q),
            channels={name: decimate(values, q) for name, values in self.channels.items()},
            sample_rate_hz=self.sample_rate_hz / q,
        )


@dataclass(frozen=True)
class DataSet:
    """All records of a data folder, by split, plus the folder's optional ``dataset.json``.

    ``splits`` maps ``"train"``, ``"val"`` and, when present, ``"test"`` to their records in
    file-name order. ``metadata`` is the parsed ``dataset.json`` (empty when absent); hypa
    reads nothing from it, it is passed on for reports and segment-wise evaluation.
    """

    directory: Path
    splits: dict[str, list[Record]]
    metadata: dict = field(default_factory=dict)

    def __getitem__(self, split: str) -> list[Record]:
        return self.splits[split]

    def __iter__(self) -> Iterator[tuple[str, list[Record]]]:
        return iter(self.splits.items())

    def decimated(self, rate_hz: float) -> DataSet:
        return DataSet(
            directory=self.directory,
            splits={split: [r.decimated(rate_hz) for r in records] for split, records in self},
            metadata=self.metadata,
        )
