"""Settings that size data are checked before anything is allocated; Ctrl-C and a received fleet folder
end in one line, never a traceback.

- the test bench's sizes (durations, the sample rate, ...) are checked for type and range, and what they
  ask for is compared with this machine's memory before a sample is generated: ``hypa.testbench`` and a
  run folder's stored configuration (``hypa evaluate`` regenerates its data from it) alike;
- Ctrl-C (SIGINT to the process group, as a terminal sends it) ends ``hypa diagnose``, its forked
  workers included, with ``hypa diagnose: interrupted`` and exit status 130;
- a fleet folder's YAML with a ``!!python`` tag runs no code and is that job's error in the summary.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from cli_helpers import hypa_run
from conftest import ROOT, SHORT_OVERRIDES, compose_config
from data_helpers import make_data_dir


def hypa(command: str, *args: str, cache: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    environment.update(HYPA_CACHE_DIR=str(cache), OMP_NUM_THREADS="1")
    return hypa_run([*command.split()[1:], *args], env=environment)


def assert_one_line(result: subprocess.CompletedProcess, command: str, *parts: str) -> str:
    """Exit status 1, no traceback, and the last line of stderr the command's error naming ``parts``."""
    assert result.returncode == 1, result.stderr[-3000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"{command}: error: "), result.stderr[-3000:]
    for part in parts:
        assert part in last, last
    return last


# through the command (a few seconds each: the command's start): override, what the one line says
BAD_SIZES = [
    ("testbench.records.val.stochastic_duration_s=1e7", ["1.02e+10 samples", "GiB",
                                                         "lower testbench.records.val.stochastic_duration_s"]),
    ("testbench.sample_rate_hz=-5", ["testbench.sample_rate_hz=-5 must be > 0"]),
    ("testbench.excitation.lane_change.duration_s=1e9", ["lower testbench.excitation.lane_change.duration_s"]),
    ("testbench.records.train_1.stochastic_duration_s=inf", ["stochastic_duration_s=inf is not a finite number"]),
]


@pytest.mark.parametrize("override, parts", [pytest.param(*case, id=case[0].split("testbench.", 1)[1])
                                             for case in BAD_SIZES])
def test_a_setting_that_sizes_the_data_is_refused_in_one_line_before_anything_is_made(
        override: str, parts: list[str], tmp_path: Path) -> None:
    started = time.perf_counter()
    result = hypa("hypa testbench", override, f"hydra.run.dir={tmp_path / 'run'}", cache=tmp_path / "cache")
    assert_one_line(result, "hypa testbench", *parts)
    assert time.perf_counter() - started < 60  # refused, not generated (a record takes minutes to simulate)
    assert not (tmp_path / "cache" / "testbench").exists() or not any((tmp_path / "cache" / "testbench").iterdir())


# the same check in this process (the command's part is the same for all): setting (below testbench.), message
BAD_VALUES = [
    ("sample_rate_hz=0", "testbench.sample_rate_hz=0 must be > 0"),
    ("sample_rate_hz=1e9", "the settings ask for 7.8e+11 samples in 3 record(s)"),
    ("records.val.stochastic_duration_s=nan", "testbench.records.val.stochastic_duration_s=nan is not a finite number"),
    ("records.val.stochastic_duration_s=0.01", ("testbench.records.val.stochastic_duration_s=0.01 is too short at "
                                                "testbench.sample_rate_hz=1024")),
    ("records.val.stochastic_duration_s=-3", "record 'val': stochastic_duration_s must be > 0 (it is -3)"),
    ("records.val.seed=-1", "testbench.records.val.seed=-1 must be >= 0"),
    ("records.val.break_frequency_hz=6", ("testbench.records.val.break_frequency_hz=6 must be below "
                                          "testbench.excitation.stochastic.cutoff_hz=5")),
    ("excitation.step_steer.hold_s=-2", "testbench.excitation.step_steer.hold_s=-2 must be >= 0"),
    ("excitation.sine_sweep.start_hz=0", "testbench.excitation.sine_sweep.start_hz=0 must be > 0"),
    ("excitation.sine_sweep.end_hz=0.2", "testbench.excitation.sine_sweep.end_hz=0.2 equals start_hz"),
    ("excitation.stochastic.cutoff_hz=-1", "testbench.excitation.stochastic.cutoff_hz=-1 must be > 0"),
    ("excitation.stochastic.crest_factor=0", "testbench.excitation.stochastic.crest_factor=0 must be > 0"),
    ("excitation.lane_change.change_s=0", "testbench.excitation.lane_change.change_s=0 must be > 0"),
    ("rear_steering.actuator_tau_s=0", "testbench.rear_steering.actuator_tau_s=0 must be > 0"),
    ("rear_steering.table_ratio=[0.1,inf]", ("testbench.rear_steering.table_ratio=[0.1, inf] holds a number that "
                                             "is not finite")),
    ("tires.mu=0", "testbench.tires.mu=0 must be > 0"),
    ("relaxation.rear_length_m=0", "testbench.relaxation.rear_length_m=0 must be > 0"),
    ("load_transfer.track_front_m=0", "testbench.load_transfer.track_front_m=0 must be > 0"),
    ("sensors.noise_scale=inf", "testbench.sensors.noise_scale=inf is not a finite number"),
]


@pytest.mark.parametrize("override, message", BAD_VALUES, ids=[case[0] for case in BAD_VALUES])
def test_every_value_the_simulation_sizes_or_divides_by_is_checked(override: str, message: str,
                                                                  tmp_path: Path) -> None:
    from omegaconf import OmegaConf

    from hypa.core.errors import UserError, settings
    from hypa.paper.testbench import TestbenchConfig, ensure_dataset

    with pytest.raises(UserError) as error, settings("testbench"):  # as the commands build the data
        ensure_dataset(TestbenchConfig.from_hydra(OmegaConf.from_dotlist([override])), tmp_path)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert not any(tmp_path.iterdir())  # nothing generated


def test_the_memory_check_compares_with_this_machine_and_allocates_nothing() -> None:
    from hypa.core.errors import UserError
    from hypa.core.machine import available_memory
    from hypa.paper.testbench import TestbenchConfig
    from hypa.paper.testbench.memory import check_fits, needed_bytes

    assert available_memory() > 2**26  # the machine says how much it has
    config = TestbenchConfig()  # the default data: 800k samples, well below half of any machine's memory
    check_fits(config)
    need = needed_bytes(config)
    check_fits(config, available=int(2 * need) + 1)
    with pytest.raises(UserError, match=r"more than half of the .* GiB of memory available here; lower "
                                        r"testbench.records.train_1.stochastic_duration_s or testbench.sample_rate_hz"):
        check_fits(config, available=int(2 * need) - 1)  # the same settings on a smaller machine


def test_a_received_run_config_asking_for_huge_records_is_refused_before_its_data_are_made(tmp_path: Path) -> None:
    """A run folder's config.yaml (read as hypa evaluate reads it) whose test-bench records ask for 1e7 s:
    building its data (what evaluation does when the run's data folder is not there) is refused in one
    line, without allocating and without a folder in the cache."""
    from omegaconf import OmegaConf

    from hypa.core.errors import UserError
    from hypa.data.from_config import data_dir_from_config
    from hypa.evaluation.runs import run_config

    cfg = compose_config("train", SHORT_OVERRIDES)
    cfg.testbench.records.val.stochastic_duration_s = 1.0e7  # as someone edited the file they sent
    run = tmp_path / "run"
    run.mkdir()
    OmegaConf.save(cfg, run / "config.yaml")
    os.environ["HYPA_CACHE_DIR"] = str(tmp_path / "cache")
    try:
        started = time.perf_counter()
        with pytest.raises(UserError, match=r"testbench: the settings ask for 1.02e\+10 samples .* lower "
                                            r"testbench.records.val.stochastic_duration_s"):
            data_dir_from_config(run_config(run))
        assert time.perf_counter() - started < 5
    finally:
        os.environ.pop("HYPA_CACHE_DIR")
    assert not (tmp_path / "cache").exists()


@pytest.mark.slow  # trains a tiny run first (about a minute on a loaded machine)
def test_evaluate_refuses_a_run_whose_stored_testbench_asks_for_huge_records(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    tiny = [f"testbench.records.{r}.stochastic_duration_s=5" for r in ("train_1", "train_2", "val")]
    trained = hypa("hypa train", "model=physical", "trainer.max_epochs=1", "trainer.limit_train_batches=2",
                   "trainer.limit_val_batches=1", "trainer.enable_progress_bar=false", "figures.enabled=false",
                   *tiny, "testbench.records.val.maneuvers=[]", f"hydra.run.dir={tmp_path / 'run'}", cache=cache,
                   timeout=600)
    assert trained.returncode == 0, trained.stderr[-3000:]
    from omegaconf import OmegaConf

    config = OmegaConf.load(tmp_path / "run" / "config.yaml")
    config.testbench.records.val.stochastic_duration_s = 1.0e7  # as someone edited the run folder they sent
    OmegaConf.save(config, tmp_path / "run" / "config.yaml")
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    record.pop("data_dir", None)  # as a received run folder: its data are made from its configuration
    (tmp_path / "run" / "run.json").write_text(json.dumps(record))
    started = time.perf_counter()
    result = hypa("hypa evaluate", f"run={tmp_path / 'run'}", f"hydra.run.dir={tmp_path / 'ev'}", cache=cache)
    assert_one_line(result, "hypa evaluate", "samples", "GiB", "stochastic_duration_s")
    assert time.perf_counter() - started < 120


@contextlib.contextmanager
def as_in_a_terminal() -> Iterator[None]:
    """The processes started inside get Ctrl-C (SIGINT) as a command in a terminal does. A suite
    started in the background by a script (``make test &``) ignores SIGINT, and a started process
    inherits that: the command under test would never see the Ctrl-C these tests send."""
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)  # not ignored: exec resets it
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)


CTRL_C_IN_A_ROUND = """
import os, signal, sys, time
from hypa.diagnosis import race
from hypa.commands.cli import main

parent, advance = os.getpid(), race._Runner.advance

def advance_after_ctrl_c(self, share, val):
    if os.getpid() != parent and not os.environ.get("CTRL_C_SENT"):  # a forked worker's first task
        os.environ["CTRL_C_SENT"] = "1"
        os.killpg(0, signal.SIGINT)  # Ctrl-C: to the whole process group, while the round's workers fit
        time.sleep(0.5)
    return advance(self, share, val)

race._Runner.advance = advance_after_ctrl_c
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_ends_diagnose_and_its_workers_with_one_line_and_status_130(tmp_path: Path) -> None:
    # The Ctrl-C comes from a worker at its first task, so it always arrives while a round fits
    # (sent from the test a second after a line, it met a search that had already ended on a fast
    # machine: the interpreter was finishing, and ended by the signal with status -2)
    data = make_data_dir(tmp_path / "data", duration_s=30.0)
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    environment.update(OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    with as_in_a_terminal():
        process = subprocess.Popen([sys.executable, "-c", CTRL_C_IN_A_ROUND, "diagnose", "dataset=files",
                                    f"data.dir={data}", "plot=false", "diagnosis.workers=2",
                                    f"hydra.run.dir={tmp_path / 'run'}"],
                                   cwd=ROOT, env=environment, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   start_new_session=True)  # its own process group: the signal reaches the workers too
    try:
        stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 130, stdout[-2000:] + stderr[-3000:]
    assert "round 1:" not in stdout, stdout[-2000:]  # the first round did not end
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr[-3000:]
    assert stderr.strip().splitlines() == ["hypa diagnose: interrupted"], stderr[-3000:]
    time.sleep(0.5)
    with pytest.raises(ProcessLookupError):  # the workers ended with it: nothing left in its process group
        os.killpg(process.pid, 0)


IDLE_WORKERS = """
import os, signal, time
from hypa.conf import CONF
from hypa.diagnosis.workers import Workers
from hypa.core.errors import user_errors

@user_errors("hypa.test")
def main():
    with Workers([], 2, None) as workers:
        time.sleep(1.0)  # the workers wait for a task
        os.killpg(0, signal.SIGINT)  # Ctrl-C: to the whole process group
        time.sleep(10)
    raise AssertionError("not reached")

main()
"""


def test_ctrl_c_while_the_diagnosis_workers_wait_is_one_line_not_one_traceback_per_worker() -> None:
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    with as_in_a_terminal():
        result = subprocess.run([sys.executable, "-c", IDLE_WORKERS], cwd=ROOT, env=environment, capture_output=True,
                                text=True, timeout=60, check=False, start_new_session=True)
    assert result.returncode == 130, result.stderr[-3000:]
    assert result.stderr.strip().splitlines() == ["hypa.test: interrupted"], result.stderr[-3000:]


INTERRUPTED = """
import sys
from hypa.core.errors import user_errors

def lightning():  # what Lightning does when Ctrl-C stops a fit, a validation or a prediction
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt:
        sys.exit(1)

def plain():
    raise KeyboardInterrupt

user_errors("hypa.test")({"plain": plain, "lightning": lightning}[sys.argv[1]])()
"""


@pytest.mark.parametrize("how", ["plain", "lightning"])
def test_ctrl_c_anywhere_in_a_command_is_one_line_and_status_130(how: str) -> None:
    """KeyboardInterrupt, or Lightning's exit status 1 after one: ``<command>: interrupted``, 130; the
    traceback only where HYPA_FULL_ERROR=1 asks for it."""
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    result = subprocess.run([sys.executable, "-c", INTERRUPTED, how], cwd=ROOT, env=environment, capture_output=True,
                            text=True, timeout=60, check=False)
    assert result.returncode == 130, result.stderr[-3000:]
    assert result.stderr.strip().splitlines() == ["hypa.test: interrupted"], result.stderr[-3000:]
    full = subprocess.run([sys.executable, "-c", INTERRUPTED, how], cwd=ROOT,
                          env={**environment, "HYPA_FULL_ERROR": "1"}, capture_output=True, text=True, timeout=60,
                          check=False)
    if how == "plain":
        assert "Traceback" in full.stderr and "KeyboardInterrupt" in full.stderr, full.stderr[-3000:]
    else:  # Lightning's own ending, as it is
        assert full.returncode == 1 and "interrupted" not in full.stderr, full.stderr[-3000:]


def _job(root: Path, name: str, hydra: str, overrides: str) -> Path:
    folder = root / name
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "hydra.yaml").write_text(hydra)
    (folder / ".hydra" / "overrides.yaml").write_text(overrides)
    return folder


def test_a_python_tag_in_a_fleet_folder_runs_nothing_and_is_that_jobs_error(tmp_path: Path) -> None:
    marker = tmp_path / "MARKER"
    attack = f'!!python/object/apply:os.system ["touch {marker}"]\n'
    sweep = tmp_path / "sweep"
    ok = _job(sweep, "0", "hydra: {job: {name: diagnose}}\n", "- data.dir=a\n")
    (ok / "error.json").write_text(json.dumps({"error": "a: no train* file", "user_error": True}))
    _job(sweep, "1", "hydra: {job: {name: diagnose}}\n", attack)  # the overrides
    _job(sweep, "2", attack, "- data.dir=c\n")  # the job's Hydra configuration
    bad_error = _job(sweep, "3", "hydra: {job: {name: diagnose}}\n", "- data.dir=d\n")
    (bad_error / "error.json").write_text("{not json")
    (_job(sweep, "4", "hydra: {job: {name: diagnose}}\n", "- data.dir=e\n") / "diagnosis.json").write_text(
        json.dumps({"causes": "input_delay"}))
    result = hypa("hypa fleet", "summary", str(sweep), cache=tmp_path / "cache")
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    assert result.returncode == 0, result.stderr[-3000:]
    assert not marker.exists()
    jobs = json.loads((sweep / "fleet.json").read_text())["jobs"]
    assert [job["status"] for job in jobs] == ["failed"] * 5
    errors = [job["error"] for job in jobs]
    assert errors[0] == "a: no train* file"
    assert "overrides.yaml: not a readable Hydra overrides file" in errors[1] and "python/object" in errors[1]
    assert "hydra.yaml: not a readable Hydra configuration file" in errors[2]
    assert "error.json: not an error.json of hypa diagnose" in errors[3]
    assert "diagnosis.json: not a diagnosis.json of hypa diagnose (causes is the string" in errors[4]
    assert all("\n" not in e for e in errors)


def test_a_huge_error_json_is_not_read(tmp_path: Path) -> None:
    from hypa.core.trust import MAX_TEXT_BYTES
    from hypa.diagnosis import fleet

    folder = _job(tmp_path, "0", "hydra: {job: {name: diagnose}}\n", "- data.dir=a\n")
    with (folder / "error.json").open("wb") as file:
        file.truncate(MAX_TEXT_BYTES + 1)  # sparse: nothing written, nothing read
    assert "larger than any error.json hypa writes" in (fleet.read_log(folder).error or "")
    with (folder / "diagnosis.json").open("wb") as file:
        file.truncate(MAX_TEXT_BYTES + 1)
    assert "larger than any diagnosis.json hypa writes" in (fleet.read_log(folder).error or "")
