"""The test-bench cache is checked before it is used: a damaged folder is regenerated, loudly.

Each test has its own cache (``HYPA_CACHE_DIR`` in ``tmp_path``) holding tiny records (5 s
each, no manoeuvres), so generating one takes well under a second.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from hypa.core.metadata import sha256
from hypa.data.from_config import data_dir_from_config
from hypa.paper.testbench import TestbenchConfig, ensure_dataset, load_description
from hypa.paper.testbench import dataset as dataset_module

from cli_helpers import hypa_run
from conftest import compose_config

RECORDS = ("train_1", "train_2", "val")
TINY = [*(f"testbench.records.{name}.stochastic_duration_s=5" for name in RECORDS),
        "testbench.records.val.maneuvers=[]"]
LOGGER = "hypa.paper.testbench.dataset"


def _compose(config: str, *overrides: str):
    return compose_config(config, [*TINY, *overrides])


@pytest.fixture(scope="module")
def config() -> TestbenchConfig:
    """The config the command line builds from :data:`TINY` (so the cache folder is the same)."""
    return TestbenchConfig.from_dict(_compose("testbench").testbench)


@pytest.fixture
def cache(config, tmp_path, monkeypatch) -> Path:
    """A freshly generated cached dataset folder of ``config``, in this test's own cache."""
    monkeypatch.setenv("HYPA_CACHE_DIR", str(tmp_path / "cache"))
    return ensure_dataset(config)


def _contents(folder: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir())}


def _run_cli(tmp_path: Path) -> str:
    """``hypa testbench <TINY>`` as a user types it; its output (log included)."""
    result = hypa_run(["testbench", *TINY, f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    return output


def _warnings(output: str) -> list[str]:
    return [line for line in output.splitlines() if "WARNING" in line]


def test_dataset_json_records_size_and_checksum_of_every_file(cache, config):
    files = load_description(cache)["files"]
    assert sorted(files) == [f"{name}.parquet" for name in RECORDS]
    for name, info in files.items():
        assert {"samples", "duration_s", "segments"} <= info.keys()  # the keys from before stay
        assert info["bytes"] == (cache / name).stat().st_size > 1000
        assert info["sha256"] == sha256(cache / name)


def _delete_train_2(folder: Path) -> str:
    (folder / "train_2.parquet").unlink()
    return "train_2.parquet missing"


def _cut_dataset_json(folder: Path) -> str:
    text = (folder / "dataset.json").read_text()
    (folder / "dataset.json").write_text(text[: len(text) // 2])
    return "dataset.json unreadable: JSONDecodeError"


@pytest.mark.parametrize("damage", [_delete_train_2, _cut_dataset_json], ids=["deleted", "json"])
def test_the_command_regenerates_a_damaged_cache_and_says_why(cache, tmp_path, damage):
    original = _contents(cache)
    reason = damage(cache)
    output = _run_cli(tmp_path)
    warnings = _warnings(output)
    assert len(warnings) == 1, output
    assert warnings[0].endswith(f"testbench: cached data in {cache} damaged ({reason}); regenerating")
    assert "simulating train_1, train_2, val" in output
    assert _contents(cache) == original  # every file back, byte for byte, dataset.json too
    assert [p.name for p in cache.parent.iterdir()] == [cache.name]  # no staging or old folder
    assert "train_2.parquet" in output.split("test-bench data in", 1)[1]  # the summary


def test_the_command_uses_an_intact_cache_as_it_is(cache, tmp_path):
    before = {path.name: path.stat().st_mtime_ns for path in cache.iterdir()}
    folder_id = (cache.stat().st_dev, cache.stat().st_ino)
    output = _run_cli(tmp_path)
    assert f"testbench: using cached data in {cache}" in output
    assert _warnings(output) == [] and "simulating" not in output, output
    assert {path.name: path.stat().st_mtime_ns for path in cache.iterdir()} == before
    assert (cache.stat().st_dev, cache.stat().st_ino) == folder_id


def _truncate_val(folder: Path) -> str:
    path = folder / "val.parquet"
    size = path.stat().st_size
    with path.open("r+b") as file:
        file.truncate(size // 2)
    return f"val.parquet has {size // 2} bytes, not {size}"


def _flip_a_byte(folder: Path) -> str:
    path = folder / "train_1.parquet"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # same size: only the checksum can tell
    path.write_bytes(bytes(data))
    return "train_1.parquet changed (SHA-256 differs)"


def _strip_checksums(folder: Path) -> str:
    description = load_description(folder)
    for info in description["files"].values():  # as hypa wrote it before checksums
        del info["sha256"], info["bytes"]
    (folder / "dataset.json").write_text(json.dumps(description, indent=2) + "\n")
    return "dataset.json has no checksums (written by an older hypa)"


def _other_config(folder: Path) -> str:
    description = load_description(folder)
    description["config"]["records"]["val"]["seed"] = 99
    (folder / "dataset.json").write_text(json.dumps(description))
    return "dataset.json describes another config"


def _add_a_training_file(folder: Path) -> str:
    (folder / "train_3.parquet").write_bytes((folder / "train_1.parquet").read_bytes())
    return "unexpected train_3.parquet"


def _delete_two_files(folder: Path) -> str:
    (folder / "val.parquet").unlink()
    (folder / "train_1.parquet").unlink()
    return "train_1.parquet missing; val.parquet missing"


@pytest.mark.parametrize(
    "damage",
    [_truncate_val, _flip_a_byte, _strip_checksums, _other_config, _add_a_training_file,
     _delete_two_files],
    ids=["truncated", "flipped", "older-hypa", "other-config", "extra-file", "two-missing"],
)
def test_ensure_dataset_regenerates_every_kind_of_damage(cache, config, damage, caplog):
    original = _contents(cache)
    reason = damage(cache)
    with caplog.at_level(logging.INFO, logger=LOGGER):
        assert ensure_dataset(config) == cache
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings == [f"testbench: cached data in {cache} damaged ({reason}); regenerating"]
    assert _contents(cache) == original
    assert [p.name for p in cache.parent.iterdir()] == [cache.name]
    assert dataset_module.cache_damage(cache, config) is None


def test_the_training_data_path_restores_a_deleted_file(cache, caplog):
    """What ``hypa train`` does to find its data: half the data is never trained on quietly."""
    original = _contents(cache)
    (cache / "train_2.parquet").unlink()
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        assert data_dir_from_config(_compose("train")) == cache
    assert "train_2.parquet missing" in caplog.text
    assert _contents(cache) == original


def test_a_run_that_finishes_second_keeps_the_first_runs_folder(cache, config, monkeypatch, caplog):
    # Two runs find the same damaged folder; the other run installs its folder while this one
    # is still generating. This run must keep that folder, not pull it from under its readers.
    original = _contents(cache)
    (cache / "val.parquet").unlink()
    real_generate = dataset_module.generate_dataset
    other: dict[str, tuple[int, int]] = {}

    def generate_while_another_run_finishes(config, out_dir):
        folder = real_generate(config, out_dir)
        if not other:
            other["id"] = (0, 0)  # the nested run below must not nest again
            ensure_dataset(config)
            other["id"] = (cache.stat().st_dev, cache.stat().st_ino)
        return folder

    monkeypatch.setattr(dataset_module, "generate_dataset", generate_while_another_run_finishes)
    with caplog.at_level(logging.INFO, logger=LOGGER):
        assert ensure_dataset(config) == cache
    assert (cache.stat().st_dev, cache.stat().st_ino) == other["id"]
    assert f"another run finished {cache} first" in caplog.text
    assert caplog.text.count("val.parquet missing") == 2  # each run saw the damage once
    assert _contents(cache) == original
    assert [p.name for p in cache.parent.iterdir()] == [cache.name]
