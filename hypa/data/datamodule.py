"""The Lightning DataModule: data folder -> decimated records -> normalized windows.

It owns the splits, the decimation and the normalization (fitted on the training split
only, or given, e.g. from a checkpoint), so a model never sees how the data was prepared.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch.utils.data import DataLoader

from hypa.data.channels import (
    DEFAULT_EVAL_CHANNELS,
    DEFAULT_INPUTS,
    DEFAULT_STATES,
    check_channel_roles,
)
from hypa.data.decimation import decimation_factor
from hypa.data.errors import DataError
from hypa.data.io import load_dataset
from hypa.data.normalization import Normalization
from hypa.data.records import DataSet, Record
from hypa.data.windows import WindowDataset, check_record_length


class HypaDataModule(L.LightningDataModule):
    """Measured vehicle-dynamics data for training and evaluating a hybrid model.

    Args:
        data_dir: folder with ``train*``, ``val*`` and optional ``test*`` files
            (.csv, .parquet, .mat) and an optional ``dataset.json``.
        inputs: model inputs (default steering_wheel_angle [rad]).
        states: measured states (default yaw_rate [rad/s], side_slip [rad]).
        eval_channels: SI channels handed to val/test batches when the files have them
            (default rear_wheel_angle [rad], lateral_acceleration [m/s^2]); never trained on.
        columns: standard name -> column name in the files (identity otherwise).
        units: standard name -> unit of the file column (``deg``, ``km/h``, a factor, ...).
        sample_rate_hz: sample rate of the files [Hz] (checked against the time column).
        rate_hz: model rate after anti-aliased decimation [Hz]; ``dt = 1 / rate_hz``.
        window: predicted steps N per window; a window has N + 1 samples.
        stride: samples between training window starts.
        eval_stride: samples between val/test window starts.
        batch_size: windows per batch.
        num_workers: DataLoader worker processes.
        normalization: statistics to use instead of fitting them on the training split
            (a :class:`Normalization` or its ``state_dict()``), e.g. from a checkpoint.
        seed: seed of the training-set shuffling.
    """

    def __init__(
        self,
        data_dir: Path | str,
        inputs: Sequence[str] = DEFAULT_INPUTS,
        states: Sequence[str] = DEFAULT_STATES,
        eval_channels: Sequence[str] = DEFAULT_EVAL_CHANNELS,
        columns: Mapping[str, str] | None = None,
        units: Mapping[str, str | float] | None = None,
        sample_rate_hz: float = 1024.0,
        rate_hz: float = 32.0,
        window: int = 100,
        stride: int = 5,
        eval_stride: int = 50,
        batch_size: int = 32,
        num_workers: int = 0,
        normalization: Normalization | Mapping[str, Any] | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        check_channel_roles(inputs, states, eval_channels)
        decimation_factor(sample_rate_hz, rate_hz)  # fail at construction, not in setup()
        for name, value in (("window", window), ("stride", stride), ("eval_stride", eval_stride),
                            ("batch_size", batch_size)):
            if int(value) < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        self.data_dir = Path(data_dir)
        self.input_names: tuple[str, ...] = tuple(inputs)
        self.state_names: tuple[str, ...] = tuple(states)
        self.eval_channels: tuple[str, ...] = tuple(eval_channels)
        self.columns = dict(columns or {})
        self.units = dict(units or {})
        self.sample_rate_hz = float(sample_rate_hz)
        self.rate_hz = float(rate_hz)
        self.window = int(window)
        self.stride = int(stride)
        self.eval_stride = int(eval_stride)
        self.batch_size = int(batch_size)
        self.num_workers = int(num_workers)
        self.seed = int(seed)
        self._normalization = self._as_normalization(normalization)
        self._data: DataSet | None = None  # decimated records, SI
        self._datasets: dict[str, WindowDataset] = {}

    # -- what the model and the evaluation need to know --------------------------------

    @property
    def dt(self) -> float:
        """Model time step [s] (1 / rate_hz)."""
        return 1.0 / self.rate_hz

    @property
    def normalization(self) -> Normalization:
        """Statistics of inputs and states; available after ``setup()`` or when given."""
        if self._normalization is None:
            raise RuntimeError("normalization is fitted in setup(); call setup() first")
        return self._normalization

    @property
    def eval_names(self) -> tuple[str, ...]:
        """Evaluation channels present in every val/test record, in configured order."""
        evaluated = [r for split in ("val", "test") for r in self.records(split)]
        return tuple(n for n in self.eval_channels if all(n in r for r in evaluated))

    @property
    def metadata(self) -> dict:
        """The data folder's ``dataset.json`` (``{}`` when absent)."""
        return self._dataset().metadata

    @property
    def splits(self) -> tuple[str, ...]:
        return tuple(self._dataset().splits)

    def records(self, split: str) -> list[Record]:
        """Decimated SI records of a split (for whole-record simulation); ``[]`` for an
        absent ``test`` split."""
        if split not in ("train", "val", "test"):
            raise KeyError(f"unknown split {split!r}; use 'train', 'val' or 'test'")
        return self._dataset().splits.get(split, [])

    def dataset(self, split: str) -> WindowDataset:
        """Window dataset of a split (after ``setup()``)."""
        if self._data is None:
            raise RuntimeError("windows are built in setup(); call setup() first")
        if split not in self._datasets:
            raise DataError(f"no {split} windows: {self.data_dir} has no {split}* file")
        return self._datasets[split]

    # -- Lightning hooks ----------------------------------------------------------------

    def setup(self, stage: str | None = None) -> None:
        """Read, validate and decimate all splits, fit the normalization, build windows.

        Idempotent: Lightning calls it once per stage, the files are read once.
        """
        if self._data is None:
            raw = load_dataset(
                self.data_dir,
                self.input_names,
                self.state_names,
                self.eval_channels,
                self.columns,
                self.units,
                self.sample_rate_hz,
            )
            data = raw.decimated(self.rate_hz)
            for records in data.splits.values():
                for record in records:
                    check_record_length(record, self.window, self.sample_rate_hz)
            self._data = data
        if self._normalization is None:
            self._normalization = Normalization.fit(
                self._data["train"], [*self.input_names, *self.state_names]
            )
        if not self._datasets:
            self._build_datasets()

    def _build_datasets(self) -> None:
        assert self._data is not None and self._normalization is not None
        self._check_covers(self._normalization)
        eval_names = self.eval_names
        self._datasets = {}
        for split, records in self._data.splits.items():
            training = split == "train"
            self._datasets[split] = WindowDataset(
                records,
                self.input_names,
                self.state_names,
                self._normalization,
                self.window,
                self.stride if training else self.eval_stride,
                eval_names=() if training else eval_names,
                with_eval=not training,
            )

    def train_dataloader(self) -> DataLoader:
        generator = torch.Generator().manual_seed(self.seed)
        return self._loader(self.dataset("train"), shuffle=True, generator=generator)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.dataset("val"), shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader(self.dataset("test"), shuffle=False)

    def _loader(self, dataset: WindowDataset, shuffle: bool, **kwargs: Any) -> DataLoader:
        return DataLoader(
            dataset,
            batch_size=self.batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
            **kwargs,
        )

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint needs to scale new data like the training data."""
        if self._normalization is None:
            return {}
        return {
            "normalization": self._normalization.state_dict(),
            "input_names": list(self.input_names),
            "state_names": list(self.state_names),
            "rate_hz": self.rate_hz,
            "window": self.window,
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Adopt stored statistics; Lightning calls this after ``setup()``, so windows that
        were already built with fitted statistics are rebuilt."""
        if "normalization" not in state_dict:
            return
        normalization = Normalization.from_state_dict(state_dict["normalization"])
        self._check_covers(normalization)
        self._normalization = normalization
        stored_rate = state_dict.get("rate_hz", self.rate_hz)
        if stored_rate != self.rate_hz:
            raise DataError(
                f"checkpoint was trained at rate_hz={stored_rate}, data module uses {self.rate_hz}"
            )
        if self._data is not None:
            self._build_datasets()

    # -- helpers --------------------------------------------------------------------------

    def _dataset(self) -> DataSet:
        if self._data is None:
            raise RuntimeError("records are read in setup(); call setup() first")
        return self._data

    def _as_normalization(
        self, value: Normalization | Mapping[str, Any] | None
    ) -> Normalization | None:
        if value is None:
            return None
        if isinstance(value, Normalization):
            normalization = value
        else:
            normalization = Normalization.from_state_dict(value)
        self._check_covers(normalization)
        return normalization

    def _check_covers(self, normalization: Normalization) -> None:
        needed = (*self.input_names, *self.state_names)
        missing = [name for name in needed if name not in normalization.names]
        if missing:
            raise DataError(
                f"the given normalization has no statistics for {missing} "
                f"(it covers {list(normalization.names)})"
            )
