"""The Lightning DataModule: declared channels and splits -> SI records -> normalized windows.

It owns the splits, the decimation, the selection and the normalization (fitted on the
training records only, or given, e.g. from a checkpoint), so a model never sees how the data
was prepared.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch.utils.data import DataLoader

from hypa.core.units import unit
from hypa.data.channels import ChannelSpec, check_channels, names_with_role
from hypa.data.dataset import DataFiles, prepare_dataset, read_files
from hypa.data.decimation import decimation_factor
from hypa.data.errors import DataError
from hypa.data.normalization import Normalization
from hypa.data.records import DataSet, Record
from hypa.data.selection import Condition
from hypa.data.signature import DataSignature
from hypa.data.splits import SplitSpec
from hypa.data.windows import WindowDataset


class HypaDataModule(L.LightningDataModule):
    """Measured data of any system for training and evaluating a hybrid model.

    Args:
        data_dir: folder of the files (``train*``, ``val*``, ``test*`` unless ``splits`` names
            them; .csv, .parquet, .mat) and an optional ``dataset.json``.
        channels: the declared channels (:class:`ChannelSpec`), in order (the test bench's:
            ``hypa.paper.testbench.sensors.TESTBENCH_CHANNELS``).
        time_column: the files' time column (its offset removed), or ``None``: sample ``i``
            lies at ``i / sample_rate_hz``.
        time_unit: unit of the time column.
        sample_rate_hz: sample rate of the files [Hz] (checked against the time column).
        rate_hz: model rate [Hz] after anti-aliased decimation by an integer factor;
            ``None``: no decimation. ``dt = 1 / rate_hz``.
        splits: explicit pieces of files per split (:class:`SplitSpec`); ``None``: the files.
        select: conditions ``"channel op number"`` that must hold (e.g. ``"velocity > 5"``);
            records are cut where they fail.
        window: predicted samples N per window.
        past: samples P before the window start (a window holds P + N + 1 samples).
        stride: samples between training window starts.
        eval_stride: samples between val/test window starts.
        batch_size: windows per batch.
        num_workers: DataLoader worker processes.
        normalization: statistics to use instead of fitting them on the training split
            (a :class:`Normalization` or its ``state_dict()``), e.g. from a checkpoint.
        seed: seed of the training-set shuffling.
        auxiliary_inputs: hold every auxiliary channel that varies over the training records as an
            input too (after the declared ones, in declared order; decided in ``setup()``): the
            diagnosis, whose candidates may read a channel the model does not
            (``unread_channel``). A model that reads an auxiliary channel gets it declared an input
            instead (:func:`hypa.data.from_config.read_as_inputs`).
    """

    def __init__(
        self,
        data_dir: Path | str,
        channels: Iterable[ChannelSpec] | Mapping[str, ChannelSpec],
        time_column: str | None = "time",
        time_unit: str = "s",
        sample_rate_hz: float = 1024.0,
        rate_hz: float | None = 32.0,
        splits: SplitSpec | None = None,
        select: Sequence[str] = (),
        window: int = 100,
        past: int = 0,
        stride: int = 5,
        eval_stride: int = 50,
        batch_size: int = 32,
        num_workers: int = 0,
        normalization: Normalization | Mapping[str, Any] | None = None,
        seed: int = 0,
        auxiliary_inputs: bool = False,
    ) -> None:
        super().__init__()
        declared = channels
        if isinstance(declared, Mapping):
            declared = declared.values()
        self.channels: dict[str, ChannelSpec] = check_channels(declared)
        unit(time_unit, "time")
        if rate_hz is not None:
            decimation_factor(sample_rate_hz, rate_hz)  # fail at construction, not in setup()
        for name, value in (("window", window), ("stride", stride), ("eval_stride", eval_stride),
                            ("batch_size", batch_size)):
            if int(value) < 1:
                raise DataError(f"data.{name} must be >= 1, got {value}")
        if int(past) < 0:
            raise DataError(f"data.past must be >= 0, got {past}")
        self._arguments: dict[str, Any] = {  # what with_past builds the same data from, another past aside
            "data_dir": data_dir, "channels": self.channels, "time_column": time_column, "time_unit": time_unit,
            "sample_rate_hz": sample_rate_hz, "rate_hz": rate_hz, "splits": splits, "select": tuple(select),
            "window": window, "past": past, "stride": stride, "eval_stride": eval_stride, "batch_size": batch_size,
            "num_workers": num_workers, "normalization": normalization, "seed": seed,
            "auxiliary_inputs": auxiliary_inputs}
        self.data_dir = Path(data_dir)
        self.input_names = names_with_role(self.channels, "input")
        self.output_names = names_with_role(self.channels, "output")
        self.scheduling_names = names_with_role(self.channels, "scheduling")
        self.eval_channels = names_with_role(self.channels, "evaluation")
        self.time_column = time_column
        self.time_unit = time_unit
        self.sample_rate_hz = float(sample_rate_hz)
        self.rate_hz = float(rate_hz) if rate_hz is not None else self.sample_rate_hz
        self.split_spec = splits
        self.select = tuple(Condition.parse(text, self.channels) for text in select)
        self.window = int(window)
        self.past = int(past)
        self.stride = int(stride)
        self.eval_stride = int(eval_stride)
        self.batch_size = int(batch_size)
        self.num_workers = int(num_workers)
        self.seed = int(seed)
        self.auxiliary_inputs = bool(auxiliary_inputs)
        self._normalization = self._as_normalization(normalization)
        self._files: DataFiles | None = None  # the files as read, kept for with_past (release_files)
        self._data: DataSet | None = None  # SI records at the model rate
        self._datasets: dict[str, WindowDataset] = {}

    # -- what the model and the evaluation need to know --------------------------------

    @property
    def state_names(self) -> tuple[str, ...]:
        """Alias of :attr:`output_names` for older callers (the measured outputs)."""
        return self.output_names

    @property
    def normalized_names(self) -> tuple[str, ...]:
        """Channels the normalization covers: inputs, outputs, scheduling signals."""
        return (*self.input_names, *self.output_names, *self.scheduling_names)

    @property
    def dt(self) -> float:
        """Model time step [s] (1 / rate_hz)."""
        return 1.0 / self.rate_hz

    @property
    def normalization(self) -> Normalization:
        """Statistics of inputs, outputs and scheduling signals; after ``setup()`` or given."""
        if self._normalization is None:
            raise RuntimeError("normalization is fitted in setup(); call setup() first")
        return self._normalization

    @property
    def signature(self) -> DataSignature:
        """What a model needs to know of these data (names, normalization, dt, window, past), after
        ``setup()``: ``HybridModule.from_data`` and ``ComposedModel.from_data`` take it."""
        return DataSignature(self.input_names, self.output_names, self.normalization, self.dt, self.window,
                             self.past, self.eval_names, self.scheduling_names)

    @property
    def eval_names(self) -> tuple[str, ...]:
        """Evaluation channels present in every val/test record, in declared order."""
        evaluated = [*self.records("val"), *self.records("test")]
        return tuple(n for n in self.eval_channels if all(n in r for r in evaluated))

    @property
    def metadata(self) -> dict:
        """The data folder's ``dataset.json`` (``{}`` when absent)."""
        return self._dataset().metadata

    @property
    def files(self) -> tuple[Path, ...]:
        """Every file the data were read from (after ``setup()``): data files and ``dataset.json``."""
        return self._dataset().files

    @property
    def splits(self) -> tuple[str, ...]:
        return tuple(self._dataset().splits)

    def records(self, split: str) -> list[Record]:
        """SI records of a split at the model rate (for whole-record simulation); ``test``
        holds every test set's records in turn; ``[]`` without test data."""
        if split not in ("train", "val", "test"):
            raise KeyError(f"unknown split {split!r}; use 'train', 'val' or 'test'")
        return self._dataset().splits.get(split, [])

    def test_sets(self) -> dict[str, list[Record]]:
        """Test-set name -> its records (``{"test": [...]}`` for unnamed test files)."""
        return dict(self._dataset().test_sets)

    def dataset(self, split: str) -> WindowDataset:
        """Window dataset of a split (after ``setup()``)."""
        if self._data is None:
            raise RuntimeError("windows are built in setup(); call setup() first")
        if split not in self._datasets:
            raise DataError(f"no {split} windows: {self.data_dir} has no {split} data")
        return self._datasets[split]

    # -- Lightning hooks ----------------------------------------------------------------

    def setup(self, stage: str | None = None) -> None:
        """Read, cut, decimate and select all splits, fit the normalization, build windows.

        Idempotent: Lightning calls it once per stage, the files are read once.
        """
        if self._data is None:
            self._data = prepare_dataset(self._read(), self.rate_hz, self.select, self.window, self.past)
        if self.auxiliary_inputs and self._normalization is None:
            self.input_names = (*self.input_names, *varying_auxiliary(self.channels, self._data.train))
        if self._normalization is None:
            self._normalization = Normalization.fit(self._data.train, self.normalized_names)
        if not self._datasets:
            self._build_datasets()

    def with_past(self, past: int) -> HypaDataModule:
        """These data with ``past`` samples before each window, set up: the same as a data module built
        with ``past`` instead (its records selected for ``past + window + 1`` samples, its normalization
        fitted on them unless one was given, its windows), but from the files this one has read (read
        now where it has not), without reading them again."""
        other = type(self)(**{**self._arguments, "past": past})
        other._files = self._read()
        other.setup()
        return other

    def release_files(self) -> None:
        """Forget the files as read (:meth:`with_past` builds from them): the prepared records and
        windows stay; a later :meth:`with_past` reads the files again. The files at their own rate
        may hold many times the prepared records: a data module that trains drops them."""
        self._files = None

    def _read(self) -> DataFiles:
        if self._files is None:
            self._files = read_files(self.data_dir, self.channels, self.split_spec, self.time_column,
                                     self.time_unit, self.sample_rate_hz)
        return self._files

    def _build_datasets(self) -> None:
        assert self._data is not None and self._normalization is not None
        self._check_covers(self._normalization)
        eval_names = self.eval_names
        self._datasets = {}
        for split, records in self._data.splits.items():
            training = split == "train"
            self._datasets[split] = WindowDataset(
                records, self.input_names, self.output_names, self._normalization, self.window,
                self.stride if training else self.eval_stride, self.scheduling_names, self.past,
                eval_names=() if training else eval_names, with_eval=not training,
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
            "output_names": list(self.output_names),
            "scheduling_names": list(self.scheduling_names),
            "rate_hz": self.rate_hz,
            "window": self.window,
            "past": self.past,
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

    @property
    def auxiliary_names(self) -> tuple[str, ...]:
        """The auxiliary channels held as inputs (``auxiliary_inputs``; after ``setup()``), in declared order."""
        return tuple(n for n in self.input_names if self.channels[n].role == "auxiliary")

    def _dataset(self) -> DataSet:
        if self._data is None:
            raise RuntimeError("records are read in setup(); call setup() first")
        return self._data

    def _as_normalization(
        self, value: Normalization | Mapping[str, Any] | None
    ) -> Normalization | None:
        if value is None:
            return None
        normalization = (
            value if isinstance(value, Normalization) else Normalization.from_state_dict(value)
        )
        self._check_covers(normalization)
        return normalization

    def _check_covers(self, normalization: Normalization) -> None:
        missing = [name for name in self.normalized_names if name not in normalization.names]
        if missing:
            raise DataError(
                f"the given normalization has no statistics for {missing} "
                f"(it covers {list(normalization.names)})"
            )


def varying_auxiliary(channels: Mapping[str, ChannelSpec], records: Sequence[Record]) -> tuple[str, ...]:
    """The auxiliary channels of ``channels`` that vary over ``records`` (a constant one, a flag that
    never changes, cannot be normalized, :meth:`Normalization.fit`), in declared order."""
    out = []
    for name in names_with_role(channels, "auxiliary"):
        if not records or not all(name in r for r in records):
            continue
        try:
            Normalization.fit(records, [name])
        except DataError:
            continue
        out.append(name)
    return tuple(out)
