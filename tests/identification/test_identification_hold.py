"""The hold chosen by the data (``hypa.training.identified.choose_hold``): a model without a hold of its own,
run without ``physics.hold``, is identified under both holds and keeps the better fit, and every later
command rebuilds it. A resonance sampled at 12 samples per period, its force smooth (linear between
samples: a first-order hold is the truth) or held over each sample (a zero-order hold is), through
``hypa train`` with a data set of the user's."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import signal

from cli_helpers import hypa_run
from data_helpers import user_dataset

FS = 1000.0  # [Hz]
MASS, STIFFNESS, DAMPING = 1e-3, 4.7, 3e-3  # a 55 Hz resonance, damping ratio 0.02

DATASET = user_dataset({
    "time": {"column": "time", "unit": "s"}, "sample_rate_hz": FS,
    "channels": {"force": {"role": "input", "unit": "N"}, "position": {"role": "output", "unit": "m"}},
    "splits": {"train": [{"file": "run.csv", "start": 0.0, "stop": 0.7}],
               "val": [{"file": "run.csv", "start": 0.7, "stop": 1.0}]},
    "past": 10})

MODEL = """# @package model
name: resonance
blocks:
  axis:
    kind: physics
    system: mass_spring_damper
    inputs: [force]
    outputs: [position]
    initial_state: estimate
    trainable: [mass, stiffness, damping]
parameters: {mass: 1.3e-3, stiffness: 5.5, damping: 2e-3, offset_force: 0.0}
outputs: [position]
stages: []
"""


def _record(hold: str, samples: int = 3000) -> np.ndarray:
    """(time, force, position): a random-phase multisine force up to 150 Hz, exact under ``hold``."""
    rng = np.random.default_rng(0)
    t = np.arange(samples) / FS
    force = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in np.linspace(5, 150, 30)) * 2e-3
    system = ([1.0], [MASS, DAMPING, STIFFNESS])
    num, den, _ = signal.cont2discrete(system, 1 / FS, method=hold)
    position = signal.lfilter(num.ravel(), den, force)
    return np.column_stack([t, force, position])


@pytest.fixture(scope="module")
def user(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("resonance")
    (folder / "conf" / "dataset").mkdir(parents=True)
    (folder / "conf" / "model").mkdir()
    (folder / "conf" / "dataset" / "resonance.yaml").write_text(DATASET)
    (folder / "conf" / "model" / "resonance.yaml").write_text(MODEL)
    for hold in ("zoh", "foh"):
        (folder / hold).mkdir()
        np.savetxt(folder / hold / "run.csv", _record(hold), fmt="%.12g", delimiter=",",
                   header="time,force,position", comments="")
    return folder


def _train(user: Path, data: str, run: Path, *extra: str) -> subprocess.CompletedProcess:
    return hypa_run(["train", "--config-dir", str(user / "conf"), "dataset=resonance", "model=resonance",
                     f"data.dir={user / data}", "trainer.enable_progress_bar=false", "figures.enabled=false", *extra,
                     f"hydra.run.dir={run}"])


@pytest.mark.parametrize("truth", ["foh", "zoh"])
def test_the_data_choose_the_hold_they_were_made_with(user: Path, tmp_path: Path, truth: str) -> None:
    result = _train(user, truth, tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    line = next(x for x in result.stdout.splitlines() if x.startswith("hold: "))
    assert line.startswith(f"hold: {truth}, chosen by the data"), line
    record = json.loads((tmp_path / "run.json").read_text())
    choice = record["hold"]
    other = "zoh" if truth == "foh" else "foh"
    assert choice["chosen"] == truth and choice["output_error"][truth] < 0.1 * choice["output_error"][other], choice
    assert record["identification"]["error"]["final"] == pytest.approx(choice["output_error"][truth])
    config = yaml.safe_load((tmp_path / "config.yaml").read_text())
    assert config["physics"]["hold"] == truth and config["model"]["hold"] is None  # what later commands rebuild
    evaluated = hypa_run(["evaluate", f"run={tmp_path}", "tensorboard=false",
                          f"hydra.run.dir={tmp_path.parent / (tmp_path.name + '-evaluate')}"])  # not the checkout's
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    metrics = json.loads((tmp_path / "evaluation" / "metrics.json").read_text())
    assert "position" in json.dumps(metrics)


def test_a_given_hold_is_kept_without_a_second_fit(user: Path, tmp_path: Path) -> None:
    result = _train(user, "foh", tmp_path, "physics.hold=zoh")
    assert result.returncode == 0, result.stderr[-3000:]
    assert not any(x.startswith("hold: ") for x in result.stdout.splitlines())
    record = json.loads((tmp_path / "run.json").read_text())
    assert "hold" not in record and record["identification"]["error"]["final"] > 1e-4
