"""Grey-box identification by the output error (hypa.identification): a user's system (the DC-motor
example) started 30 % off its true parameters, on data simulated from the truth."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from data_helpers import USER_EXAMPLE, make_dc_motor_data
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
TRUE = {"torque_constant": 0.065, "friction": 3e-5, "load_torque": 0.004}  # examples/user_system/make_data.py
OFF = {"torque_constant": 0.065 * 0.7, "friction": 3e-5 * 1.3, "load_torque": 0.004 * 0.7}


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("dc_motor")
    make_dc_motor_data(folder, 20)
    return folder


def problem(data: Path, trainable: list[str], parameters: dict[str, float]):
    """The example's model (its nominal values replaced) and its training records as whole free runs."""
    from hypa.data import datamodule_from_config
    from hypa.identification import Stretches
    from hypa.models.spec import parse_model_spec
    from hypa.training import HybridModule

    sys.path.insert(0, str(USER_EXAMPLE))
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="train", overrides=[f"hydra.searchpath=[file://{USER_EXAMPLE / 'conf'}]",
                                                      "dataset=dc_motor", "model=dc_motor", f"data.dir={data}"])
    dm = datamodule_from_config(cfg.data, data)
    dm.setup()
    config = OmegaConf.to_container(cfg.model, resolve=True)
    config["parameters"] = parameters
    config["blocks"]["motor"]["trainable"] = trainable
    parse_model_spec(config)
    module = HybridModule(config, {}, dm.normalization.state_dict(), dm.input_names, dm.output_names, dt=dm.dt,
                          hold="zoh", past=dm.past)
    return module.model, Stretches.cut(dm, dm.records("train"), 10**9)


def test_parameters_started_30_percent_off_are_recovered_deterministically(data: Path) -> None:
    from hypa.identification import identify

    results = []
    for _ in range(2):
        model, stretches = problem(data, list(TRUE), OFF)
        results.append(identify(model, stretches))
    found = results[0].values()
    for name, value in TRUE.items():
        assert found[name] == pytest.approx(value, rel=0.02), (name, found)
    assert results[1].values() == found  # the same data, the same parameters, to the last bit
    assert results[0].converged and results[0].error_final < 1e-3 * results[0].error_initial
    assert results[0].warnings == ()
    for estimate in results[0].estimates:  # ± 1σ finite, and the truth within a few of them
        assert estimate.std is not None and abs(estimate.value - TRUE[estimate.name]) < 0.02 * TRUE[estimate.name]
    assert model.parameters_.as_floats()["torque_constant"] == pytest.approx(found["torque_constant"])


def test_a_parameter_the_data_cannot_determine_is_flagged(data: Path) -> None:
    """With the resistance free too, the speed alone cannot tell it from the others."""
    from hypa.identification import identify

    model, stretches = problem(data, [*TRUE, "resistance"], OFF)
    result = identify(model, stretches)
    flagged = [w for w in result.warnings if "resistance" in w and ("cannot be told apart" in w or "not determined" in w)]
    assert flagged, result.warnings
    assert "Warnings:" in result.markdown()


def test_a_free_run_that_is_not_finite_at_the_start_is_refused(data: Path, monkeypatch) -> None:
    import torch

    from hypa.identification import IdentificationError, Stretches, identify

    model, stretches = problem(data, list(TRUE), OFF)
    diverged = lambda self, model: [(torch.full_like(b["y"][:, self.first:], torch.inf), b["y"][:, self.first:])  # noqa: E731
                                    for b in self.batches]
    monkeypatch.setattr(Stretches, "predict", diverged)
    with pytest.raises(IdentificationError, match="not finite at its starting parameters"):
        identify(model, stretches)


def test_hypa_train_identifies_a_physics_only_model(data: Path, tmp_path: Path) -> None:
    """Through the command line: the run's checkpoint holds the identified parameters, its run.json
    and identification.md the report, and hypa.evaluate scores it."""
    env = make_dc_motor_data(tmp_path / "unused", 1)
    run = tmp_path / "run"
    command = [sys.executable, "-m", "hypa.train", "--config-dir", str(USER_EXAMPLE / "conf"), "dataset=dc_motor",
               "model=dc_motor", f"data.dir={data}", "identification.enabled=true", "trainer.enable_progress_bar=false",
               f"hydra.run.dir={run}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "identified 3 parameter(s)" in result.stdout and "after identification" in result.stdout
    record = json.loads((run / "run.json").read_text())
    identified = record["identification"]
    assert identified["converged"] and identified["warnings"] == []
    for name, value in TRUE.items():
        assert identified["parameters"][name]["value"] == pytest.approx(value, rel=0.02)
    assert record["best_checkpoint"]["path"] == "checkpoints/best-identified.ckpt"
    assert "| torque_constant | 0.05 | 0.065 |" in (run / "identification.md").read_text()
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    board = EventAccumulator(str(run / "tensorboard"), size_guidance={"tensors": 0}).Reload()
    assert {"physics/torque_constant", "val/loss"} <= set(board.Tags()["scalars"])
    assert "identification/text_summary" in board.Tags()["tensors"]
    assert board.Scalars("physics/torque_constant")[0].value == pytest.approx(0.065, rel=0.02)
    evaluated = subprocess.run([sys.executable, "-m", "hypa.evaluate", f"run={run}", f"out={tmp_path / 'eval'}",
                                "tensorboard=false", f"hydra.run.dir={tmp_path / 'hydra'}"],
                               cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert metrics["splits"]["val"]["free_run"]["all"]["speed"]["r2"] > 0.999
    assert "## Identification" in (tmp_path / "eval" / "summary.md").read_text()  # the run's report says how


@pytest.mark.parametrize("override, message", [
    ("identification.tolerance=0", "identification.tolerance=0 must be > 0"),
    ("identification.stretch_s=-1", "identification.stretch_s=-1 must be > 0"),
    ("identification.max_evaluations=0", "identification.max_evaluations=0 must be >= 1"),
    ("identification.enabled=maybe", "identification.enabled=maybe is not true or false"),
])
def test_bad_identification_settings_are_refused(override: str, message: str) -> None:
    """Read by hypa.train before any data (its UserError is the command's one line, tests/test_cli_errors.py)."""
    from hypa.errors import UserError
    from hypa.train import identification_settings

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="train", overrides=["identification.enabled=true", override])
    with pytest.raises(UserError, match=message.replace("(", r"\(")):
        identification_settings(cfg)
