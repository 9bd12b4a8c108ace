"""The tests' ``hypa_run`` (tests/cli_helpers.py): a command run in the test's process answers as the
child process would, and leaves the process as it found it, twice in a row.

Most CLI tests run their commands by ``hypa_run``; each command still runs as a real ``python -m hypa``
somewhere in ``make test``: train, evaluate, diagnose, export and benchmark in
tests/core/test_output_folders.py (held folders) and tests/core/test_run_trust.py (a full disk, two
runs at once), diagnose in tests/core/test_bounded_settings.py (Ctrl-C) and tests/diagnosis/test_fleet.py
(a sweep), timing and the dispatch in tests/commands/test_cli.py, and simulate, testbench, explain and
reproduce below, beside the same command in this process.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch

from cli_helpers import hypa_run
from conftest import ROOT
from data_helpers import make_data_dir

FAST = ["model=physical", "identification.enabled=false", "dataset=files", "trainer.max_epochs=1",
        "trainer.enable_progress_bar=false", "figures.enabled=false", "data.batch_size=8", "torch_threads=1"]


def state() -> dict:
    """What a command changes in its process (what hypa_run restores)."""
    return {"cwd": os.getcwd(), "environ": dict(os.environ), "argv": list(sys.argv), "path": list(sys.path),
            "spec": sys.modules["__main__"].__spec__, "threads": torch.get_num_threads(),
            "root": (logging.root.level, list(logging.root.handlers)), "sigint": signal.getsignal(signal.SIGINT),
            "random": torch.random.get_rng_state().tolist()}


def test_a_command_runs_twice_in_this_process_and_leaves_it_as_it_was(tmp_path: Path) -> None:
    data = make_data_dir(tmp_path / "data", duration_s=6.0)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)  # not the run's torch_threads=1
    try:
        before = state()
        env = {**os.environ, "HYDRA_FULL_ERROR": "0", "A_TESTS_OWN": "1"}
        trained = hypa_run(["train", *FAST, f"data.dir={data}", f"hydra.run.dir={tmp_path / 'run'}"],
                           cwd=tmp_path, env=env)
        assert trained.returncode == 0, trained.stderr[-3000:]
        assert "best val/loss" in trained.stdout and (tmp_path / "run" / "run.json").is_file()
        assert state() == before
        # the same folder again: the command's one-line error and exit status 1, in the same process
        refused = hypa_run(["train", *FAST, f"data.dir={data}", f"hydra.run.dir={tmp_path / 'run'}", "seed=7"],
                           cwd=tmp_path, env=env)
        assert refused.returncode == 1 and "Traceback" not in refused.stderr, refused.stderr[-3000:]
        assert refused.stderr.strip().splitlines()[-1].startswith("hypa train: error: ")
        assert "already holds another run's checkpoints" in refused.stderr
        assert state() == before
    finally:
        torch.set_num_threads(threads)


def test_an_unknown_command_a_warning_and_a_bug_answer_as_the_interpreter_would(tmp_path: Path, monkeypatch) -> None:
    """A warning is printed on the command's stderr (not recorded by pytest), a bug is its traceback and 1."""
    unknown = hypa_run(["trian"])
    assert unknown.returncode == 2 and unknown.stdout == "" and "unknown command 'trian'" in unknown.stderr
    from hypa.commands import cli

    def bug(argv):
        print("started")
        warnings.warn("a warning of the command's", UserWarning, stacklevel=1)
        raise RuntimeError("a bug")

    monkeypatch.setattr(cli, "main", bug)
    crashed = hypa_run(["train"], cwd=tmp_path)
    assert crashed.returncode == 1 and crashed.stdout == "started\n"
    assert "Traceback" in crashed.stderr and crashed.stderr.strip().endswith("RuntimeError: a bug")
    assert "UserWarning: a warning of the command's" in crashed.stderr


CHILDREN = [  # a user error of each command that nothing else in make test runs as a child, and its message
    (["simulate", "dataset=files", "data.dir={data}", "physics.hold=both"], "physics.hold=both is not one of zoh, foh"),
    (["testbench", "testbench.records.train_2.stochastic_duration_s=0"], "stochastic_duration_s must be > 0"),
    (["explain", "run={tmp}/nowhere"], "nowhere does not exist"),
    (["reproduce", "skip_training=true", "out={tmp}/results"], "no runs in"),
]


@pytest.mark.parametrize("arguments, message", [pytest.param(*case, id=case[0][0]) for case in CHILDREN])
def test_a_command_as_a_child_and_in_this_process_ends_alike(arguments: list[str], message: str,
                                                              tmp_path: Path) -> None:
    """The commands no other test runs as ``python -m hypa`` in ``make test``: a user error, both ways."""
    data = make_data_dir(tmp_path / "data", duration_s=6.0) if "data.dir={data}" in arguments else None
    args = [a.format(data=data, tmp=tmp_path) for a in arguments]
    env = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    env["HYPA_CACHE_DIR"] = str(tmp_path / "cache")
    results = [subprocess.run([sys.executable, "-m", "hypa", *args, f"hydra.run.dir={tmp_path / 'child'}"], cwd=ROOT,
                              env=env, capture_output=True, text=True, timeout=300, check=False),
               hypa_run([*args, f"hydra.run.dir={tmp_path / 'here'}"], env=env)]
    for result in results:
        assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr[-3000:]
        assert message in result.stderr.strip().splitlines()[-1], result.stderr[-3000:]
    last = [r.stderr.strip().splitlines()[-1].replace(str(tmp_path / "child"), str(tmp_path / "here"))
            for r in results]
    assert last[0] == last[1]
