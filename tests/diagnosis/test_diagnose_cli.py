"""hypa diagnose end to end: a hidden steering delay is named, fixed and gains; bad input fails clearly.

The delay case: the test bench's truth is the nominal linear single track (tires, relaxation,
rear steering and sensor biases off; white sensor noise on) plus a 60 ms dead time on the
steering; the nominal model is the default ``model=vehicle_nominal`` (FOH, as in
conf/diagnose.yaml). The dead time is a gradient fit of a fractional delay; white noise on
about 2 minutes of data moves it by a few ms (the hit-rate tests of test_diagnose_vehicle.py
use 15 % over random delays).
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cli_helpers import hypa_run
from conftest import ROOT
from data_helpers import ALL_CHANNELS, make_data_dir

SHORT = [f"testbench.records.{name}.stochastic_duration_s={d}" for name, d in
         (("train_1", 40), ("train_2", 40), ("val", 30))] + ["testbench.records.val.maneuvers=[]"]
DELAY_ONLY = ["testbench.tires.enabled=false", "testbench.relaxation.enabled=false",
              "testbench.load_transfer.enabled=false", "testbench.rear_steering.transient_ratio=0",
              "testbench.rear_steering.enabled=false", "testbench.sensors.bias_scale=0",
              "testbench.steering.delay_s=0.06"]


def run_diagnose(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HYPA_CACHE_DIR": str(tmp_path / "cache")}
    return hypa_run(["diagnose", f"hydra.run.dir={tmp_path / 'run'}", *overrides], env=env)


@pytest.fixture(scope="module")
def delay_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    tmp = tmp_path_factory.mktemp("diagnose")
    return run_diagnose(tmp, *SHORT, *DELAY_ONLY), tmp / "run"


DELAY_BLOCK = "diagnosed_delay_steering_wheel_angle"


def test_hidden_delay_is_named_with_its_estimate(delay_run) -> None:
    result, run = delay_run
    assert result.returncode == 0, result.stderr[-3000:]
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    assert diagnosis["cause"] == "input_delay"
    assert diagnosis["causes"] == ["input_delay"]
    assert diagnosis["estimate"][f"{DELAY_BLOCK}/delay_s"] == pytest.approx(0.06, abs=0.008)
    assert {"cause", "target", "score", "estimate", "evidence"} <= set(diagnosis["candidates"][0])
    assert diagnosis["named"][0]["units"][f"{DELAY_BLOCK}/delay_s"] == "s"
    assert "named causes: input_delay" in result.stdout and "diagnosis.md" in result.stdout


def test_extended_model_gains_on_the_validation_records(delay_run) -> None:
    _, run = delay_run
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    before, after = diagnosis["metrics"]["nominal"], diagnosis["metrics"]["extended"]
    for output in ("yaw_rate", "side_slip"):
        assert after[output]["mse"] < 0.2 * before[output]["mse"]
        assert diagnosis["gain"]["all"][output] < -0.8
    assert diagnosis["gain"]["all"]["overall"] < -0.8
    assert diagnosis["unexplained"] == []


def test_extended_model_is_a_hypa_model_that_trains(delay_run, tmp_path: Path) -> None:
    _, run = delay_run
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    config = Path(diagnosis["extended"]["config"]["diagnosed"])
    assert config == run / "conf" / "model" / "diagnosed.yaml"
    model = yaml.safe_load(config.read_text())
    estimate = diagnosis["estimate"][f"{DELAY_BLOCK}/delay_s"]
    assert model["blocks"][DELAY_BLOCK]["parameters"]["delay_s"] == pytest.approx(estimate)
    assert model["blocks"][DELAY_BLOCK]["trainable"] == ["delay_s"]
    assert model["hold"] == "foh"  # the hold it was diagnosed with: the fitted values belong to it
    assert "diagnosed_learned" not in diagnosis["extended"]["config"]  # a dead time is no subsystem to learn
    # nothing is left unexplained here, and the hybrid on the extension is written all the same (the benchmark's row)
    hybrid = yaml.safe_load(Path(diagnosis["extended"]["config"]["diagnosed_hybrid"]).read_text())
    assert hybrid["name"] == "diagnosed_hybrid" and hybrid["blocks"][DELAY_BLOCK] == model["blocks"][DELAY_BLOCK]
    assert "diagnosed_hybrid.yaml" in diagnosis["extended"]["train_command"]["diagnosed_hybrid"]
    command = diagnosis["extended"]["train_command"]["diagnosed"]
    assert command in (run / "diagnosis.md").read_text()
    words = shlex.split(command)
    assert words[:4] == ["python", "-m", "hypa", "train"] and "testbench.steering.delay_s=0.06" in words
    env = {**os.environ, "HYPA_CACHE_DIR": str(run.parent / "cache")}
    trained = hypa_run([*words[3:], f"hydra.run.dir={tmp_path / 'train'}", "trainer.max_epochs=1",
                        "trainer.limit_train_batches=3", "figures.enabled=false"], env=env)
    assert trained.returncode == 0, trained.stderr[-3000:]
    from hypa.evaluation.runs import load_run

    delay = float(load_run(tmp_path / "train").module.model.parameters_.value(f"{DELAY_BLOCK}/delay_s"))
    assert delay == pytest.approx(estimate, abs=0.01)
    assert delay != estimate  # trained, not only loaded


def test_report_and_figures_are_written(delay_run) -> None:
    _, run = delay_run
    report = (run / "diagnosis.md").read_text()
    for heading in ("## Named causes", "## Per output", "## What remains", "## The extended model",
                    "## Every candidate of the first round"):
        assert heading in report
    assert "input_delay** on `steering_wheel_angle`" in report and " ms" in report
    name = "time_series_val.png"
    assert (run / name).stat().st_size > 10_000
    assert f"]({name})" in report


def test_missing_column_names_the_column(tmp_path: Path) -> None:
    folder = make_data_dir(tmp_path / "data", channels=tuple(c for c in ALL_CHANNELS if c != "side_slip"))
    result = run_diagnose(tmp_path, "dataset=files", f"data.dir={folder}")
    assert result.returncode != 0
    assert "side_slip" in result.stderr and "Traceback" not in result.stderr


def test_unstable_nominal_parameters_fail_in_one_line(delay_run) -> None:
    """A weak rear axle makes the single track oversteer beyond its critical speed (unstable at 33 m/s)."""
    _, first = delay_run
    result = run_diagnose(first.parent / "unstable", *SHORT, "vehicle.cr=20000")
    assert result.returncode != 0
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith("hypa diagnose: error:") and "unstable" in error, result.stderr[-2000:]
    assert "cr=20000" in error and "Traceback" not in result.stderr


def test_extension_train_true_trains_and_reports_the_trained_gain(delay_run) -> None:
    """extension.train=true runs hypa train on the written model inside the diagnosis folder and
    puts its free-run metrics beside the nominal and parametric ones (one short epoch here)."""
    _, first = delay_run
    env = {**os.environ, "HYPA_CACHE_DIR": str(first.parent / "cache")}  # the fixture's generated data
    run = first.parent / "run_trained"
    result = hypa_run(
        ["diagnose", f"hydra.run.dir={run}", *SHORT, *DELAY_ONLY, "plot=false", "extension.train=true",
         'extension.train_overrides=["trainer.max_epochs=1","trainer.limit_train_batches=3","figures.enabled=false"]'],
        env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    trained = diagnosis["extended"]["trained"]
    assert Path(trained["run"]) == run / "extended_run" and trained["model"] == "diagnosed"
    assert next((run / "extended_run" / "checkpoints").glob("best-*.ckpt"))
    # the dead time starts at its estimate, so even one short epoch keeps most of the gain
    assert trained["gain"]["all"]["overall"] < -0.8
    assert set(trained["metrics"]) == {"yaw_rate", "side_slip"}
    assert "trained extension" in result.stdout
    assert "extension." not in diagnosis["extended"]["train_command"]["diagnosed"]  # only the data overrides pass
    assert "trained RMS" in (run / "diagnosis.md").read_text()


def test_the_trained_correction_network_is_explained(delay_run) -> None:
    """With no cause allowed (max_causes=0) the delay stays unexplained: the diagnosis writes the
    hybrid, extension.train=true trains it, and what its correction network adds to each output is
    explained by hypa.explain's ladder, in the report, the json and extended_run/explanation."""
    _, first = delay_run
    env = {**os.environ, "HYPA_CACHE_DIR": str(first.parent / "cache")}
    run = first.parent / "run_explained"
    result = hypa_run(
        ["diagnose", f"hydra.run.dir={run}", *SHORT, *DELAY_ONLY, "plot=false", "diagnosis.max_causes=0",
         "extension.train=true",
         'extension.train_overrides=["trainer.max_epochs=1","trainer.limit_train_batches=3","figures.enabled=false"]'],
        env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    diagnosis = json.loads((run / "diagnosis.json").read_text())
    trained = diagnosis["extended"]["trained"]
    assert trained["model"] == "diagnosed_hybrid"
    explained = trained["explained"]
    assert [(e["block"], e["signal"]) for e in explained] == [("correction", "yaw_rate_correction"),
                                                               ("correction", "side_slip_correction")]
    for e in explained:
        assert e["description"].startswith(f"{e['signal']} = ") and "explains" in e["description"]
        assert Path(e["report"]) == run / "extended_run" / "explanation" / "explanation.md"
    explanation = json.loads((run / "extended_run" / "explanation" / "explanation.json").read_text())
    assert explanation["blocks"][0]["corrects"] == ["yaw_rate", "yaw_rate_physics"]
    assert "yaw_rate_correction = yaw_rate − yaw_rate_physics" in Path(explained[0]["report"]).read_text()
    assert "What its networks learned" in (run / "diagnosis.md").read_text()
    assert "its network correction learned: yaw_rate_correction = " in result.stdout


def test_a_failing_extension_training_is_one_line_with_the_command_to_rerun(delay_run) -> None:
    """The extension trains in the diagnosis's own process: a bad training setting ends the command
    with one line that names the step and gives the ``hypa train`` command to run it alone."""
    _, first = delay_run
    env = {**os.environ, "HYPA_CACHE_DIR": str(first.parent / "cache")}
    run = first.parent / "run_failing_extension"
    result = subprocess.run(
        [sys.executable, "-m", "hypa", "diagnose", f"hydra.run.dir={run}", *SHORT, *DELAY_ONLY, "plot=false",
         "extension.train=true", 'extension.train_overrides=["trainer.max_epochs=abc"]'],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 1, result.stderr[-3000:]
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith("hypa diagnose: error: training the extended model failed: "), result.stderr[-2000:]
    assert "trainer.max_epochs=abc" in error and "run it alone: python -m hypa train " in error
    assert "model_file=" in error and "Traceback" not in result.stderr
