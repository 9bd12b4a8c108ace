"""The real data sets (../shared/data) through the commands a user types: every benchmark model
trains a few batches on each, and ``python -m hypa.benchmark`` writes its table and JSON."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
pytestmark = pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data is not beside the project")
TINY = ["trainer.max_epochs=1", "trainer.limit_train_batches=2", "trainer.limit_val_batches=2",
        "trainer.enable_progress_bar=false", "figures.enabled=true", "figures.seconds=2", "figures.start_s=0",
        "ann.hidden_size=8"]
CASES = [(d, m) for d in ("silverbox", "emps", "racecar") for m in (f"{d}_physical", f"{d}_hybrid", "blackbox")]


def hypa(module: str, *args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("dataset, model", CASES)
def test_every_benchmark_model_trains_on_the_real_data(dataset: str, model: str, tmp_path: Path) -> None:
    result = hypa("hypa.train", f"dataset={dataset}", f"model={model}", *TINY, f"hydra.run.dir={tmp_path}")
    assert result.returncode == 0, result.stderr[-3000:]
    info = json.loads((tmp_path / "run.json").read_text())
    assert info["best_val_loss"] == info["best_val_loss"] and info["best_val_loss"] < 10  # finite, sane
    assert list((tmp_path / "tensorboard").glob("events.out.tfevents.*"))


def test_benchmark_writes_the_table_and_json(tmp_path: Path) -> None:
    result = hypa("hypa.benchmark", "dataset=racecar", "models=[physical]", "train_overrides=['ann.hidden_size=8']",
                  f"hydra.run.dir={tmp_path}")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "| test | yaw_rate |" in result.stdout and "deg/s" in result.stdout
    content = json.loads((tmp_path / "benchmark.json").read_text())["racecar"]
    scores = content["models"]["physical"]["test_sets"]["test"]
    assert set(scores) == {"yaw_rate", "side_slip"}
    assert scores["yaw_rate"]["r2"] > 0.5 and scores["yaw_rate"]["rms"] > 0  # rad/s, SI
    assert content["models"]["physical"]["training_time_s"] > 0
