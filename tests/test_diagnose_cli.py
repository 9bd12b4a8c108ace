"""python -m hypa.diagnose end to end: a hidden steering delay is named, fixed and gains; bad input fails clearly.

The delay case: the test bench's truth is the nominal linear single track (tires, relaxation,
rear steering and sensor biases off; white sensor noise on) plus a 60 ms dead time on the
steering, and the nominal hold is FOH as in conf/diagnose.yaml. Tolerance of the delay: the
candidate's grid (20 ms) is refined twice around the best point to ~2 ms, and white noise on
~2.5 minutes of data moves the optimum by less than that (test_diagnosis_naming uses the same
5 ms over random delays).
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from data_helpers import ALL_CHANNELS, make_data_dir

ROOT = Path(__file__).resolve().parents[1]
SHORT = [f"testbench.records.{name}.stochastic_duration_s={d}" for name, d in
         (("train_1", 40), ("train_2", 40), ("val", 30))] + ["testbench.records.val.maneuvers=[]"]
DELAY_ONLY = ["testbench.tires.enabled=false", "testbench.relaxation.enabled=false",
              "testbench.rear_steering.enabled=false", "testbench.sensors.bias_scale=0",
              "testbench.steering.delay_s=0.06"]


def run_diagnose(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HYPA_CACHE_DIR": str(tmp_path / "cache")}
    return subprocess.run([sys.executable, "-m", "hypa.diagnose", f"hydra.run.dir={tmp_path / 'run'}", *overrides],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def delay_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    tmp = tmp_path_factory.mktemp("diagnose")
    return run_diagnose(tmp, *SHORT, *DELAY_ONLY), tmp / "run"


def test_hidden_delay_is_named_with_its_estimate(delay_run) -> None:
    result, run = delay_run
    assert result.returncode == 0, result.stderr[-3000:]
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    assert diagnosis["cause"] == "input_delay"
    assert diagnosis["causes"] == ["input_delay"]
    assert diagnosis["estimate"]["delay_s"] == pytest.approx(0.06, abs=0.005)
    assert {"cause", "score", "estimate", "evidence"} <= set(diagnosis["candidates"][0])
    assert "named causes: input_delay" in result.stdout and "diagnosis.md" in result.stdout


def test_extended_model_gains_on_the_validation_records(delay_run) -> None:
    """The delay is the only error, so applying it must remove most of the squared error (noise stays)."""
    _, run = delay_run
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    assert diagnosis["extended"]["spec"]["delay_s"] == pytest.approx(diagnosis["estimate"]["delay_s"])
    before, after = diagnosis["baseline"]["metrics"]["all"], diagnosis["extended"]["metrics"]["all"]
    for state in ("yaw_rate", "side_slip", "overall"):
        assert after[state]["mse"] < 0.2 * before[state]["mse"]
        assert diagnosis["gain"]["all"][state] < -0.8
    # a 60 ms delay is a phase lag of 2π f d: visible in the nominal transfer function, gone after
    transfer = diagnosis["gain"]["transfer"]
    assert transfer["nominal"]["phase_difference_deg"] < -10.0
    assert abs(transfer["extended"]["phase_difference_deg"]) < 3.0


def test_extended_model_is_a_hypa_model_that_trains(delay_run, tmp_path: Path) -> None:
    """Step 3 as a hypa model: the written config has the dead time at the estimate, and the
    printed command trains it through the real CLI (one short epoch) with the delay trainable."""
    result, run = delay_run
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    config = Path(diagnosis["extended"]["config"])
    assert config == run / "conf" / "model" / "diagnosed.yaml"
    model = yaml.safe_load(config.read_text())
    assert model["hold"] == "foh"
    assert model["blocks"]["dead_time"]["parameters"]["delay_s"] == pytest.approx(diagnosis["estimate"]["delay_s"])
    assert model["blocks"]["dead_time"]["trainable"] == ["delay_s"]
    command = diagnosis["extended"]["train_command"]
    assert command in result.stdout and command in (run / "diagnosis.md").read_text()
    words = shlex.split(command)
    assert words[:3] == ["python", "-m", "hypa.train"] and "testbench.steering.delay_s=0.06" in words
    env = {**os.environ, "HYPA_CACHE_DIR": str(run.parent / "cache")}
    trained = subprocess.run(
        [sys.executable, *words[1:], f"hydra.run.dir={tmp_path / 'train'}", "trainer.max_epochs=1",
         "trainer.limit_train_batches=3", "figures.enabled=false", "trainer.enable_progress_bar=false"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert trained.returncode == 0, trained.stderr[-3000:]
    checkpoint = torch.load(next((tmp_path / "train" / "checkpoints").glob("best-*.ckpt")), weights_only=False)
    delay = checkpoint["state_dict"]["model.parameters_.raw.dead_time/delay_s"].exp().item()
    assert delay == pytest.approx(diagnosis["estimate"]["delay_s"], abs=0.01)
    assert delay != diagnosis["estimate"]["delay_s"]  # trained, not only loaded


def test_report_and_figures_are_written(delay_run) -> None:
    _, run = delay_run
    report = (run / "diagnosis.md").read_text()
    for heading in ("What is wrong", "Why we think so", "What we changed", "What it gained"):
        assert heading in report
    for name in ("time_series_val.png", "error_vs_ay.png", "transfer_nominal.png", "correlations.png",
                 "mean_error.png", "transfer_before_after.png"):
        assert (run / name).stat().st_size > 10_000, name
        assert f"]({name})" in report


def test_missing_column_names_the_column(tmp_path: Path) -> None:
    folder = make_data_dir(tmp_path / "data", channels=tuple(c for c in ALL_CHANNELS if c != "side_slip"))
    result = run_diagnose(tmp_path, "dataset=files", f"data.dir={folder}")
    assert result.returncode != 0
    assert "side_slip" in result.stderr and "Traceback" not in result.stderr


def test_unstable_nominal_parameters_fail_before_reading_data(tmp_path: Path) -> None:
    """A weak rear axle makes the single track oversteer beyond its critical speed (unstable at 33 m/s)."""
    result = run_diagnose(tmp_path, "dataset=files", f"data.dir={tmp_path / 'nowhere'}", "vehicle.cr=20000")
    assert result.returncode != 0
    assert "unstable" in result.stderr, result.stderr[-2000:]
    assert "cr=20000" in result.stderr and "vehicle.cr" in result.stderr
    assert "Traceback" not in result.stderr


def test_extension_train_true_trains_and_reports_the_trained_gain(delay_run) -> None:
    """extension.train=true runs hypa.train on the written model inside the diagnosis folder and
    puts its free-run metrics beside the nominal and parametric ones (one short epoch here)."""
    _, first = delay_run
    env = {**os.environ, "HYPA_CACHE_DIR": str(first.parent / "cache")}  # the fixture's generated data
    run = first.parent / "run_trained"
    result = subprocess.run(
        [sys.executable, "-m", "hypa.diagnose", f"hydra.run.dir={run}", *SHORT, *DELAY_ONLY, "plot=false",
         "extension.train=true",
         'extension.train_overrides=["trainer.max_epochs=1","trainer.limit_train_batches=3","figures.enabled=false"]'],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    trained = diagnosis["extended"]["trained"]
    assert Path(trained["run"]) == run / "extended_run"
    assert next((run / "extended_run" / "checkpoints").glob("best-*.ckpt"))
    # the dead time starts at its estimate, so even one short epoch keeps most of the gain
    assert trained["gain"]["all"]["overall"] < -0.8
    assert set(trained["metrics"]["all"]) == {"yaw_rate", "side_slip", "overall"}
    assert "trained extension" in result.stdout
    assert "extension." not in diagnosis["extended"]["train_command"]  # only the data and vehicle overrides pass
    assert "RMSE trained" in (run / "diagnosis.md").read_text()
