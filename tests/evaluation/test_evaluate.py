"""Evaluation of trained runs: free run against the physics, the CLI, and make reproduce (tiny)."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import hypa_run
from conftest import SHORT_OVERRIDES, compose_config
from test_train import run_train

TINY = ["trainer.max_epochs=1", "trainer.limit_train_batches=3", "trainer.limit_val_batches=2",
        "trainer.enable_progress_bar=false", "figures.enabled=false", "ann.hidden_size=8"]
# a validation record with the maneuvers, so the out-of-distribution split is exercised
WITH_MANEUVERS = ["testbench.records.val.maneuvers=[lane_change,step_steer]"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory, hypa_cache) -> dict[str, Path]:
    runs = {}
    for model in ("physical", "v1"):
        folder = tmp_path_factory.mktemp(model)
        overrides = [f"model={model}", "ann=lstm", *TINY, *WITH_MANEUVERS]
        run_train(folder, overrides)
        (folder / ".hydra").mkdir(exist_ok=True)  # what the command line's Hydra run would write
        _write_config(folder, overrides)
        runs[model] = folder
    return runs


def _write_config(folder: Path, overrides: list[str]) -> None:
    from omegaconf import OmegaConf

    cfg = compose_config("train", [*SHORT_OVERRIDES, *overrides])
    OmegaConf.save(cfg, folder / ".hydra" / "config.yaml")


def test_free_run_of_physical_model_equals_the_physics_recursion(trained, hypa_cache) -> None:
    from hypa.commands.evaluate import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.models.rollout import free_run
    from hypa.vehicle import VehicleParameters

    from vehicle_reference import simulate_vehicle

    run = load_run(trained["physical"])
    dm = run_datamodule(run)
    record = dm.records("val")[0]
    prediction = free_run(run.module.model, dm, record)
    fitted = VehicleParameters(**run.module.model.parameters_.as_floats())
    y = record.stack(("yaw_rate", "side_slip"))
    expected = simulate_vehicle(fitted, record["steering_wheel_angle"][None], y[None, 0], dm.dt)[0]
    for i, name in enumerate(("yaw_rate", "side_slip")):
        scale = np.abs(expected[:, i]).max()
        assert np.abs(prediction.predicted[name] - expected[:, i]).max() < 1e-4 * scale  # float32 model


def test_evaluate_cli_writes_metrics_figures_and_report(trained, hypa_cache, tmp_path) -> None:
    folder = trained["v1"]
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    result = hypa_run(["evaluate", f"run={folder}", f"out={tmp_path / 'ev'}", f"hydra.run.dir={tmp_path / 'hydra'}"],
                      env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    metrics = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    val = metrics["splits"]["val"]
    for mode in ("windowed", "free_run"):
        assert {"all", "stochastic", "maneuvers", "lane_change", "step_steer"} <= set(val[mode])
        assert set(val[mode]["all"]) == {"yaw_rate", "side_slip", "overall"}
        assert set(val[mode]["all"]["overall"]) == {"mae", "mse", "mape", "r2"}
    assert -1.0 <= val["signals"]["rear_wheel_angle"]["corr"] <= 1.0
    for name in ("metrics.csv", "summary.md", "transfer_steering_wheel_angle_yaw_rate.png",
                 "transfer_steering_wheel_angle_side_slip.png", "free_run.png", "rear_wheel_angle.png"):
        assert (tmp_path / "ev" / name).stat().st_size > 100
    assert "report:" in result.stdout


def test_evaluate_cli_explains_a_wrong_path(tmp_path) -> None:
    result = hypa_run(["evaluate", f"run={tmp_path / 'nope'}", f"hydra.run.dir={tmp_path / 'hydra'}"])
    assert result.returncode != 0 and "does not exist" in result.stderr


def test_a_run_trained_before_a_network_setting_existed_is_flagged(caplog) -> None:
    """S4's max_decay changes what trained layers compute: a checkpoint without it gets a warning
    naming the setting and its default; one with every setting (or no network) gets none."""
    import logging

    from hypa.ann import ann_hyperparameters
    from hypa.training.checkpoints import _warn_new_network_settings

    v1 = {"blocks": {"rear_steering": {"kind": "ann"}, "single_track": {"kind": "physics"}}}
    current = {k: v for k, v in ann_hyperparameters("s4").items() if k != "zero_init"}
    old = {k: v for k, v in current.items() if k != "max_decay"}
    with caplog.at_level(logging.WARNING, logger="hypa.training.checkpoints"):
        _warn_new_network_settings(Path("best.ckpt"), {"model_config": v1, "ann_name": "s4", "ann_hparams": old})
    assert "ann.max_decay=25.0" in caplog.text and "retrain" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="hypa.training.checkpoints"):
        _warn_new_network_settings(Path("best.ckpt"), {"model_config": v1, "ann_name": "s4", "ann_hparams": current})
        physical = {"blocks": {"single_track": {"kind": "physics"}}}
        _warn_new_network_settings(Path("best.ckpt"), {"model_config": physical, "ann_name": "s4", "ann_hparams": {}})
    assert caplog.text == ""
