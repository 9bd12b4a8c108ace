"""A user's own system and data set from scratch, through the commands a user types:
``examples/user_system`` (a DC motor by import path, its dataset and model YAMLs in a config
folder of the user's) trained by ``hypa train`` and evaluated by ``hypa evaluate``."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cli_helpers import hypa_run
from conftest import ROOT
from data_helpers import make_dc_motor_data

EXAMPLE = ROOT / "examples" / "user_system"


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    data, run = tmp_path_factory.mktemp("dc_motor_data"), tmp_path_factory.mktemp("dc_motor_run")
    env = make_dc_motor_data(data, 30)
    result = hypa_run(["train", "--config-dir", str(EXAMPLE / "conf"), "dataset=dc_motor", "model=dc_motor",
                       f"data.dir={data}", "trainer.max_epochs=4", "trainer.enable_progress_bar=false",
                       "optimizer.physics_lr=0.05", f"hydra.run.dir={run}"], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "best val/loss" in result.stdout
    return run


def test_user_system_trains_and_finds_the_true_parameters(trained: Path) -> None:
    """The data come from a motor whose torque constant (0.065) and load torque (0.004) differ
    from the nominal 0.05 and 0; the grey-box fit through the CLI must find them."""
    sys.path.insert(0, str(EXAMPLE))
    try:
        from hypa.evaluation.runs import load_run

        fitted = load_run(trained, trust=["dc_motor"]).module.model.parameters_.as_floats()
    finally:
        sys.path.remove(str(EXAMPLE))
    assert fitted["torque_constant"] == pytest.approx(0.065, rel=0.02)
    assert fitted["load_torque"] == pytest.approx(0.004, rel=0.05)


def test_user_system_evaluates_in_its_own_units(trained: Path, tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(EXAMPLE)}
    result = hypa_run(["evaluate", f"run={trained}", f"out={tmp_path}", "trust=[dc_motor]", "tensorboard=false",
                       f"hydra.run.dir={tmp_path / 'hydra'}"], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["splits"]["val"]["free_run"]["all"]["speed"]["r2"] > 0.99
    assert metrics["units"]["speed"] == "rad/s"
    assert "rpm" in (tmp_path / "summary.md").read_text()
    assert (tmp_path / "transfer_voltage_speed.png").stat().st_size > 1000


@pytest.mark.slow  # 51 s; the benchmark: test_real_data_cli's, in make test; --config-dir: the tests above
def test_a_users_own_data_set_and_model_are_benchmarked(tmp_path: Path) -> None:
    """hypa benchmark --config-dir DIR dataset=NAME models=[M]: no suite needed; without test
    records it refuses (an empty table would be a silent non-result), and the diagnosis's rows
    without a nominal model to diagnose (diagnose=M) or with one that does not exist."""
    data = tmp_path / "data"
    env = make_dc_motor_data(data, 10)
    command = [sys.executable, "-m", "hypa", "benchmark", "--config-dir", str(EXAMPLE / "conf"), "dataset=dc_motor",
               "models=[dc_motor]", f"data.dir={data}", "train_overrides=['identification.enabled=true']"]
    refused = subprocess.run([*command, f"hydra.run.dir={tmp_path / 'refused'}"], cwd=ROOT, capture_output=True,
                             text=True, timeout=300, env=env, check=False)
    assert refused.returncode == 1 and "has no test records" in refused.stderr, refused.stderr[-3000:]
    written = [*(c for c in command if not c.startswith("models=")), "models=[dc_motor,diagnosed]"]
    for extra, message in (([], "give diagnose=M"), (["diagnose=no_such_model"], "diagnose=no_such_model is not")):
        refused = subprocess.run([*written, *extra, f"hydra.run.dir={tmp_path / 'refused'}"], cwd=ROOT,
                                 capture_output=True, text=True, timeout=300, env=env, check=False)
        assert refused.returncode == 1 and message in refused.stderr, refused.stderr[-3000:]
    (data / "test.csv").write_bytes((data / "val.csv").read_bytes())
    result = subprocess.run([*command, f"hydra.run.dir={tmp_path / 'run'}"], cwd=ROOT, capture_output=True, text=True,
                            timeout=600, env=env, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    scores = json.loads((tmp_path / "run" / "benchmark.json").read_text())["dc_motor"]["models"]["dc_motor"]
    assert scores["test_sets"]["test"]["speed"]["r2"] > 0.999


def test_a_null_past_is_chosen_for_the_model_and_recorded(tmp_path: Path) -> None:
    """data.past=null (the default of a data set that sets none): the motor's current is estimated
    from the measured speed, 2 states from 1 output, so each window sees 4 x 2 - 1 = 7 past samples;
    hypa train says so and records 7 (what hypa evaluate rebuilds), hypa simulate chooses the same,
    and a model that estimates nothing keeps 0. The end-to-end LSTM, which starts from the measured
    outputs over the past, gets 4 times the order of the data's linear predictor (``linear_memory``)."""
    import yaml

    data = tmp_path / "data"
    env = make_dc_motor_data(data, 10)
    common = ["--config-dir", str(EXAMPLE / "conf"), "dataset=dc_motor", f"data.dir={data}", "data.past=null"]

    def run(*args: str) -> str:
        result = hypa_run([*args[0].split()[1:], *args[1:]], env=env)
        assert result.returncode == 0, result.stderr[-3000:]
        return result.stdout

    out = run("hypa train", *common, "model=dc_motor", "trainer.max_epochs=1", "trainer.enable_progress_bar=false",
              f"hydra.run.dir={tmp_path / 'train'}")
    assert "data.past: 7 samples before each window (0.007 s), chosen for the model" in out, out[-2000:]
    assert yaml.safe_load((tmp_path / "train" / "config.yaml").read_text())["data"]["past"] == 7
    out = run("hypa simulate", *common, "model=dc_motor", "plot=false", f"hydra.run.dir={tmp_path / 'simulate'}")
    assert "data.past: 7 samples" in out, out[-2000:]
    out = run("hypa train", *common, "model=blackbox", "trainer.max_epochs=1", "trainer.limit_train_batches=2",
              "trainer.limit_val_batches=2", "trainer.enable_progress_bar=false", f"hydra.run.dir={tmp_path / 'lstm'}")
    assert "network 'network' starts from the measured outputs over the past" in out, out[-2000:]
    past = yaml.safe_load((tmp_path / "lstm" / "config.yaml").read_text())["data"]["past"]
    assert 7 <= past <= 100 and (past == 100 or (past + 1) % 4 == 0), past  # 4 x the order - 1, at most a window
    measured = {"name": "measured", "outputs": ["speed"], "blocks": {"motor": {
        "kind": "physics", "system": "dc_motor:DCMotor", "inputs": ["voltage"], "outputs": ["speed"],
        "initial_state": "steady", "scale_as": ["speed"]}}}
    (tmp_path / "conf" / "model").mkdir(parents=True)
    (tmp_path / "conf" / "model" / "steady.yaml").write_text("# @package model\n" + yaml.safe_dump(measured))
    out = run("hypa simulate", *common, "model=steady", "plot=false", f"hydra.searchpath=[file://{tmp_path / 'conf'}]",
              f"hydra.run.dir={tmp_path / 'steady'}")
    assert "data.past:" not in out
