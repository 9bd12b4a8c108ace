"""The default data of hypa: a folder of measured-data files, generated once and cached.

A dataset folder holds one ``<record>.parquet`` per record of the config and
``dataset.json``: the full config, its hash, the column units and per file its segments
as half-open time intervals [start_s, end_s) [s].
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

from hypa.testbench.config import TestbenchConfig
from hypa.testbench.records import COLUMNS, SimulatedRecord, simulate_record, write_record
from hypa.testbench.sensors import UNITS

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
    write_record(out_dir / f"{name}.parquet", record.columns)
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
    }


def generate_dataset(config: TestbenchConfig, out_dir: Path) -> Path:
    """Simulate every record of ``config`` into ``out_dir`` (created); returns ``out_dir``.

    Files of the same name are overwritten; other files in ``out_dir`` are left alone.
    """
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


def ensure_dataset(config: TestbenchConfig, cache_dir: Path | None = None) -> Path:
    """The cached dataset folder ``<cache_dir>/<config hash>`` for ``config``, made if absent.

    ``cache_dir`` defaults to :func:`default_cache_dir`. The data are generated into a
    temporary sibling folder that is renamed into place only when complete, so a crashed
    run leaves no half folder and of two parallel runs the first rename wins.
    """
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = cache_dir / config_hash(config)
    if (target / DESCRIPTION_FILE).is_file():
        log.info("testbench: using cached data in %s", target)
        return target
    cache_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=cache_dir))
    staging.chmod(0o755)  # mkdtemp's 0700 would survive the rename
    try:
        generate_dataset(config, staging)
        try:
            os.rename(staging, target)
        except OSError:
            if not (target / DESCRIPTION_FILE).is_file():
                raise
            log.info("testbench: another run finished %s first", target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target
