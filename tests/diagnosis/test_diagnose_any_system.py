"""``hypa diagnose model=M`` on a user's own system, through the command a user types.

The DC motor of ``examples/user_system`` (a class by import path, its dataset and model YAMLs in
the user's config folder): its data come from a motor whose torque constant is 0.065 N m/A
where the nominal model believes 0.05, with a load torque of 4 mN m it does not know. The
diagnosis must name the torque constant's mismatch first, with its value, write an extended
model that ``hypa train`` trains, and report what remains. The voltage is a staircase, so the
nominal hold is ZOH (with FOH the half-sample difference comes out, correctly, as a 0.5 ms lag).
"""

import json
import os
import shlex
from pathlib import Path

import pytest
import yaml

from cli_helpers import hypa_run
from conftest import ROOT
from data_helpers import make_dc_motor_data

EXAMPLE = ROOT / "examples" / "user_system"


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory) -> Path:
    data, out = tmp_path_factory.mktemp("dc_motor_data"), tmp_path_factory.mktemp("dc_motor_diagnosis")
    env = make_dc_motor_data(data, 20)
    result = hypa_run(["diagnose", "--config-dir", str(EXAMPLE / "conf"), "dataset=dc_motor", "model=dc_motor",
                       f"data.dir={data}", "physics.hold=zoh", f"hydra.run.dir={out}"], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "named causes: parameter_mismatch" in result.stdout, result.stdout[-2000:]
    return out


def test_names_the_torque_constant_with_its_value(diagnosed: Path) -> None:
    result = json.loads((diagnosed / "diagnosis.json").read_text())
    first = result["named"][0]
    assert (first["cause"], first["target"]) == ("parameter_mismatch", "torque_constant")
    assert first["values"]["torque_constant"] == pytest.approx(0.065, rel=0.05)
    assert "input_delay" not in result["causes"] and "input_lag" not in result["causes"]
    assert result["score"]["extended"] < 0.2 * result["score"]["nominal"]
    assert result["candidates"][0]["cause"] == "parameter_mismatch"  # the fleet summary's schema
    assert set(result["structure"]) == {"speed"}
    report = (diagnosed / "diagnosis.md").read_text()
    assert "**parameter_mismatch** on `torque_constant`: 0.0" in report and "N m/A" in report
    assert (diagnosed / "time_series_train.png").exists() or any(diagnosed.glob("time_series_*.png"))


def test_the_extended_model_is_a_hypa_model_that_trains(diagnosed: Path, tmp_path: Path) -> None:
    written = yaml.safe_load((diagnosed / "conf" / "model" / "diagnosed.yaml").read_text())
    assert written["parameters"]["torque_constant"] == pytest.approx(0.065, rel=0.05)
    assert set(written["blocks"]["motor"]["trainable"]) == {"torque_constant", "friction", "load_torque"}
    command = json.loads((diagnosed / "diagnosis.json").read_text())["extended"]["train_command"]["diagnosed"]
    assert command.startswith("python -m hypa train --config-dir")
    env = {**os.environ, "PYTHONPATH": str(EXAMPLE)}
    assert f"--config-dir {EXAMPLE / 'conf'}" in command  # the user's dataset YAML is found again
    args = [*shlex.split(command)[1:], "trainer.max_epochs=1",
            "trainer.enable_progress_bar=false", f"hydra.run.dir={tmp_path}"]
    result = hypa_run(args[2:], env=env)  # args: -m hypa train ...
    assert result.returncode == 0, result.stderr[-3000:]
    assert "best val/loss" in result.stdout
