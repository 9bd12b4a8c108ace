"""Containers for measured records and data sets (SI units, declared channel names)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hypa.data.decimation import decimate, decimate_time, decimation_factor

SPLITS: tuple[str, ...] = ("train", "val", "test")


@dataclass(frozen=True, eq=False)  # eq: identity (comparing arrays has no single answer)
class Record:
    """One measured stretch: a time base and named channels of equal length, all SI.

    ``time`` [s] (strictly increasing, relative to the file's first sample), ``channels`` maps
    channel names to 1-D float64 arrays in SI units, ``sample_rate_hz`` [Hz] is the rate of
    ``time``. ``path`` is the file the record was read from, ``start`` the file sample index of
    the record's sample 0 and ``label`` a readable name (default: the file name; a piece of a
    file reads ``SNLS80mV.csv[105712:127400]``, in file samples).
    """

    path: Path
    time: np.ndarray
    channels: dict[str, np.ndarray]
    sample_rate_hz: float
    start: int = 0
    label: str | None = None
    step: int = field(default=1)  # file samples per record sample (the decimation factor)

    def __post_init__(self) -> None:
        for name, values in self.channels.items():
            if values.shape != self.time.shape:
                raise ValueError(
                    f"{self.name}: channel {name!r} has shape {values.shape}, "
                    f"time has {self.time.shape}"
                )

    @property
    def name(self) -> str:
        """Readable name: the file name, plus the piece where the record is one."""
        return self.label or self.path.name

    @property
    def file(self) -> str:
        """File name of the record (e.g. ``train_01.csv``), for per-file metadata."""
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

    def without(self, names: Iterable[str]) -> Record:
        """The record without the channels ``names`` (e.g. evaluation channels for training)."""
        dropped = set(names)
        kept = {n: v for n, v in self.channels.items() if n not in dropped}
        return Record(self.path, self.time, kept, self.sample_rate_hz, self.start, self.label,
                      self.step)

    def piece(self, start: int, stop: int, label: str | None = None) -> Record:
        """Samples ``start:stop`` of this record; its label names them in file samples."""
        # file samples of the first and (exclusive) after the last sample taken
        first, last = self.start + start * self.step, self.start + (stop - 1) * self.step + 1
        if label is None:
            label = self.name if (start, stop) == (0, len(self)) else f"{self.file}[{first}:{last}]"
        return Record(self.path, self.time[start:stop],
                      {n: v[start:stop] for n, v in self.channels.items()},
                      self.sample_rate_hz, first, label, self.step)

    def decimated(self, rate_hz: float) -> Record:
        """The record at ``rate_hz`` (anti-aliased, see :mod:`hypa.data.decimation`)."""
        q = decimation_factor(self.sample_rate_hz, rate_hz)
        return Record(
            path=self.path,
            time=decimate_time(self.time, q),
            channels={name: decimate(values, q) for name, values in self.channels.items()},
            sample_rate_hz=self.sample_rate_hz / q,
            start=self.start,
            label=self.label,
            step=self.step * q,
        )


@dataclass(frozen=True)
class DataSet:
    """All records of a data set, by split, plus the folder's optional ``dataset.json``.

    ``train`` and ``val`` are lists of records; ``test_sets`` maps a test-set name to its
    records (``{"test": [...]}`` for test files that are not named; empty without test data).
    ``metadata`` is the parsed ``dataset.json`` (empty when absent); hypa reads nothing from it,
    it is passed on for reports and segment-wise evaluation. ``files``: every file the data set
    was read from (the data files and the ``dataset.json``), for the checksums of a run.
    """

    directory: Path
    train: list[Record]
    val: list[Record]
    test_sets: dict[str, list[Record]] = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    files: tuple[Path, ...] = ()

    @property
    def test(self) -> list[Record]:
        """Every test record, test set after test set."""
        return [record for records in self.test_sets.values() for record in records]

    @property
    def splits(self) -> dict[str, list[Record]]:
        """``train``, ``val`` and, when there are test records, ``test``."""
        out = {"train": self.train, "val": self.val}
        if self.test:
            out["test"] = self.test
        return out

    def __getitem__(self, split: str) -> list[Record]:
        return self.splits[split]
