"""Every ``python -m hypa.*`` command stops on a user's mistake with one line and exit status 1.

A table of commands x bad inputs (a bad override value, a missing run folder, a file that is no
checkpoint, a checkpoint of another program, bad test-bench settings, an empty results folder):
each must exit 1 with no traceback, its last stderr line ``hypa.<cmd>: error: ...`` (or Hydra's
own one-line hint for a configuration Hydra cannot compose), and name what is wrong.
``HYDRA_FULL_ERROR=1`` still shows the traceback.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
import torch

from cli_helpers import hypa_run
from data_helpers import make_data_dir

HYDRA_HINT = "Set the environment variable HYDRA_FULL_ERROR=1 for a complete stack trace."
FILES = ["dataset=files", "data.dir={data}"]  # never the test bench's generated data: fast


@pytest.fixture(scope="module")
def places(tmp_path_factory) -> dict[str, Path]:
    """A small data folder, a run folder whose checkpoint is a text file, and one whose
    checkpoint is another program's (a torch file without a hypa model)."""
    root = tmp_path_factory.mktemp("cli-errors")
    data = make_data_dir(root / "data", duration_s=6.0)
    text_run, other_run = root / "text_run", root / "other_run"
    for run in (text_run, other_run):
        (run / ".hydra").mkdir(parents=True)
        (run / ".hydra" / "config.yaml").write_text("model: {name: physical}\n")
        (run / "checkpoints").mkdir()
    (text_run / "checkpoints" / "last.ckpt").write_text("not a checkpoint\n")
    torch.save({"state_dict": {"w": torch.zeros(2)}, "epoch": 3}, other_run / "checkpoints" / "last.ckpt")
    return {"data": data, "text_run": text_run, "other_run": other_run, "root": root}


# id, command, overrides ({name} from the fixture), a part of the message
CASES = [
    ("train-max_epochs-text", "hypa train", [*FILES, "trainer.max_epochs=abc"],
     "trainer.max_epochs=abc is not an integer"),
    ("train-window-negative", "hypa train", [*FILES, "data.window=-3"], "data.window must be >= 1"),
    ("train-unknown-model", "hypa train", [*FILES, "model=nonexistent"], "Could not find 'model/nonexistent'"),
    ("train-unknown-hold", "hypa train", [*FILES, "physics.hold=xyz"], "physics.hold=xyz is not one of zoh, foh"),
    ("train-hold-against-the-model", "hypa train",
     ["dataset=silverbox", "model=silverbox_physical", "physics.hold=zoh"],
     "model 'silverbox_physical' fixes hold: cubic, but physics.hold=zoh was given"),
    ("diagnose-hold-against-the-model", "hypa diagnose",
     ["dataset=silverbox", "model=silverbox_physical", "physics.hold=zoh"], "but physics.hold=zoh was given"),
    ("train-ann-size", "hypa train", [*FILES, "model=v1", "ann.hidden_size=-2"],
     "ann=lstm: hidden_size and num_layers must be >= 1"),
    ("train-trainer-lightning", "hypa train", [*FILES, "trainer.accelerator=abacus"],
     "trainer: You selected an invalid accelerator name"),
    ("evaluate-missing-run", "hypa evaluate", ["run={root}/nowhere"], "nowhere does not exist"),
    ("evaluate-text-checkpoint", "hypa evaluate", ["run={text_run}/checkpoints/last.ckpt"],
     "text_run/checkpoints/last.ckpt: not a readable checkpoint"),
    ("evaluate-no-recorded-checkpoint", "hypa evaluate", ["run={text_run}"],
     "text_run/run.json records no best checkpoint"),
    ("evaluate-foreign-checkpoint", "hypa evaluate", ["run={other_run}/checkpoints/last.ckpt"],
     "last.ckpt: not a checkpoint of hypa train"),
    ("simulate-unknown-hold", "hypa simulate", [*FILES, "physics.hold=both"],
     "physics.hold=both is not one of zoh, foh"),
    ("simulate-networks", "hypa simulate", [*FILES, "model=v1"],
     "hypa simulate runs physics only; model v1 has the network blocks rear_steering"),
    ("testbench-seed-text", "hypa testbench", ["testbench.records.val.seed=abc"],
     "testbench.records.val.seed: Value 'abc'"),
    ("testbench-zero-duration", "hypa testbench", ["testbench.records.train_2.stochastic_duration_s=0"],
     "record 'train_2': stochastic_duration_s must be > 0"),
    ("train-splits-composition", "hypa train", [*FILES, "data.splits={{train:[a]}}"], "full_key: data.splits"),
    ("diagnose-vehicle-negative", "hypa diagnose", [*FILES, "vehicle.cf=-1"], "'cf' must be positive, got -1.0"),
    ("diagnose-missing-catalogue", "hypa diagnose", [*FILES, "diagnosis.catalogue=[{root}/missing.yaml]"],
     "missing.yaml"),
    ("reproduce-no-runs", "hypa reproduce", ["skip_training=true", "out={root}/results"], "no runs in"),
]


def hypa(command: str, overrides: list[str], places: dict[str, Path], tmp_path: Path,
         **env: str) -> subprocess.CompletedProcess:
    args = [o.format(**places) for o in overrides]
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    environment.update(HYPA_CACHE_DIR=str(tmp_path / "cache"), **env)
    return hypa_run([*command.split()[1:], *args, f"hydra.run.dir={tmp_path / 'run'}"], env=environment)


@pytest.mark.parametrize("command, overrides, message", [pytest.param(*case[1:], id=case[0]) for case in CASES])
def test_user_error_is_one_line_with_exit_status_1(command: str, overrides: list[str], message: str,
                                                   places: dict[str, Path], tmp_path: Path) -> None:
    result = hypa(command, overrides, places, tmp_path)
    assert result.returncode == 1, result.stderr[-3000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    assert message in result.stderr, result.stderr[-3000:]
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"{command}: error: ") or last == HYDRA_HINT, last


def test_hydra_full_error_keeps_the_traceback(places: dict[str, Path], tmp_path: Path) -> None:
    result = hypa("hypa evaluate", ["run={text_run}/checkpoints/last.ckpt"], places, tmp_path, HYDRA_FULL_ERROR="1")
    assert result.returncode == 1
    assert "Traceback" in result.stderr and "UserError" in result.stderr
    assert "not a readable checkpoint" in result.stderr


def test_a_data_folder_without_dataset_files_is_not_silently_ignored(tmp_path) -> None:
    """``data.dir=PATH`` alone would have trained on the test bench: one line says what to add."""
    result = hypa_run(["train", f"data.dir={tmp_path}", f"hydra.run.dir={tmp_path}"])
    assert result.returncode == 1
    assert "add dataset=files" in result.stderr.strip().splitlines()[-1] and "Traceback" not in result.stderr
