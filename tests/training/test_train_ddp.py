"""Training across processes through the real command line: ``trainer.strategy=ddp trainer.devices=2`` on the CPU
(gloo), against the same run in one process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT, SHORT_OVERRIDES
from data_helpers import DC_MOTOR_HYBRID, USER_EXAMPLE, make_dc_motor_data

DDP = ["trainer.strategy=ddp", "trainer.devices=2", "trainer.accelerator=cpu"]
QUIET = ["trainer.enable_progress_bar=false", "figures.enabled=false"]


def hypa_train(run: Path, overrides: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "hypa", "train", *overrides, f"hydra.run.dir={run}"]
    result = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    return result


def assert_one_run(run: Path, stdout: str) -> dict:
    """Rank 0 wrote the run folder alone: one record, one set of checkpoints, one TensorBoard folder, one
    log (rank 1's lines in it), the final lines once; and the ranks ended with the same weights."""
    assert stdout.count("best val/loss") == 1 and stdout.count("checkpoint:") == 1
    written = {p.name for p in run.iterdir() if not p.name.startswith(".")} - {"identification.md"}
    assert written == {"checkpoints", "config.yaml", "run.json", "tensorboard", "train.log"}
    best, last = sorted(p.name for p in (run / "checkpoints").iterdir())  # nothing else: no rank's temporary file
    assert best.startswith("best-") and last == "last.ckpt"
    assert [p.name for p in (run / "tensorboard").iterdir() if p.is_dir()] == []  # no version folder per rank
    log = (run / "train.log").read_text()
    assert "[rank 1]" in log
    assert "the same weights on all 2 processes" in log
    assert not list(run.glob("train_ddp_process_*"))
    record = json.loads((run / "run.json").read_text())
    assert (run / record["best_checkpoint"]["path"]).is_file()
    return record


def test_v2_trains_across_two_processes_as_in_one(tmp_path: Path, hypa_cache: Path) -> None:
    """V2's two stages over every training window, 1 epoch each. The global batch is the same (1 x 16 and
    2 x 8 windows) and DDP averages the ranks' gradients, so each step's gradient is that of 16 windows in
    both; what differs is which 16 (Lightning's DistributedSampler shuffles with its own permutation). The
    two runs differed by 1e-3 (relative) here: 1 % leaves room for another order, and a DDP that did not
    average gradients shows up in the weights check, which is exact."""
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    common = ["model=v2", "ann=lstm", "ann.hidden_size=8", "trainer.max_epochs=1", *QUIET, *SHORT_OVERRIDES]
    hypa_train(tmp_path / "one", [*common, "data.batch_size=16", "trainer.accelerator=cpu"], env)
    two = hypa_train(tmp_path / "two", [*common, "data.batch_size=8", *DDP], env)
    record = assert_one_run(tmp_path / "two", two.stdout)
    alone = json.loads((tmp_path / "one" / "run.json").read_text())
    assert record["best_val_loss"] == pytest.approx(alone["best_val_loss"], rel=0.01)
    assert "stage 'rear_steering' done" in (tmp_path / "two" / "train.log").read_text()


TRUE = {"torque_constant": 0.065, "friction": 3e-5, "load_torque": 0.004}  # examples/user_system/make_data.py


@pytest.mark.slow  # 34 s; ddp across two processes: the V2 test above, in make test
def test_a_hybrid_identified_once_trains_on_its_physics_across_two_processes(tmp_path: Path) -> None:
    """Rank 0 identifies the physics (once: one report), rank 1 receives it: both train from the identified
    values (the checkpoint's are, after an epoch at a negligible physics learning rate) to the same weights.
    A physics-only model has no epochs: it is identified and validated in one process."""
    data = tmp_path / "data"
    env = make_dc_motor_data(data, 20)
    (tmp_path / "conf" / "model").mkdir(parents=True)
    (tmp_path / "conf" / "model" / "dc_motor_hybrid.yaml").write_text(DC_MOTOR_HYBRID)
    user = ["--config-dir", str(USER_EXAMPLE / "conf"), "dataset=dc_motor", f"data.dir={data}", *QUIET, *DDP]
    run = tmp_path / "hybrid"
    result = hypa_train(run, [*user, f"hydra.searchpath=[file://{tmp_path / 'conf'}]", "model=dc_motor_hybrid",
                              "ann=lstm", "ann.hidden_size=4", "trainer.max_epochs=1",
                              "trainer.limit_train_batches=4", "optimizer.physics_lr=1e-9"], env)
    assert result.stdout.count("identified 3 parameter(s)") == 1
    record = assert_one_run(run, result.stdout)
    from hypa.training.checkpoints import load_module

    sys.path.insert(0, str(USER_EXAMPLE))  # the system class, for loading the checkpoint here
    trained = load_module(run / record["best_checkpoint"]["path"], ["dc_motor"]).model.parameters_.as_floats()
    for name, value in TRUE.items():
        assert record["identification"]["parameters"][name]["value"] == pytest.approx(value, rel=0.02)
        assert trained[name] == pytest.approx(value, rel=0.02)
    physics = hypa_train(tmp_path / "physics", [*user, "model=dc_motor"], env)
    assert "after identification" in physics.stdout
    assert "[rank 1]" not in (tmp_path / "physics" / "train.log").read_text()


def test_ddp_spawn_is_refused_in_one_line(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "hypa", "train", "trainer.strategy=ddp_spawn", "trainer.devices=2",
               f"hydra.run.dir={tmp_path}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1].startswith("hypa train: error: trainer.strategy=ddp_spawn")
    assert "trainer.strategy=ddp" in result.stderr and not (tmp_path / "run.json").exists()
