"""A data set from its declaration: files -> SI records -> pieces -> decimated -> selected.

The order matters and is fixed:

1. each file named by the splits is read once (:func:`hypa.data.io.load_record`), SI units,
   with its evaluation channels; training pieces drop them, so an evaluation channel never
   reaches a training record;
2. each piece is cut from its file (bounds in file samples);
3. each piece is decimated to ``rate_hz`` on its own (``None``: kept at the file's rate), so
   the anti-aliasing filter never reaches across a split bound;
4. ``select`` cuts each piece into the stretches where its conditions hold; stretches shorter
   than one window (``past + window + 1`` samples) are dropped. Without ``select`` a record
   shorter than one window is an error.

Step 1, the expensive one, is :func:`read_files`; steps 2 to 4, which depend on the window and the
past, are :func:`prepare_dataset`, run again on the same files for another past;
:func:`load_dataset` runs both.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hypa.data.channels import ChannelSpec
from hypa.data.errors import DataError
from hypa.data.files import METADATA_FILE, read_metadata
from hypa.data.io import load_record
from hypa.data.records import DataSet, Record
from hypa.data.selection import Condition, select
from hypa.data.splits import Piece, SplitSpec
from hypa.data.windows import check_record_length

log = logging.getLogger(__name__)


def load_dataset(
    data_dir: Path,
    channels: Mapping[str, ChannelSpec],
    splits: SplitSpec | None = None,
    time_column: str | None = "time",
    time_unit: str = "s",
    sample_rate_hz: float = 1024.0,
    rate_hz: float | None = None,
    select_conditions: Sequence[Condition] = (),
    window: int = 1,
    past: int = 0,
) -> DataSet:
    """Read and prepare every record of a data set (see the module docstring): :func:`read_files`,
    then :func:`prepare_dataset`.

    ``splits`` ``None``: the ``train*``, ``val*`` and ``test*`` files of ``data_dir``.
    """
    files = read_files(data_dir, channels, splits, time_column, time_unit, sample_rate_hz)
    return prepare_dataset(files, rate_hz, select_conditions, window, past)


@dataclass(frozen=True, eq=False)
class DataFiles:
    """The files of a data set as read (step 1 of the module docstring), before any piece is cut:
    the expensive part, which :func:`prepare_dataset` turns into a :class:`DataSet` for a window and
    a past as often as asked, without reading a file again.

    ``records``: file name -> the whole file, SI, with its evaluation channels; ``channels``: the
    declared channels they were read with; ``metadata``: the folder's ``dataset.json`` (empty when
    absent); ``paths``: every file read (the data files and the ``dataset.json``), for a run's checksums.
    """

    directory: Path
    channels: Mapping[str, ChannelSpec]
    splits: SplitSpec
    sample_rate_hz: float
    records: dict[str, Record]
    metadata: dict = field(default_factory=dict)
    paths: tuple[Path, ...] = ()


def read_files(
    data_dir: Path,
    channels: Mapping[str, ChannelSpec],
    splits: SplitSpec | None = None,
    time_column: str | None = "time",
    time_unit: str = "s",
    sample_rate_hz: float = 1024.0,
) -> DataFiles:
    """Read each file the splits name once (:func:`hypa.data.io.load_record`), SI units, with its
    evaluation channels, and the folder's ``dataset.json``.

    ``splits`` ``None``: the ``train*``, ``val*`` and ``test*`` files of ``data_dir``.
    """
    data_dir = Path(data_dir)
    splits = splits if splits is not None else SplitSpec.from_folder(data_dir)
    records: dict[str, Record] = {}
    for name in splits.files():
        path = data_dir / name
        if not path.is_file():
            if data_dir.is_dir():
                present = ", ".join(sorted(p.name for p in data_dir.iterdir())) or "nothing"
                where = f"{data_dir} has: {present}"
            else:
                where = f"{data_dir} does not exist"
            raise DataError(f"{path}: no such file (named in data.splits); {where}")
        records[name] = load_record(path, list(channels.values()), time_column, time_unit,
                                    sample_rate_hz, with_eval=True)
    return DataFiles(
        directory=data_dir,
        channels=dict(channels),
        splits=splits,
        sample_rate_hz=float(sample_rate_hz),
        records=records,
        metadata=read_metadata(data_dir) if data_dir.is_dir() else {},
        paths=(*(data_dir / name for name in records),
               *((data_dir / METADATA_FILE,) if (data_dir / METADATA_FILE).is_file() else ())),
    )


def prepare_dataset(
    files: DataFiles,
    rate_hz: float | None = None,
    select_conditions: Sequence[Condition] = (),
    window: int = 1,
    past: int = 0,
) -> DataSet:
    """The records of the files already read, cut, decimated and selected (steps 2 to 4 of the
    module docstring; cheap beside reading them): what depends on the window and the past is done
    here, so the same files serve another ``past`` (:meth:`hypa.data.HypaDataModule.with_past`)."""
    sample_rate_hz = files.sample_rate_hz
    evaluation = [n for n, c in files.channels.items() if c.role == "evaluation"]
    needed = past + window + 1

    def prepare(what: str, pieces: Sequence[Piece], training: bool) -> list[Record]:
        records = []
        for piece in pieces:
            record = _cut(files.records[piece.file], piece)
            if training:
                record = record.without(evaluation)
            if rate_hz is not None and rate_hz != sample_rate_hz:
                record = record.decimated(rate_hz)
            records.append(record)
        if not select_conditions:
            for record in records:
                check_record_length(record, window, sample_rate_hz, past)
            return records
        kept, longest = select(records, select_conditions, needed)
        if not kept:
            conditions = " and ".join(str(c) for c in select_conditions)
            rate = records[0].sample_rate_hz
            raise DataError(
                f"select [{conditions}] leaves no window in {what}: its longest stretch holds "
                f"{longest} samples ({longest / rate:.3g} s at {rate:g} Hz), one window needs "
                f"past + window + 1 = {needed}; relax the conditions or shorten data.window"
            )
        log.info("%s: %d stretch(es) where %s holds (%d sample(s))", what, len(kept),
                 " and ".join(map(str, select_conditions)), sum(len(r) for r in kept))
        return kept

    splits = files.splits
    return DataSet(
        directory=files.directory,
        train=prepare("the training split", splits.train, training=True),
        val=prepare("the validation split", splits.val, training=False),
        test_sets={name: prepare(f"test set {name!r}", pieces, training=False)
                   for name, pieces in splits.test.items()},
        metadata=files.metadata,
        files=files.paths,
    )


def _cut(record: Record, piece: Piece) -> Record:
    if piece.whole:
        return record
    start, stop = piece.bounds(len(record))
    return record.piece(start, stop, f"{record.file}[{start}:{stop}]")
