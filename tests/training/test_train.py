"""Training through the real configuration: every model x ann, loggers, stages, resume."""

import os
import sys
from pathlib import Path

import pytest
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import open_dict

from hypa.commands.train import train

from cli_helpers import hypa_run
from conftest import SHORT_OVERRIDES, compose_config

TINY = ["trainer.max_epochs=1", "trainer.limit_train_batches=2", "trainer.limit_val_batches=2",
        "trainer.enable_progress_bar=false", "figures.enabled=false", "data.batch_size=8",
        "ann.hidden_size=8"]
TINY_ANN = {"lstm": ["ann.hidden_size=8"], "s4": ["ann.d_model=8", "ann.d_state=4", "ann.n_layers=1"],
            "transformer": ["ann.d_model=8", "ann.n_heads=2", "ann.n_layers=1", "ann.dim_feedforward=16"],
            "mamba": ["ann.d_model=8", "ann.d_state=4", "ann.n_layers=1"]}


def run_train(tmp_path: Path, overrides: list[str]) -> dict:
    """Compose the real config like the command line does, and train in-process."""
    cfg = compose_config("train", [*SHORT_OVERRIDES, *overrides], return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(tmp_path)
        cfg.hydra.job.num = 0
    HydraConfig.instance().set_config(cfg)
    return train(cfg)


COMBINATIONS = [("physical", "lstm")] + [(m, a) for m in ("blackbox", "v1", "v2", "v3")
                                         for a in ("lstm", "transformer", "s4", "mamba")]


@pytest.mark.parametrize("model, ann", COMBINATIONS)
def test_every_model_and_ann_trains(model: str, ann: str, tmp_path: Path, hypa_cache: Path) -> None:
    overrides = [o for o in TINY if not o.startswith("ann.")] + TINY_ANN[ann]
    result = run_train(tmp_path, [f"model={model}", f"ann={ann}", *overrides])
    assert torch.isfinite(torch.tensor(result["best_val_loss"]))
    assert Path(result["checkpoint"]).is_file()


def test_cli_run_with_loggers_early_stopping_and_checkpoint(tmp_path: Path, hypa_cache: Path) -> None:
    """The real command line, not fast_dev_run: TensorBoard events and checkpoints are written."""
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    cmd = [sys.executable, "-m", "hypa", "train", "model=v1", "ann=lstm", f"hydra.run.dir={tmp_path}",
           "trainer.max_epochs=3", "trainer.limit_train_batches=3", "trainer.limit_val_batches=2",
           "early_stopping.patience=1", "ann.hidden_size=8", *SHORT_OVERRIDES]
    result = hypa_run(cmd[3:], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "best val/loss" in result.stdout and "tensorboard --logdir" in result.stdout
    events = list((tmp_path / "tensorboard").glob("events.out.tfevents.*"))
    assert events and events[0].stat().st_size > 1000
    assert (tmp_path / "checkpoints" / "last.ckpt").is_file()
    assert list((tmp_path / "checkpoints").glob("best-*.ckpt"))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(tmp_path / "tensorboard"), size_guidance={"images": 0}).Reload()
    scalars = set(acc.Tags()["scalars"])
    assert {"train/loss_epoch", "val/loss", "val/yaw_rate/r2", "val/side_slip/mae"} <= scalars
    assert "val/rear_wheel_angle/corr" in scalars
    assert {"val/outputs", "val/rear_wheel_angle"} <= set(acc.Tags()["images"])


def test_two_stage_schedule_switches_and_freezes_stage_one(tmp_path: Path, hypa_cache: Path, monkeypatch) -> None:
    from hypa.training import HybridModule, StagedTraining

    at_switch = {}
    original = StagedTraining._next_stage

    def spy(self, trainer, module):
        original(self, trainer, module)
        at_switch.update({k: v.clone() for k, v in module.model.state_dict().items()})
        at_switch["epoch"] = trainer.current_epoch

    monkeypatch.setattr(StagedTraining, "_next_stage", spy)
    result = run_train(tmp_path, ["model=v2", "ann=lstm", "trainer.max_epochs=2", "trainer.limit_train_batches=3",
                                  "trainer.limit_val_batches=2", "trainer.enable_progress_bar=false",
                                  "figures.enabled=false", "ann.hidden_size=8", "early_stopping.patience=5"])
    assert at_switch["epoch"] == 1  # stage 1 used its 2-epoch budget
    assert result["epochs"] == 4  # then stage 2 its own
    ckpt = torch.load(result["last_checkpoint"], weights_only=False)
    staged = next(v for k, v in ckpt["callbacks"].items() if "StagedTraining" in k)
    assert staged["stage"] == 1 and staged["stage_start_epoch"] == 2
    final = HybridModule.load_from_checkpoint(result["last_checkpoint"]).model.state_dict()
    rear = [k for k in final if k.startswith("blocks.rear_steering.")]
    correction = [k for k in final if k.startswith("blocks.correction.")]
    assert rear and correction
    for k in rear:  # frozen through stage 2
        torch.testing.assert_close(final[k], at_switch[k], rtol=0, atol=0)
    assert any(not torch.equal(final[k], at_switch[k]) for k in correction)  # trained in stage 2


def test_interrupted_stage_two_resumes_in_stage_two(tmp_path: Path, hypa_cache: Path) -> None:
    base = ["model=v2", "ann=lstm", "trainer.limit_train_batches=2", "trainer.limit_val_batches=2",
            "trainer.enable_progress_bar=false", "figures.enabled=false", "ann.hidden_size=8",
            "early_stopping.patience=5", "trainer.max_epochs=2"]
    first = run_train(tmp_path / "first", base)  # ends in stage 2 at epoch 4
    resumed = run_train(tmp_path / "resumed", [*base, "trainer.max_epochs=3", f"ckpt_path={first['last_checkpoint']}"])
    ckpt = torch.load(resumed["last_checkpoint"], weights_only=False)
    staged = next(v for k, v in ckpt["callbacks"].items() if "StagedTraining" in k)
    assert staged["stage"] == 1 and staged["stage_start_epoch"] == 2  # stage 2, never stage 1 again
    assert resumed["epochs"] == 5  # stage 2 (from epoch 2) gets its 3-epoch budget: epochs 2, 3, 4


def test_rear_wheel_angle_never_reaches_training(tmp_path: Path, hypa_cache: Path, monkeypatch) -> None:
    from hypa.training import HybridModule

    seen = []
    original = HybridModule.training_step

    def spy(self, batch, batch_idx):
        seen.append(set(batch))
        return original(self, batch, batch_idx)

    monkeypatch.setattr(HybridModule, "training_step", spy)
    run_train(tmp_path, ["model=v1", "ann=lstm", *TINY])
    assert seen and all(keys == {"u", "y", "s"} for keys in seen)


def test_same_seed_repeats_the_run(tmp_path: Path, hypa_cache: Path) -> None:
    first = run_train(tmp_path / "a", ["model=v1", "ann=lstm", "seed=3", *TINY])
    second = run_train(tmp_path / "b", ["model=v1", "ann=lstm", "seed=3", *TINY])
    other = run_train(tmp_path / "c", ["model=v1", "ann=lstm", "seed=4", *TINY])
    assert first["best_val_loss"] == second["best_val_loss"]
    assert other["best_val_loss"] != first["best_val_loss"]


def test_misspelled_model_lists_what_exists(tmp_path: Path) -> None:
    result = hypa_run(["train", "model=v4", f"hydra.run.dir={tmp_path}"])
    assert result.returncode != 0
    assert "v4" in result.stderr and all(name in result.stderr for name in ("v1", "v2", "v3", "physical", "blackbox"))


def test_a_model_with_nothing_to_train_is_one_line(tmp_path: Path, hypa_cache: Path) -> None:
    """Physics only, every parameter fixed: no identification and no epochs to run (it used to reach
    Lightning and end in a traceback about tensors without gradients)."""
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    fixed = ["model.blocks.rear_steering.trainable=[]", "model.blocks.single_track.trainable=[]"]
    result = hypa_run(["train", "model=physical", *fixed, f"hydra.run.dir={tmp_path}", *SHORT_OVERRIDES], env=env)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert "model 'physical' has nothing to train" in result.stderr.strip().splitlines()[-1]
    assert "hypa simulate model=physical" in result.stderr


def test_staged_training_checkpoints_the_stage_best_weights() -> None:
    """Resumed in stage 1, the switch to stage 2 must still start from stage 1's best weights."""
    from hypa.models import StageSpec
    from hypa.training import StagedTraining

    stages = [StageSpec("a", ("rear_steering",), ("correction",)), StageSpec("b", ("correction",))]
    saved = StagedTraining(stages, max_epochs=5)
    saved._best, saved._best_weights = 0.5, {"w": torch.ones(3)}
    restored = StagedTraining(stages, max_epochs=5)
    restored.load_state_dict(saved.state_dict())
    assert restored._best == 0.5 and torch.equal(restored._best_weights["w"], torch.ones(3))


def test_a_shorter_physics_horizon_trains_the_same_model(tmp_path: Path, hypa_cache: Path) -> None:
    """physics.horizon < window chains lifted products through their last state: exact, so the
    same seed gives the same validation loss as one product over the whole window."""
    losses = []
    for horizon in ("null", "25"):
        result = run_train(tmp_path / horizon, ["model=physical", *TINY, f"physics.horizon={horizon}"])
        losses.append(result["best_val_loss"])
    assert losses[1] == pytest.approx(losses[0], rel=1e-4)
