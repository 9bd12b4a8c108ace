"""Runs you can trust, through the real commands: a crafted checkpoint runs nothing, one run owns
one folder, the recorded best checkpoint is the one evaluated, a full disk leaves no truncated
checkpoint, bad values and a diverging loss stop with one line, damaged run folders get one line.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from cli_helpers import hypa_run
from conftest import ROOT, compose_config
from data_helpers import make_data_dir

FAST = ["model=physical", "identification.enabled=false",  # epochs: what these cases are about
        "dataset=files", "trainer.max_epochs=2", "trainer.enable_progress_bar=false",
        "figures.enabled=false", "data.batch_size=8"]


def hypa(command: str, *args: str, cwd: Path = ROOT, limit_bytes: int | None = None,
         **env: str) -> subprocess.CompletedProcess:
    """``command`` (``hypa train``) in this process (``hypa_run``); with ``limit_bytes``, a process of its own."""
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    environment.update(env)
    if limit_bytes is None:
        return hypa_run([*command.split()[1:], *args], cwd=cwd, env=environment)

    def limit() -> None:  # a full disk, as the process sees it: writes past the size fail (EFBIG)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", *command.split(), *args],
                          cwd=cwd, env=environment, capture_output=True,
                          text=True, timeout=300, preexec_fn=limit, check=False)


def one_line_error(result: subprocess.CompletedProcess, command: str, *parts: str) -> str:
    """The result is a user error: exit status 1, no traceback, one ``<command>: error:`` line, the last
    (Lightning's progress lines may come before it)."""
    assert result.returncode == 1, result.stderr[-3000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    errors = [line for line in result.stderr.splitlines() if ": error: " in line]
    assert len(errors) == 1 and errors[0] == result.stderr.strip().splitlines()[-1], result.stderr[-3000:]
    assert errors[0].startswith(f"{command}: error: "), errors[0]
    for part in parts:
        assert part in errors[0], errors[0]
    return errors[0]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_data_dir(tmp_path_factory.mktemp("trust") / "data", duration_s=6.0)


@pytest.fixture(scope="module")
def run(tmp_path_factory, data: Path) -> Path:
    """One finished physics-only run (read-only for the tests: they copy it)."""
    folder = tmp_path_factory.mktemp("trust") / "run"
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"hydra.run.dir={folder}")
    assert result.returncode == 0, result.stderr[-3000:]
    return folder


def copy_run(run: Path, to: Path) -> Path:
    shutil.copytree(run, to)
    (to / ".lock").unlink(missing_ok=True)
    return to


def recorded(folder: Path) -> dict:
    return json.loads((folder / "run.json").read_text())["best_checkpoint"]


class Payload:
    """What a crafted checkpoint would run when unpickled: create a file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def craft(checkpoint: Path, marker: Path) -> None:
    """A real hypa checkpoint with a payload added; run.json's checksum follows, as an attacker's would."""
    from hypa.core.metadata import sha256

    state = torch.load(checkpoint, weights_only=True)
    state["callbacks"]["payload"] = Payload(marker)
    torch.save(state, checkpoint)
    record_file = checkpoint.parent.parent / "run.json"
    record = json.loads(record_file.read_text())
    if record.get("best_checkpoint", {}).get("path") == f"checkpoints/{checkpoint.name}":
        record["best_checkpoint"]["sha256"] = sha256(checkpoint)
        record_file.write_text(json.dumps(record))


@pytest.mark.parametrize("command, argument", [
    pytest.param("hypa evaluate", "run={folder}", id="evaluate-folder"),
    pytest.param("hypa evaluate", "run='{checkpoint}'", id="evaluate-checkpoint"),
    pytest.param("hypa explain", "run='{checkpoint}'", id="explain"),
    pytest.param("hypa train", "ckpt_path='{checkpoint}'", id="train-resume"),
    pytest.param("hypa reproduce", "skip_training=true out={results}", id="reproduce"),  # evaluates <out>/runs/*
])
def test_a_crafted_checkpoint_runs_nothing(command: str, argument: str, run: Path, data: Path,
                                           tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "results" / "runs" / "run")
    checkpoint = folder / recorded(folder)["path"]
    marker = tmp_path / "payload-ran"
    craft(checkpoint, marker)
    extra = [*FAST, f"data.dir={data}"] if command == "hypa train" else []
    arguments = argument.format(folder=folder, checkpoint=checkpoint, results=tmp_path / "results").split(" ")
    result = hypa(command, *arguments, *extra, f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, command, "not a readable checkpoint", "posix.system", "did not run")
    assert not marker.exists()


def test_the_loader_every_command_shares_refuses_a_crafted_checkpoint(run: Path, tmp_path: Path) -> None:
    """hypa benchmark, hypa reproduce and the diagnosis's trained extension load runs by load_run."""
    from hypa.core.errors import UserError
    from hypa.evaluation.runs import load_run

    folder = copy_run(run, tmp_path / "run")
    marker = tmp_path / "payload-ran"
    craft(folder / recorded(folder)["path"], marker)
    with pytest.raises(UserError, match="not a readable checkpoint"):
        load_run(folder)
    assert not marker.exists()
    assert "weights_only=False" not in "".join(p.read_text() for p in (ROOT / "hypa").rglob("*.py"))


def test_a_run_folder_holds_one_run(run: Path, data: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    before = {p.name: p.read_bytes() for p in (folder / "checkpoints").iterdir()}
    record, config = (folder / "run.json").read_text(), (folder / "config.yaml").read_text()
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"hydra.run.dir={folder}", "seed=7")
    one_line_error(result, "hypa train", "already holds another run's checkpoints", "ckpt_path=")
    assert {p.name: p.read_bytes() for p in (folder / "checkpoints").iterdir()} == before
    assert (folder / "run.json").read_text() == record and (folder / "config.yaml").read_text() == config
    # hypa evaluate still scores that run, under its own settings (the refused run wrote no .hydra/ either)
    from hypa.evaluation.runs import load_run

    assert load_run(folder).settings.seed == 0


def test_a_resumed_run_continues_in_its_own_folder_and_log(run: Path, data: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    log_before = (folder / "train.log").read_text()
    result = hypa("hypa train", *FAST, f"data.dir={data}", "trainer.max_epochs=3",
                  f"ckpt_path={folder / 'checkpoints' / 'last.ckpt'}", f"hydra.run.dir={tmp_path / 'hydra'}")
    assert result.returncode == 0, result.stderr[-3000:]
    log_after = (folder / "train.log").read_text()
    assert log_after.startswith(log_before) and "resuming last.ckpt" in log_after[len(log_before):]
    best = recorded(folder)
    assert (folder / best["path"]).is_file() and best["epoch"] >= 1
    assert not (tmp_path / "hydra" / "checkpoints").exists()


def test_two_runs_into_one_folder_at_once_one_is_refused(data: Path, tmp_path: Path) -> None:
    folder = tmp_path / "run"
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    runs = [subprocess.Popen([sys.executable, "-m", "hypa", "train",
                              *FAST, f"data.dir={data}", f"hydra.run.dir={folder}",
                              f"seed={seed}"], cwd=ROOT, env=environment, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for seed in (1, 2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in runs]
    assert sorted(code for code, _ in results) == [0, 1], results
    winner = [1, 2][[code for code, _ in results].index(0)]
    loser = next(err for code, err in results if code == 1)
    assert "is being written by another hypa train" in loser or "already holds another run's checkpoints" in loser
    assert sorted(p.name for p in (folder / "checkpoints").iterdir()) == ["best-epoch=01.ckpt", "last.ckpt"] or \
        len(list((folder / "checkpoints").glob("best-*.ckpt"))) == 1
    from omegaconf import OmegaConf

    assert OmegaConf.load(folder / "config.yaml").seed == winner
    assert json.loads((folder / "run.json").read_text())["best_checkpoint"]["path"].startswith("checkpoints/best-")


def test_evaluate_scores_the_recorded_checkpoint_not_the_newest_name(run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    best = folder / recorded(folder)["path"]
    decoy = folder / "checkpoints" / "best-epoch=99.ckpt"  # sorts last by name: the old rule picked it
    decoy.write_bytes(b"half a checkpoint")
    from hypa.evaluation.runs import load_run

    assert load_run(folder).checkpoint == best.resolve()
    best.write_bytes(best.read_bytes()[:-100])  # damaged after it was recorded
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'eval'}")
    one_line_error(result, "hypa evaluate", "is not the checkpoint that", "checksum differs")


def test_a_full_disk_leaves_no_truncated_checkpoint(data: Path, tmp_path: Path) -> None:
    folder = tmp_path / "run"
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"hydra.run.dir={folder}", limit_bytes=12_000)
    one_line_error(result, "hypa train", "File too large while writing the checkpoint")
    assert not list((folder / "checkpoints").glob("*")) if (folder / "checkpoints").is_dir() else True
    assert "best_checkpoint" not in json.loads((folder / "run.json").read_text())


def test_an_interrupted_checkpoint_write_keeps_the_previous_file(tmp_path: Path, monkeypatch) -> None:
    from hypa.training.checkpoints import AtomicCheckpointIO

    path = tmp_path / "best.ckpt"
    io = AtomicCheckpointIO()
    io.save_checkpoint({"w": torch.ones(3)}, path)
    intact = path.read_bytes()

    def half_then_full_disk(obj, file):
        file.write(b"PK\x03\x04 half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", half_then_full_disk)
    with pytest.raises(OSError, match="No space left on device while writing the checkpoint"):
        io.save_checkpoint({"w": torch.zeros(3)}, path)
    assert path.read_bytes() == intact and [p.name for p in tmp_path.iterdir()] == ["best.ckpt"]


def test_a_diverging_loss_stops_the_run_naming_the_epoch(data: Path, tmp_path: Path, monkeypatch) -> None:
    """Epoch 0 trains normally, the loss turns NaN in epoch 1: one line naming it, epoch 0 stays the best."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from hypa.commands.train import train
    from hypa.training import HybridModule
    from hypa.training.divergence import DivergedError

    original = HybridModule.training_step

    def diverging(self, batch, batch_idx):
        loss = original(self, batch, batch_idx)
        return loss * float("nan") if self.current_epoch == 1 else loss

    monkeypatch.setattr(HybridModule, "training_step", diverging)
    cfg = compose_config("train", [*FAST, f"data.dir={data}", "trainer.max_epochs=4"], return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(tmp_path)
        cfg.hydra.job.num = 0
    HydraConfig.instance().set_config(cfg)
    with pytest.raises(DivergedError, match=r"training loss nan at epoch 1 \(batch 0\).*epoch 0, val/loss"):
        train(cfg)
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["best_checkpoint"]["epoch"] == 0 and "epoch 1" in record["stopped"]
    for checkpoint in (tmp_path / "checkpoints").glob("*.ckpt"):
        weights = torch.load(checkpoint, weights_only=True)["state_dict"]
        assert all(torch.isfinite(w).all() for w in weights.values() if w.is_floating_point())


@pytest.mark.parametrize("override, message", [
    ("optimizer.lr=nan", "optimizer.lr=nan is not a finite number"),
    ("optimizer.lr=-1", "optimizer.lr=-1 must be > 0"),
    ("optimizer.physics_lr=0", "optimizer.physics_lr=0 must be > 0"),
    ("trainer.max_epochs=0", "trainer.max_epochs=0 must be >= 1"),
    ("trainer.max_epochs=-1", "trainer.max_epochs=-1 must be >= 1"),
])
def test_bad_training_values_stop_before_training(override: str, message: str, data: Path, tmp_path: Path) -> None:
    """Refused before the run folder is claimed or any data read (in-process: the command's one line for a
    UserError is shown once, below, and in tests/core/test_cli_errors.py)."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from hypa.commands.train import train
    from hypa.core.errors import UserError

    cfg = compose_config("train", [*FAST, f"data.dir={data}", override], return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(tmp_path / "run")
        cfg.hydra.job.num = 0
    HydraConfig.instance().set_config(cfg)
    with pytest.raises(UserError, match=message.replace(".", r"\.")):
        train(cfg)
    assert not (tmp_path / "run").exists()


def test_a_bad_learning_rate_is_one_line_through_the_command(data: Path, tmp_path: Path) -> None:
    result = hypa("hypa train", *FAST, f"data.dir={data}", "optimizer.lr=nan", f"hydra.run.dir={tmp_path / 'run'}")
    one_line_error(result, "hypa train", "optimizer.lr=nan is not a finite number")
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_an_unwritable_output_folder_is_one_line(data: Path, tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"hydra.run.dir={blocker / 'run'}")
    one_line_error(result, "hypa train", "Not a directory")
    read_only = tmp_path / "read-only"
    read_only.mkdir()
    command = [*FAST, f"data.dir={data}", f"hydra.run.dir={read_only / 'run'}"]
    if os.geteuid() != 0:
        read_only.chmod(0o555)
        result = hypa("hypa train", *command)
        read_only.chmod(0o755)
        one_line_error(result, "hypa train", "Permission denied")
        return
    # root writes through permissions: a read-only bind mount in a private mount namespace instead
    script = (f"mount --bind {read_only} {read_only} && mount -o remount,ro,bind {read_only} && "
              f"{sys.executable} -m hypa train " + " ".join(f"'{c}'" for c in command))
    probe = subprocess.run(["unshare", "-m", "sh", "-c", f"mount --bind {read_only} {read_only}"],
                           capture_output=True, text=True, check=False)
    if shutil.which("unshare") is None or probe.returncode != 0:
        pytest.skip("running as root without mount namespaces: no read-only folder to try")
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    result = subprocess.run(["unshare", "-m", "sh", "-c", script], cwd=ROOT, env=environment, capture_output=True,
                            text=True, timeout=300, check=False)
    one_line_error(result, "hypa train", "Read-only file system")


def test_damaged_run_folders_are_one_line(run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    (folder / "config.yaml").write_text("data: [unclosed\n")
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'eval'}")
    one_line_error(result, "hypa evaluate", "config.yaml: not a readable run configuration")
    (folder / "run.json").write_text("{not json")
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'eval'}")
    one_line_error(result, "hypa evaluate", "run.json: not a readable run record")


def test_evaluate_refuses_a_model_that_predicts_non_finite_values(run: Path, tmp_path: Path) -> None:
    from hypa.core.metadata import sha256

    folder = copy_run(run, tmp_path / "run")
    checkpoint = folder / recorded(folder)["path"]
    state = torch.load(checkpoint, weights_only=True)
    for weight in state["state_dict"].values():
        if weight.is_floating_point():
            weight.fill_(float("nan"))
    torch.save(state, checkpoint)
    record = json.loads((folder / "run.json").read_text())
    record["best_checkpoint"]["sha256"] = sha256(checkpoint)
    (folder / "run.json").write_text(json.dumps(record))
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'eval'}")
    one_line_error(result, "hypa evaluate", "predicts non-finite", "retrain")
