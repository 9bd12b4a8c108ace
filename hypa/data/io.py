"""Reading measured files (CSV, Parquet, MATLAB v5) into validated SI records.

A data folder holds ``train*``, ``val*`` and optionally ``test*`` files (matched on the
file-name stem, sorted by name), one record per file, and optionally a ``dataset.json``
written by the test bench. Every problem raises :class:`DataError` naming the file, the
column and the row; nothing is dropped or repaired silently.
"""

from __future__ import annotations

import difflib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from hypa.data.channels import check_channel_roles, check_mapping_keys, unit_factor
from hypa.data.errors import DataError
from hypa.data.records import SPLITS, DataSet, Record

SUPPORTED_SUFFIXES: tuple[str, ...] = (".csv", ".parquet", ".mat")
METADATA_FILE = "dataset.json"
RATE_TOLERANCE = 0.01  # measured vs configured sample rate (relative)
STEP_TOLERANCE = 0.10  # a single time step vs the median step (relative)


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """All columns of a file by their name in the file, unconverted (file units).

    CSV and Parquet are read with pyarrow; ``.mat`` files (MATLAB v5/v7, not v7.3) with
    ``scipy.io.loadmat``, where every variable is a column.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        import pyarrow.csv

        return _arrow_columns(path, pyarrow.csv.read_csv)
    if suffix == ".parquet":
        import pyarrow.parquet

        return _arrow_columns(path, pyarrow.parquet.read_table)
    if suffix == ".mat":
        return _mat_columns(path)
    raise DataError(
        f"{path}: unsupported file type {path.suffix!r}; use one of {', '.join(SUPPORTED_SUFFIXES)}"
    )


def _arrow_columns(path: Path, reader) -> dict[str, np.ndarray]:
    import pyarrow as pa

    try:
        table = reader(path)
    except (pa.ArrowException, OSError) as error:
        raise DataError(f"{path}: cannot be read ({error})") from error
    names = table.column_names
    duplicated = sorted({name for name in names if names.count(name) > 1})
    if duplicated:
        raise DataError(f"{path}: column name(s) {duplicated} appear more than once")
    # Nulls (empty cells, "nan", "NA") become NaN here and are reported by the finiteness check.
    return {name: table.column(name).to_numpy() for name in names}


def _mat_columns(path: Path) -> dict[str, np.ndarray]:
    from scipy.io import loadmat

    try:
        content = loadmat(path)
    except NotImplementedError as error:  # scipy's answer to an HDF5-based v7.3 file
        raise DataError(
            f"{path}: MATLAB v7.3 (HDF5) files are not supported; save it with "
            f"save(..., '-v7') or export the channels as CSV"
        ) from error
    except (ValueError, OSError) as error:
        raise DataError(f"{path}: cannot be read as a MATLAB file ({error})") from error
    return {name: value for name, value in content.items() if not name.startswith("__")}


def load_record(
    path: Path,
    channels: Sequence[str],
    optional: Sequence[str] = (),
    columns: Mapping[str, str] | None = None,
    units: Mapping[str, str | float] | None = None,
    sample_rate_hz: float = 1024.0,
) -> Record:
    """Read one file into a :class:`Record` with ``time`` plus ``channels`` in SI units.

    ``channels`` must be in the file, ``optional`` ones are taken when present.
    ``columns`` maps a standard name to the file's column name (identity otherwise),
    ``units`` gives the file's unit of a channel (SI otherwise). The time base must be
    strictly increasing with a regular step at ``sample_rate_hz`` [Hz] (1 % on the median
    step, 10 % on every single step).
    """
    path = Path(path)
    columns = dict(columns or {})
    units = dict(units or {})
    raw = read_columns(path)
    wanted = ["time", *channels] + [name for name in optional if columns.get(name, name) in raw]
    values: dict[str, np.ndarray] = {}
    for name in wanted:
        column = columns.get(name, name)
        if column not in raw:
            raise DataError(_missing_column_message(path, name, column, list(raw)))
        factor = unit_factor(units[name], name) if name in units else 1.0
        values[name] = _numeric_column(path, name, column, raw[column]) * factor
    lengths = {name: array.size for name, array in values.items()}
    if len(set(lengths.values())) > 1:
        raise DataError(f"{path}: columns have different lengths: {lengths}")
    time = values.pop("time")
    _check_time(path, columns.get("time", "time"), time, sample_rate_hz)
    return Record(path=path, time=time, channels=values, sample_rate_hz=float(sample_rate_hz))


def _where(path: Path, name: str, column: str) -> str:
    shown = f"column {column!r}" if column == name else f"column {column!r} ({name})"
    return f"{path}: {shown}"


def _row(path: Path, row: int) -> str:
    """Row as a 0-based sample index, and for CSV also the line an editor shows."""
    line = f" (line {row + 2} of the CSV)" if path.suffix.lower() == ".csv" else ""
    return f"row {row}{line}"


def _missing_column_message(path: Path, name: str, column: str, available: list[str]) -> str:
    guess = difflib.get_close_matches(column, available, n=1, cutoff=0.5)
    hint = f" (did you mean {guess[0]!r}?)" if guess else ""
    return (
        f"{path}: column {column!r} for channel {name!r} not found{hint}; the file has: "
        f"{', '.join(available) or 'no columns'}. Map the name with data.columns.{name}=<column>."
    )


def _numeric_column(path: Path, name: str, column: str, raw: np.ndarray) -> np.ndarray:
    """The column as finite float64, or a DataError naming the offending row."""
    array = np.asarray(raw)
    if array.ndim == 2 and 1 in array.shape:  # MATLAB stores vectors as (n, 1) or (1, n)
        array = array.ravel()
    if array.ndim != 1:
        raise DataError(f"{_where(path, name, column)} is not a 1-D column (shape {array.shape})")
    if array.size == 0:
        raise DataError(f"{_where(path, name, column)} has no rows")
    if array.dtype.kind in "biuf":
        values = array.astype(np.float64)
    else:
        values = np.empty(array.size)
        for row, item in enumerate(array):
            try:
                values[row] = np.nan if item is None else float(item)
            except (TypeError, ValueError):
                raise DataError(
                    f"{_where(path, name, column)}, {_row(path, row)}: {item!r} is not a number"
                ) from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise DataError(
            f"{_where(path, name, column)} has {bad.size} missing or non-finite value(s) "
            f"(NaN, inf or empty); first at {_row(path, int(bad[0]))}"
        )
    return values


def _check_time(path: Path, column: str, time: np.ndarray, sample_rate_hz: float) -> None:
    where = _where(path, "time", column)
    if time.size < 2:
        raise DataError(f"{where}: a record needs at least 2 samples, got {time.size}")
    step = np.diff(time)
    backwards = np.flatnonzero(step <= 0)
    if backwards.size:
        row = int(backwards[0]) + 1
        raise DataError(
            f"{where}, {_row(path, row)}: time is not strictly increasing "
            f"({time[row]!r} s after {time[row - 1]!r} s)"
        )
    median = float(np.median(step))
    measured = 1.0 / median
    if abs(measured - sample_rate_hz) > RATE_TOLERANCE * sample_rate_hz:
        raise DataError(
            f"{where}: measured sample rate {measured:.6g} Hz (median step {median * 1e3:.6g} ms) "
            f"differs from the configured sample_rate_hz={sample_rate_hz:g} Hz by more than "
            f"{RATE_TOLERANCE:.0%}; set data.sample_rate_hz or check the time unit "
            f"(data.units.time)"
        )
    irregular = np.flatnonzero(np.abs(step - median) > STEP_TOLERANCE * median)
    if irregular.size:
        row = int(irregular[0]) + 1
        raise DataError(
            f"{where}, {_row(path, row)}: irregular time step of {step[row - 1] * 1e3:.6g} ms "
            f"where the median step is {median * 1e3:.6g} ms ({irregular.size} such step(s)); "
            f"gaps are not interpolated, split the file at the gap"
        )


def find_split_files(data_dir: Path) -> dict[str, list[Path]]:
    """Files of each split: ``train*``, ``val*`` (both required) and ``test*`` (optional)."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise DataError(f"data folder {data_dir} does not exist or is not a folder")
    files = sorted(p for p in data_dir.iterdir() if p.is_file() and not p.name.startswith("."))
    found: dict[str, list[Path]] = {}
    for split in SPLITS:
        matches = [p for p in files if p.stem.startswith(split)]
        for p in matches:
            if p.suffix.lower() not in SUPPORTED_SUFFIXES:
                raise DataError(
                    f"{p}: unsupported file type {p.suffix!r} for a {split} file; use one of "
                    f"{', '.join(SUPPORTED_SUFFIXES)} (or rename it so it does not start with "
                    f"{split!r})"
                )
        if matches:
            found[split] = matches
    for split in ("train", "val"):
        if split not in found:
            raise DataError(
                f"{data_dir}: no {split}* file ({'/'.join(SUPPORTED_SUFFIXES)}); the folder has: "
                f"{', '.join(p.name for p in files) or 'nothing'}"
            )
    return found


def read_metadata(data_dir: Path) -> dict:
    """The folder's ``dataset.json`` as a dict, or ``{}`` when there is none."""
    path = Path(data_dir) / METADATA_FILE
    if not path.is_file():
        return {}
    try:
        content = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise DataError(f"{path}: not valid JSON ({error})") from error
    if not isinstance(content, dict):
        raise DataError(f"{path}: expected a JSON object at the top level")
    return content


def load_dataset(
    data_dir: Path,
    inputs: Sequence[str],
    states: Sequence[str],
    eval_channels: Sequence[str] = (),
    columns: Mapping[str, str] | None = None,
    units: Mapping[str, str | float] | None = None,
    sample_rate_hz: float = 1024.0,
) -> DataSet:
    """Read and validate every record of a data folder (at the file's sample rate, SI).

    Training records hold exactly ``inputs`` and ``states``; evaluation channels are read
    for val/test only, so an evaluation-only channel such as ``rear_wheel_angle`` cannot
    reach a training batch.
    """
    columns = dict(columns or {})
    units = dict(units or {})
    check_channel_roles(inputs, states, eval_channels)
    used = ["time", *inputs, *states, *eval_channels]
    check_mapping_keys(columns, "columns", used)
    check_mapping_keys(units, "units", used)
    for name, unit in units.items():  # fail on a bad unit before reading any file
        unit_factor(unit, name)
    model_channels = [*inputs, *states]
    splits: dict[str, list[Record]] = {}
    for split, paths in find_split_files(data_dir).items():
        optional = () if split == "train" else tuple(eval_channels)
        splits[split] = [
            load_record(path, model_channels, optional, columns, units, sample_rate_hz)
            for path in paths
        ]
    return DataSet(directory=Path(data_dir), splits=splits, metadata=read_metadata(data_dir))
