"""A run folder says what it was made from, and hypa evaluate notices other data.

One tiny run through the command line (a network whose inputs are an interpolation, so the
resolved ``config.yaml`` differs from Hydra's), then: ``run.json`` holds the hypa version, the
git commit, the package versions and the SHA-256 of each data file read; evaluating on the
same files is silent, on a changed or an added file it warns and names the file.
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import subprocess
from importlib import metadata
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from cli_helpers import hypa_run
from conftest import ROOT
from data_helpers import make_data_dir

TINY = ["trainer.max_epochs=1", "trainer.limit_train_batches=2", "trainer.limit_val_batches=2",
        "trainer.enable_progress_bar=false", "figures.enabled=false", "ann.hidden_size=8"]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("metadata")
    data = make_data_dir(root / "data", duration_s=8.0)
    folder = root / "run"
    result = hypa_run(["train", "dataset=files", f"data.dir={data}", "model=blackbox", *TINY,
                       f"hydra.run.dir={folder}"])
    assert result.returncode == 0, result.stderr[-3000:]
    return folder


def copied(run: Path, tmp_path: Path) -> Path:
    """The run and its data copied, run.json pointing at the copy's data (to change them)."""
    shutil.copytree(run.parent, tmp_path / "copy")
    folder = tmp_path / "copy" / "run"
    info = json.loads((folder / "run.json").read_text())
    info["data_dir"] = str(tmp_path / "copy" / "data")
    (folder / "run.json").write_text(json.dumps(info))
    return folder


def test_run_json_records_versions_commit_and_data_checksums(run: Path) -> None:
    info = json.loads((run / "run.json").read_text())
    assert info["hypa_version"] == metadata.version("hypa")
    assert info["packages"] == {p: metadata.version(p) for p in ("torch", "lightning", "hydra-core")}
    data = Path(info["data_dir"])
    assert info["data_files"] == {f: hashlib.sha256((data / f).read_bytes()).hexdigest()
                                  for f in ("train_00.csv", "train_01.csv", "val_00.csv")}
    head = subprocess.run(["git", "-C", str(ROOT / "hypa"), "rev-parse", "HEAD"], capture_output=True, text=True,
                          check=False) if shutil.which("git") else None
    if head is not None and head.returncode == 0:
        assert info["git"]["commit"] == head.stdout.strip() and isinstance(info["git"]["dirty"], bool)
    else:
        assert "git" not in info
    assert info["best_val_loss"] == info["best_val_loss"]  # still written after training


def test_config_yaml_is_the_resolved_configuration(run: Path) -> None:
    hydra_config = (run / ".hydra" / "config.yaml").read_text()
    assert "${channels:" in hydra_config  # blackbox's inputs: an interpolation there
    resolved = OmegaConf.load(run / "config.yaml")
    assert "${" not in (run / "config.yaml").read_text()
    assert list(resolved.model.blocks.network.inputs) == ["steering_wheel_angle"]
    assert resolved.trainer.max_epochs == 1 and resolved.data.source == "files"


def test_evaluate_is_silent_on_the_training_data(run: Path, caplog) -> None:
    from hypa.commands.evaluate import run_datamodule
    from hypa.evaluation.runs import load_run

    with caplog.at_level(logging.WARNING):
        run_datamodule(load_run(run))
    assert not [r for r in caplog.records if "differ" in r.getMessage()]


def test_evaluate_warns_when_a_data_file_changed(run: Path, tmp_path: Path) -> None:
    folder = copied(run, tmp_path)
    val = tmp_path / "copy" / "data" / "val_00.csv"
    lines = val.read_text().splitlines()
    row = lines[200].split(",")
    row[2] = "0.5"  # one measured value, as a re-export or an edit would change it
    lines[200] = ",".join(row)
    val.write_text("\n".join(lines) + "\n")
    result = hypa_run(["evaluate", f"run={folder}", "tensorboard=false", f"hydra.run.dir={tmp_path / 'evaluate'}"])
    assert result.returncode == 0, result.stderr[-3000:]  # a warning, not an error
    warnings = [line for line in (result.stdout + result.stderr).splitlines() if "WARNING" in line]
    assert any("differ" in w and "changed: val_00.csv" in w for w in warnings), warnings
    assert "report:" in result.stdout


def test_evaluate_warns_when_the_files_are_others(run: Path, tmp_path: Path, caplog) -> None:
    from hypa.commands.evaluate import run_datamodule
    from hypa.evaluation.runs import load_run

    folder = copied(run, tmp_path)
    data = tmp_path / "copy" / "data"
    shutil.copy(data / "val_00.csv", data / "test_00.csv")  # a test file the run never read
    with caplog.at_level(logging.WARNING):
        run_datamodule(load_run(folder))
    assert any("not read in training: test_00.csv" in r.getMessage() for r in caplog.records)


def test_data_module_lists_every_file_it_read(tmp_path: Path) -> None:
    from hypa.data import HypaDataModule
    from hypa.paper.testbench.sensors import TESTBENCH_CHANNELS

    data = make_data_dir(tmp_path / "data", duration_s=8.0)
    (data / "dataset.json").write_text("{}")
    (data / "notes.txt").write_text("not data")
    dm = HypaDataModule(data, TESTBENCH_CHANNELS, window=50)
    dm.setup()
    assert sorted(p.name for p in dm.files) == ["dataset.json", "train_00.csv", "train_01.csv", "val_00.csv"]


def test_git_state_of_a_checkout_and_of_a_plain_folder(tmp_path: Path) -> None:
    from hypa.core.metadata import git_state

    if shutil.which("git") is None:
        assert git_state(tmp_path) is None
        return
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "__init__.py").write_text("")
    assert git_state(plain) is None  # not a git checkout
    repo = tmp_path / "repo"
    repo.mkdir()

    def git(*args: str) -> None:
        subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True)

    git("init", "-q")
    (repo / "__init__.py").write_text("")
    assert git_state(repo) is None  # hypa's files not tracked: another repository's, not hypa's commit
    git("add", "__init__.py")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "x")
    state = git_state(repo)
    assert state is not None and len(state["commit"]) == 40 and state["dirty"] is False
    (repo / "__init__.py").write_text("changed = True\n")
    assert git_state(repo)["dirty"] is True
