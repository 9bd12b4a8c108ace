"""Measured files as they are: every column by its name in the file, in the file's units.

Formats: CSV (read with pyarrow; a header line starting with ``#``, as some loggers write it,
is read as the header), Parquet, and MATLAB v5/v7 ``.mat`` (every variable is a column; a
1x1 variable such as a gain is a scalar usable in expressions). An unnamed CSV column with
no values (from trailing commas, e.g. ``"V1","V2",``) is dropped. ASAM MDF files (``.mf4``,
``.mdf``) hold channels on time bases of their own; they are read channel by channel by
:mod:`hypa.data.mdf`, not as columns here.

A data folder holds ``train*``, ``val*`` and optionally ``test*`` files (matched on the stem,
sorted by name) and an optional ``dataset.json`` written by the test bench.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hypa.core.trust import read_bounded
from hypa.data.errors import DataError

TABLE_SUFFIXES: tuple[str, ...] = (".csv", ".parquet", ".mat")  # one time base, columns
MDF_SUFFIXES: tuple[str, ...] = (".mf4", ".mdf")  # ASAM MDF 4 (and 3): a time base per group
SUPPORTED_SUFFIXES: tuple[str, ...] = TABLE_SUFFIXES + MDF_SUFFIXES
METADATA_FILE = "dataset.json"
SPLIT_PREFIXES: tuple[str, ...] = ("train", "val", "test")


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """All columns of a file by their name in the file, unconverted (file units)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    if suffix == ".csv":
        return _csv_columns(path)
    if suffix == ".parquet":
        import pyarrow.parquet

        return _arrow_columns(path, pyarrow.parquet.read_table)
    if suffix == ".mat":
        return _mat_columns(path)
    if suffix in MDF_SUFFIXES:
        raise DataError(
            f"{path}: an MDF file has no columns on one time base; read it with "
            f"hypa.data.load_record (or hypa.data.mdf.read_signals for the raw channels)"
        )
    raise DataError(
        f"{path}: unsupported file type {path.suffix!r}; use one of {', '.join(SUPPORTED_SUFFIXES)}"
    )


def _csv_columns(path: Path) -> dict[str, np.ndarray]:
    import pyarrow.csv

    with path.open("r", errors="replace") as file:
        first = file.readline()
    read_options = None
    if first.startswith("#"):  # "# time(s),x(m),...": the header behind a comment sign
        names = [name.strip().strip('"') for name in first.lstrip("#").strip().split(",")]
        read_options = pyarrow.csv.ReadOptions(column_names=names, skip_rows=1)
    return _arrow_columns(path, lambda p: pyarrow.csv.read_csv(p, read_options=read_options))


def _arrow_columns(path: Path, reader) -> dict[str, np.ndarray]:
    import pyarrow as pa

    try:
        table = reader(path)
    except (pa.ArrowException, OSError) as error:
        raise DataError(f"{path}: cannot be read ({error})") from error
    names = table.column_names
    duplicated = sorted({name for name in names if names.count(name) > 1 and name})
    if duplicated:
        raise DataError(f"{path}: column name(s) {duplicated} appear more than once")
    # Nulls (empty cells, "nan", "NA") become NaN here and are reported by the finiteness check.
    return {
        name: table.column(name).to_numpy()
        for name in names
        if name.strip() or table.column(name).null_count < table.num_rows
    }


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


def find_split_files(data_dir: Path) -> dict[str, list[Path]]:
    """Files of each split: ``train*``, ``val*`` (both required) and ``test*`` (optional)."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise DataError(f"data folder {data_dir} does not exist or is not a folder")
    files = sorted(p for p in data_dir.iterdir() if p.is_file() and not p.name.startswith("."))
    found: dict[str, list[Path]] = {}
    for split in SPLIT_PREFIXES:
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
                f"{', '.join(p.name for p in files) or 'nothing'} (or declare data.splits)"
            )
    return found


def read_metadata(data_dir: Path) -> dict:
    """The folder's ``dataset.json`` as a dict, or ``{}`` when there is none."""
    path = Path(data_dir) / METADATA_FILE
    if not path.is_file():
        return {}
    try:
        content = json.loads(read_bounded(path, what=METADATA_FILE))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as error:
        raise DataError(f"{path}: not valid JSON ({error})") from error
    if not isinstance(content, dict):
        raise DataError(f"{path}: expected a JSON object at the top level")
    return content
