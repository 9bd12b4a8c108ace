"""Tuned sweeps (hydra/sweeper=hybrid_optuna) and the submitit launchers, through the real command line:
two Optuna trials, a two-job sweep on submitit's local executor, and the sbatch script of the SLURM config."""

import json
import math
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep
from omegaconf import OmegaConf

import hypa.commands.train
from hypa.ann import ann_hyperparameters

from conftest import ROOT, SHORT_OVERRIDES, compose_config

ANNS = ("lstm", "gru", "transformer", "s4", "mamba")
TINY = ["trainer.max_epochs=1", "trainer.limit_train_batches=2", "trainer.limit_val_batches=2",
        "trainer.enable_progress_bar=false", "figures.enabled=false", "data.batch_size=8", *SHORT_OVERRIDES]


def hypa_train(*args: str, cwd: Path, cache: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "HYPA_CACHE_DIR": str(cache)}
    return subprocess.run([sys.executable, "-m", "hypa", "train", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300, check=False)


def compose_train(*overrides: str):
    return compose_config("train", overrides, return_hydra_config=True)


def search_space(ann: str) -> dict:
    """hybrid_optuna's parameters for this ANN, parsed the way the sweeper parses them."""
    params = compose_train("hydra/sweeper=hybrid_optuna", f"ann={ann}").hydra.sweeper.params
    parsed = OverridesParser.create().parse_overrides([f"{key}={value}" for key, value in params.items()])
    return {o.get_key_element(): o.value() for o in parsed}


@pytest.mark.parametrize("ann", ANNS)
def test_optuna_width_follows_the_ann(ann: str) -> None:
    space = search_space(ann)
    width = "ann.hidden_size" if ann in ("lstm", "gru") else "ann.d_model"
    assert set(space) == {width, "optimizer.lr", "optimizer.physics_lr", "data.stride"}
    cfg = compose_train(f"ann={ann}")
    for key, sweep in space.items():  # every swept key exists, its default inside the space
        default = OmegaConf.select(cfg, key, throw_on_missing=True)
        if default is None:  # null: the network's own default in a hybrid (an end-to-end one derives it)
            default = ann_hyperparameters(ann)[key.removeprefix("ann.")]
        if isinstance(sweep, ChoiceSweep):
            assert default in sweep.list
        else:
            assert isinstance(sweep, IntervalSweep) and "log" in sweep.tags and sweep.start < default < sweep.end
    if ann == "transformer":
        assert all(width % cfg.ann.n_heads == 0 for width in space["ann.d_model"].list)


@pytest.mark.slow  # 34 s; a multirun through a launcher: the submitit sweep, in make test (Optuna itself only here)
def test_optuna_sweep_two_trials(tmp_path: Path, hypa_cache: Path) -> None:
    sweep = tmp_path / "sweep"
    result = hypa_train("-m", "hydra/sweeper=hybrid_optuna", "model=v2", "ann=lstm", "hydra.sweeper.n_trials=2",
                        f"hydra.sweep.dir={sweep}", *TINY, cwd=ROOT, cache=hypa_cache)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Best parameters:" in result.stdout + result.stderr
    best = yaml.safe_load((sweep / "optimization_results.yaml").read_text())
    assert math.isfinite(best["best_value"])
    space = search_space("lstm")
    assert set(best["best_params"]) == set(space)
    for key, value in best["best_params"].items():
        sweep_of_key = space[key]
        if isinstance(sweep_of_key, ChoiceSweep):
            assert value in sweep_of_key.list
        else:
            assert sweep_of_key.start <= value <= sweep_of_key.end
    trials = sorted(sweep.glob("*_v2-lstm-seed0"))
    assert [t.name.split("_")[0] for t in trials] == ["0", "1"]
    losses = {t: json.loads((t / "run.json").read_text())["best_val_loss"] for t in trials}
    winner = min(losses, key=losses.get)
    assert best["best_value"] == pytest.approx(losses[winner], rel=1e-12)  # the study saw what hypa train returned
    config = OmegaConf.load(winner / ".hydra" / "config.yaml")
    for key, value in best["best_params"].items():  # and the winner trained with the reported parameters
        assert OmegaConf.select(config, key) == pytest.approx(value)


def test_main_returns_inf_when_no_finite_val_loss(monkeypatch) -> None:
    """Optuna's sweeper aborts the study on a NaN objective; a diverged trial must rank last instead."""
    monkeypatch.setattr(hypa.commands.train, "train", lambda cfg: {"best_val_loss": float("nan")})
    assert hypa.commands.train.main.job(OmegaConf.create({})) == math.inf
    monkeypatch.setattr(hypa.commands.train, "train", lambda cfg: {"best_val_loss": 0.25})
    assert hypa.commands.train.main.job(OmegaConf.create({})) == 0.25


def test_submitit_local_two_job_sweep(tmp_path: Path, hypa_cache: Path) -> None:
    """The cluster path without a cluster: submitit pickles the task, runs each job in its own process,
    and every job lands in the one sweep folder (its timestamp resolved once, not per job)."""
    result = hypa_train("-m", "hydra/launcher=submitit_local", "seed=0,1", "model=v1", "ann=lstm",
                        "ann.hidden_size=8", *TINY, cwd=tmp_path, cache=hypa_cache)
    assert result.returncode == 0, result.stderr[-3000:]
    [sweep] = (tmp_path / "multirun").iterdir()
    for run in ("0_v1-lstm-seed0", "1_v1-lstm-seed1"):
        assert math.isfinite(json.loads((sweep / run / "run.json").read_text())["best_val_loss"])
        assert (sweep / run / "checkpoints" / "last.ckpt").is_file()
    logs = sorted(sweep.glob(".submitit/*/*_log.out"))
    assert len(logs) == 2 and all("Job completed successfully" in log.read_text() for log in logs)
    assert len(list(sweep.glob(".submitit/*/*_result.pkl"))) == 2


def test_slurm_config_makes_an_sbatch_array(tmp_path: Path, monkeypatch) -> None:
    """conf/hydra/launcher/slurm.yaml through submitit up to sbatch (a stand-in that keeps the script):
    every key is a parameter submitit knows, and a cluster's settings reach the #SBATCH lines."""
    import submitit
    from hydra_plugins.hydra_submitit_launcher.config import BaseQueueConf

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    stand_ins = {"sbatch": f'cp "$1" {tmp_path}/job.sh\necho "Submitted batch job 4242"',
                 "srun": "exit 1"}  # submitit looks for srun to tell it is on a cluster; never run here
    for name, body in stand_ins.items():
        (bin_dir / name).write_text(f"#!/bin/sh\n{body}\n")
        (bin_dir / name).chmod((bin_dir / name).stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    launcher = compose_train("hydra/launcher=slurm", "hydra.launcher.partition=gpu", "hydra.launcher.account=proj",
                             "hydra.launcher.timeout_min=90").hydra.launcher
    params = {k: v for k, v in OmegaConf.to_container(launcher).items()
              if k not in ("_target_", "submitit_folder", "name", "max_num_timeout")}
    # the names the launcher passes (hydra_submitit_launcher's BaseSubmititLauncher.launch)
    base = set(OmegaConf.structured(BaseQueueConf).keys())
    executor = submitit.AutoExecutor(cluster="slurm", folder=tmp_path / "submitit" / "%j")
    executor.update_parameters(name="hypa", **{k if k in base else f"slurm_{k}": v for k, v in params.items()})
    jobs = executor.map_array(abs, range(40))  # more jobs than array_parallelism runs at once
    assert [job.job_id for job in jobs[:2]] == ["4242_0", "4242_1"]
    script = (tmp_path / "job.sh").read_text()
    for line in ("--partition=gpu", "--account=proj", "--time=90", "--gpus-per-node=1", "--cpus-per-task=4",
                 "--mem=16GB", "--array=0-39%32"):
        assert f"#SBATCH {line}\n" in script, line
    assert "srun" in script and sys.executable in script  # the jobs run this interpreter (shared filesystem)
