"""The default data of hypa: a folder of measured-data files, generated once and cached.

A dataset folder holds one ``<record>.parquet`` per record of the config and
``dataset.json``: the full config, its hash, the column units and per file its segments
as half-open time intervals [start_s, end_s) [s], its size ``bytes`` and its ``sha256``.
A cached folder is checked against these before it is used (:func:`cache_damage`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from hypa.core.metadata import sha256
from hypa.paper.testbench.config import TestbenchConfig
from hypa.paper.testbench.memory import check_fits
from hypa.paper.testbench.records import COLUMNS, SimulatedRecord, simulate_record, write_record
from hypa.paper.testbench.sensors import UNITS

log = logging.getLogger(__name__)

# Bump whenever the code changes what a given config generates: it is part of the cache key.
FORMAT_VERSION = 2
DESCRIPTION_FILE = "dataset.json"


def config_hash(config: TestbenchConfig) -> str:
    """Short (12 hex digits) SHA-256 of the config and :data:`FORMAT_VERSION`."""
    payload = json.dumps(
        {"format_version": FORMAT_VERSION, "config": config.to_dict()}, sort_keys=True
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:12]


def default_cache_dir() -> Path:
    """``$HYPA_CACHE_DIR/testbench``, else ``~/.cache/hypa/testbench``."""
    root = os.environ.get("HYPA_CACHE_DIR")
    return (Path(root) if root else Path.home() / ".cache" / "hypa") / "testbench"


def _simulate_and_write(config: TestbenchConfig, name: str, out_dir: Path) -> dict[str, Any]:
    start = time.perf_counter()
    record: SimulatedRecord = simulate_record(config, name)
    path = out_dir / f"{name}.parquet"
    write_record(path, record.columns)
    samples = len(record.columns["time"])
    log.info(
        "testbench: %s done (%.0f s of data, %d samples) in %.1f s",
        name,
        record.duration_s,
        samples,
        time.perf_counter() - start,
    )
    return {
        "samples": samples,
        "duration_s": record.duration_s,
        "segments": [
            {"name": s.name, "start_s": s.start_s, "end_s": s.end_s} for s in record.segments
        ],
        "bytes": path.stat().st_size,
        "sha256": sha256(path),
    }


def generate_dataset(config: TestbenchConfig, out_dir: Path) -> Path:
    """Simulate every record of ``config`` into ``out_dir`` (created); returns ``out_dir``.

    Files of the same name are overwritten; other files in ``out_dir`` are left alone. Settings
    whose data would not fit into this machine's memory are refused first (:func:`check_fits`).
    """
    check_fits(config)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = list(config.records)
    log.info("testbench: simulating %s into %s", ", ".join(names), out_dir)
    start = time.perf_counter()
    infos = [_simulate_and_write(config, name, out_dir) for name in names]
    description = {
        "format_version": FORMAT_VERSION,
        "config_hash": config_hash(config),
        "sample_rate_hz": config.sample_rate_hz,
        "columns": {name: UNITS[name] for name in COLUMNS},
        "files": {f"{name}.parquet": info for name, info in zip(names, infos)},
        "config": config.to_dict(),
    }
    (out_dir / DESCRIPTION_FILE).write_text(json.dumps(description, indent=2) + "\n")
    log.info("testbench: generated in %.1f s", time.perf_counter() - start)
    return out_dir


def load_description(folder: Path) -> dict[str, Any]:
    """The parsed ``dataset.json`` of a dataset folder."""
    return json.loads((Path(folder) / DESCRIPTION_FILE).read_text())


def cache_damage(folder: Path, config: TestbenchConfig) -> str | None:
    """Why the cached dataset folder of ``config`` cannot be used, as a short phrase
    (``train_2.parquet missing``); ``None`` when it is intact.

    Intact: ``dataset.json`` is readable JSON written for this config (same hash, format
    version and config), it lists exactly the config's records, and each listed file has its
    recorded size [bytes] and SHA-256. A file the description does not list (other than hidden
    ones) is damage too, because a data folder's reader takes every ``train*``/``val*`` file.
    Every file is hashed once.
    """
    folder = Path(folder)
    try:
        description = load_description(folder)
    except FileNotFoundError:
        return f"{DESCRIPTION_FILE} missing"
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        return f"{DESCRIPTION_FILE} unreadable: {type(error).__name__}"
    if not isinstance(description, dict) or not isinstance(description.get("files"), dict):
        return f"{DESCRIPTION_FILE} is not a dataset description"
    if (
        description.get("config_hash") != config_hash(config)
        or description.get("format_version") != FORMAT_VERSION
        or description.get("config") != json.loads(json.dumps(config.to_dict()))
    ):
        return f"{DESCRIPTION_FILE} describes another config"
    files: dict[str, Any] = description["files"]
    expected = {f"{name}.parquet" for name in config.records}
    if set(files) != expected:
        listed = ", ".join(sorted(files)) or "no files"
        return f"{DESCRIPTION_FILE} lists {listed}, not {', '.join(sorted(expected))}"
    if not all(isinstance(info, dict) and {"sha256", "bytes"} <= info.keys()
               for info in files.values()):
        return f"{DESCRIPTION_FILE} has no checksums (written by an older hypa)"
    problems = []
    for name, info in sorted(files.items()):
        path = folder / name
        try:
            size = path.stat().st_size
            if size != info["bytes"]:
                problems.append(f"{name} has {size} bytes, not {info['bytes']}")
            elif sha256(path) != info["sha256"]:
                problems.append(f"{name} changed (SHA-256 differs)")
        except FileNotFoundError:
            problems.append(f"{name} missing")
        except OSError as error:  # a folder in its place, no permission
            problems.append(f"{name} unreadable: {error.strerror or type(error).__name__}")
    known = files.keys() | {DESCRIPTION_FILE}
    unexpected = sorted(p.name for p in folder.iterdir()
                        if not p.name.startswith(".") and p.name not in known)
    if unexpected:
        problems.append(f"unexpected {', '.join(unexpected)}")
    return "; ".join(problems) or None


def _folder_id(folder: Path) -> tuple[int, int] | None:
    """(device, inode) of a folder, ``None`` when absent: tells a folder another run renamed
    into place from the one this run looked at."""
    try:
        stat = folder.stat()
    except FileNotFoundError:
        return None
    return stat.st_dev, stat.st_ino


def _install(staging: Path, target: Path, damaged: tuple[int, int] | None) -> None:
    """Rename the complete ``staging`` folder to ``target``, moving the damaged folder
    (identified by :func:`_folder_id`, ``None`` when there was none) out of the way first."""
    try:
        os.rename(staging, target)
        return
    except OSError:
        if not target.exists():
            raise
    # A folder other than the damaged one is another run's complete, identical result
    # (generation is deterministic): keep it rather than pull it from under that run's readers.
    if _folder_id(target) != damaged:
        log.info("testbench: another run finished %s first", target)
        return
    # Two renames, not one atomic swap (which needs renameat2): if another run installs its
    # folder between the check above and the first rename, this moves that good folder aside
    # and the name is absent for the instant until the second rename. A reader then fails
    # loudly (file not found); it never sees a mix of old and new files.
    aside = target.with_name(f".{target.name}-damaged-{os.getpid()}-{time.time_ns()}")
    try:
        os.rename(target, aside)
    except FileNotFoundError:  # another run moved it aside a moment ago
        aside = None
    try:
        os.rename(staging, target)
    except OSError:
        if not (target / DESCRIPTION_FILE).is_file():
            raise
        log.info("testbench: another run finished %s first", target)
    finally:
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)


def ensure_dataset(config: TestbenchConfig, cache_dir: Path | None = None) -> Path:
    """The cached dataset folder ``<cache_dir>/<config hash>`` for ``config``, made if absent
    and made again, with a warning, when it is damaged (see :func:`cache_damage`).

    ``cache_dir`` defaults to :func:`default_cache_dir`. The data are generated into a
    temporary sibling folder that is renamed into place only when complete, so a crashed
    run leaves no half folder and of two parallel runs the first rename wins. A damaged
    folder is renamed aside just before and deleted after, so ``<config hash>`` never holds a
    mix of old and new files. Settings whose data would not fit into this machine's memory are
    refused before anything is looked up or made (:func:`check_fits`).
    """
    check_fits(config)
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = cache_dir / config_hash(config)
    damaged = _folder_id(target)  # before the check: another run may replace it meanwhile
    if damaged is not None:
        damage = cache_damage(target, config) if target.is_dir() else "not a folder"
        if damage is None:
            log.info("testbench: using cached data in %s", target)
            return target
        log.warning("testbench: cached data in %s damaged (%s); regenerating", target, damage)
    cache_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=cache_dir))
    staging.chmod(0o755)  # mkdtemp's 0700 would survive the rename
    try:
        generate_dataset(config, staging)
        _install(staging, target, damaged)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def folder_from_settings(testbench: Any) -> Path:
    """The test bench's data folder for its settings (a command's ``testbench`` node): cached, or
    generated now (``data.source: testbench``; the entry point ``hypa.data_sources``)."""
    from hypa.core.errors import settings

    with settings("testbench"):  # the test bench's settings build its data: a bad one is the user's, in one line
        folder = ensure_dataset(TestbenchConfig.from_hydra(testbench))
    log.info("test-bench data: %s", folder)
    return folder
