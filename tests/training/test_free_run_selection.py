"""Epochs chosen by free runs of the validation records (``early_stopping.monitor=val/free_run``): the
metric is the benchmark's own free-run error in val/loss's unit, a diverged free run is never the
best epoch, and the run's stages, early stopping, kept checkpoint and printed best all follow it;
``auto`` lets a hybrid's identified physics choose (the free runs where the windows err more)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest
import torch

from hypa.data import HypaDataModule
from hypa.models.rollout import free_run, free_run_metrics
from hypa.training import HybridModule
from hypa.training.free_run import FREE_RUN, WINDOWS, chosen_monitor, free_run_loss, windows_loss

from cli_helpers import hypa_run
from conftest import SHORT_OVERRIDES, compose_config


@pytest.fixture(scope="module")
def bench(hypa_cache: Path) -> tuple[HypaDataModule, HybridModule]:
    from omegaconf import OmegaConf

    from hypa.data.from_config import data_dir_from_config, datamodule_from_config

    cfg = compose_config("train", [*SHORT_OVERRIDES, "model=physical"])
    dm = datamodule_from_config(cfg.data, data_dir_from_config(cfg))
    dm.setup()
    module = HybridModule.from_data(dm, OmegaConf.to_container(cfg.model, resolve=True))
    return dm, module


def test_it_is_the_free_runs_squared_error_in_the_unit_of_val_loss(bench) -> None:
    """Against the evaluation's own free-run metrics (``hypa evaluate``, the benchmark): per output the
    mean squared error over the records' predicted samples divided by the training scale's variance,
    pooled over outputs and samples as an MSE loss pools them."""
    dm, module = bench
    runs = [free_run(module.model, dm, r) for r in dm.records("val")]
    metrics = free_run_metrics(runs, dm.output_names)
    samples = sum(len(r.time) - r.first for r in runs)
    expected = sum(metrics[n]["mse"] / module.model.measured_scale[n][1] ** 2 for n in dm.output_names) \
        / len(dm.output_names)
    assert samples > 100
    assert free_run_loss(module.model, dm) == pytest.approx(expected, rel=1e-9)


def test_a_diverged_free_run_is_never_a_best_epoch(bench) -> None:
    dm, module = bench
    raw = module.model.parameters_.raw
    name = next(iter(raw))
    kept = raw[name].detach().clone()
    try:
        with torch.no_grad():
            raw[name].fill_(float("nan"))
        assert free_run_loss(module.model, dm) == math.inf
    finally:
        with torch.no_grad():
            raw[name].copy_(kept)
    assert math.isfinite(free_run_loss(module.model, dm))


def test_a_run_chosen_by_its_free_runs(tmp_path: Path, hypa_cache: Path) -> None:
    """Through the command line: every epoch logs val/free_run, the stage's and the run's best are
    its least, the epoch lines show it, and the run's record keeps it."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    result = hypa_run(["train", "model=v2", "ann=lstm", f"hydra.run.dir={tmp_path}", "trainer.max_epochs=3",
                       "trainer.limit_train_batches=3", "trainer.limit_val_batches=2", "figures.enabled=false",
                       "ann.hidden_size=8", "early_stopping.patience=5", "early_stopping.monitor=val/free_run",
                       *SHORT_OVERRIDES], env={**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)})
    assert result.returncode == 0, result.stderr[-3000:]
    assert "best val/free_run " in result.stdout
    assert "val/free_run" in result.stdout.split("best val/free_run")[0]  # the epoch lines show it
    acc = EventAccumulator(str(tmp_path / "tensorboard")).Reload()
    logged = [e.value for e in acc.Scalars("val/free_run")]
    assert len(logged) >= 3 and all(math.isfinite(v) for v in logged)
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["best_checkpoint"]["monitor"] == "val/free_run"
    best = record["best_checkpoint"]["val_loss"]
    assert best == pytest.approx(min(logged), rel=1e-6)  # the best epoch's, not the windows' best


def test_auto_chooses_by_which_errs_more_at_the_identified_physics(bench) -> None:
    """``windows_loss`` is val/loss outside a trainer (the module's own validation step over the same
    windows), and ``chosen_monitor`` picks the free runs only where the windows err more."""
    import lightning as L

    dm, module = bench
    logged = L.Trainer(logger=False, enable_progress_bar=False, enable_model_summary=False).validate(
        module, datamodule=dm, verbose=False)[0]["val/loss"]
    state = torch.random.get_rng_state()
    windows = windows_loss(module, dm)
    assert torch.equal(torch.random.get_rng_state(), state)  # the run's random stream is left as it was
    assert windows == pytest.approx(logged, rel=1e-5)
    chosen, w, free = chosen_monitor(module, dm)
    assert (w, free) == (pytest.approx(windows), pytest.approx(free_run_loss(module.model, dm)))
    assert chosen == (FREE_RUN if windows > free else WINDOWS)


def test_auto_on_the_real_tanks_chooses_the_free_runs(tmp_path: Path) -> None:
    """The cascaded tanks' hybrid: its identified physics errs 4 times more on the windows (their starts:
    the upper level is not measured) than on the free run of the validation record, so ``auto`` chooses
    ``val/free_run``, says so, and every stage of the run follows it."""
    result = hypa_run(["train", "dataset=cascaded_tanks", "model=cascaded_tanks_hybrid", "ann=lstm",
                       "ann.hidden_size=8", "trainer.max_epochs=2", "early_stopping.monitor=auto",
                       "figures.enabled=false", f"hydra.run.dir={tmp_path}"])
    assert result.returncode == 0, result.stderr[-3000:]
    assert "epochs chosen by val/free_run: the identified physics' validation windows" in result.stdout
    assert "best val/free_run " in result.stdout
    assert json.loads((tmp_path / "run.json").read_text())["best_checkpoint"]["monitor"] == "val/free_run"
