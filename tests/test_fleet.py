"""A fleet of logs: ``python -m hypa.diagnose -m data.dir=A,B,C`` diagnoses each log, then one summary.

End to end: three test-bench logs whose rear cornering stiffness wears from 180 to 140 kN/rad
(linear truth, white sensor noise, nothing else hidden; the nominal physics believes 200 kN/rad),
plus an empty folder as a bad log. The summary must name ``parameter_mismatch`` on cr in every
good log with the estimate falling monotonically, show the spread of that drift, and show the bad
log as failed with its one-line error. Records of 20 + 20 s train and 15 s validation keep each
job at ~2 s; cr is refit to ~1 % at that length (test_diagnosis_naming allows 5 % at 60 s), so
3 % on each log still separates steps of 20 kN/rad (11-14 %).

The summary builder on its own: synthetic diagnosis.json / error.json job folders.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hydra.core.override_parser.overrides_parser import OverridesParser

from hypa.diagnosis import fleet
from hypa.diagnosis.trained import ExtensionTrainingError
from hypa.errors import UserError
from hypa.testbench import TestbenchConfig
from hypa.testbench.dataset import generate_dataset

ROOT = Path(__file__).resolve().parents[1]
WORN_CR = (180_000.0, 160_000.0, 140_000.0)  # [N/rad] the truth's rear axle, log by log
RECORDS = {"train_1": {"seed": 1, "stochastic_duration_s": 20.0, "maneuvers": []},
           "train_2": {"seed": 2, "stochastic_duration_s": 20.0, "maneuvers": []},
           "val": {"seed": 3, "stochastic_duration_s": 15.0, "maneuvers": []}}


def write_logs(root: Path) -> list[Path]:
    """One test-bench log folder per worn cr (what ``python -m hypa.testbench out=DIR`` writes)."""
    return [generate_dataset(TestbenchConfig.linear(noise=True).merged({"records": RECORDS, "vehicle": {"cr": cr}}),
                             root / f"log_{i}") for i, cr in enumerate(WORN_CR)]


def run(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "HYDRA_FULL_ERROR": "0"})


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path, list[Path]]:
    tmp = tmp_path_factory.mktemp("fleet")
    logs = write_logs(tmp)
    bad = tmp / "empty_log"
    bad.mkdir()
    folders = [logs[0], logs[1], bad, logs[2]]
    result = run("hypa.diagnose", "-m", f"hydra.sweep.dir={tmp / 'sweep'}", "dataset=files",
                 "data.dir=" + ",".join(str(f) for f in folders), "plot=false")
    return result, tmp / "sweep", folders


def test_fleet_summary_counts_causes_and_shows_the_drift(sweep) -> None:
    result, folder, logs = sweep
    assert (folder / "fleet.json").is_file(), result.stderr[-3000:]
    summary = json.loads((folder / "fleet.json").read_text())
    assert (summary["logs"], summary["diagnosed"], summary["failed"]) == (4, 3, 1)
    assert [job["log"] for job in summary["jobs"]] == [str(f) for f in logs]
    assert summary["causes"] == {"parameter_mismatch": {"logs": 3, "share": 1.0}}
    cr = summary["estimates"]["parameter_mismatch: cr"]
    assert cr["unit"] == "N/rad" and cr["logs"] == 3
    values = [v for v in cr["values"] if v is not None]
    assert cr["values"][2] is None  # the failed log
    assert values == pytest.approx(list(WORN_CR), rel=0.03)
    assert values[0] > values[1] > values[2]  # the wear, log by log
    assert (cr["min"], cr["max"]) == (min(values), max(values))
    assert cr["mean"] == pytest.approx(160_000, rel=0.03)
    assert cr["std"] == pytest.approx(20_000, rel=0.15)  # the drift's spread, far above the ~1 % estimate noise
    for job in summary["jobs"]:
        if job["status"] == "diagnosed":
            assert job["causes"] == ["parameter_mismatch"]
            assert job["mse_change"]["all"] < -0.9  # the refit cr removes nearly all of the error


def test_fleet_markdown_has_a_row_per_log_and_the_spread(sweep) -> None:
    result, folder, logs = sweep
    report = (folder / "fleet.md").read_text()
    rows = [line for line in report.splitlines() if line.startswith("| ") and str(logs[0].parent) in line]
    assert len(rows) == 4
    header = next(line for line in report.splitlines() if line.startswith("| job | log |"))
    assert "parameter_mismatch: cr [N/rad]" in header
    estimate = json.loads((folder / "fleet.json").read_text())["jobs"][0]["estimates"]["parameter_mismatch: cr"]
    assert f"| {fleet.number(estimate['value'])} |" in rows[0]  # rounded to 4 digits, no exponent
    assert "| parameter_mismatch | 3 / 3 | 100 % |" in report
    assert "| parameter_mismatch: cr | N/rad | 3 |" in report
    assert "fleet.md" in result.stdout and "| parameter_mismatch | 3 / 3 |" in result.stdout


def test_a_bad_log_fails_alone_with_its_one_line_error(sweep) -> None:
    result, folder, logs = sweep
    assert result.returncode == 1  # like make -k: every log ran, the summary is written, one failed
    failed = json.loads((folder / "fleet.json").read_text())["jobs"][2]
    assert failed["status"] == "failed" and failed["log"] == str(logs[2])
    assert str(logs[2]) in failed["error"] and "train" in failed["error"]
    assert f"**failed**: {failed['error']}" in (folder / "fleet.md").read_text()
    assert f"hypa.diagnose: error: {failed['error']}" in result.stderr
    assert "Traceback" not in result.stderr


def test_summary_command_rebuilds_the_same_summary(sweep, capsys) -> None:
    _, folder, _ = sweep
    written = (folder / "fleet.json").read_text(), (folder / "fleet.md").read_text()
    (folder / "fleet.json").unlink()
    (folder / "fleet.md").unlink()
    assert fleet.main(["summary", str(folder)]) == 0
    assert ((folder / "fleet.json").read_text(), (folder / "fleet.md").read_text()) == written
    assert "fleet of 4 logs (1 failed" in capsys.readouterr().out


def test_run_command_expands_a_glob_into_the_sweep(tmp_path: Path, capfd, monkeypatch) -> None:
    """The glob helper end to end, fast: nominal parameters that cannot be right make every job
    fail before it reads its log, and the summary lists each matched folder with the error."""
    logs = [tmp_path / "logs" / name for name in ("run 1", "run,2", "run_10")]
    for log in logs:
        log.mkdir(parents=True)
    (tmp_path / "logs" / "notes.txt").write_text("not a log")
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("HYDRA_FULL_ERROR", "0")
    code = fleet.main(["run", str(tmp_path / "logs" / "*"), "vehicle.cf=-1", f"hydra.sweep.dir={tmp_path / 'sweep'}"])
    out, err = capfd.readouterr()
    assert code == 1, err[-3000:]
    assert out.startswith("python -m hypa.diagnose -m dataset=files ")
    summary = json.loads((tmp_path / "sweep" / "fleet.json").read_text())
    assert [job["log"] for job in summary["jobs"]] == [str(log) for log in logs]
    assert {job["error"] for job in summary["jobs"]} == {"vehicle parameter 'cf' must be positive, got -1.0"}
    assert err.count("hypa.diagnose: error: vehicle parameter 'cf'") == 3


def test_run_command_without_a_match_is_a_one_line_error(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        fleet.main(["run", str(tmp_path / "nothing*")])
    assert exit_.value.code == 1
    assert "hypa.diagnosis.fleet: error: no log folder matches" in capsys.readouterr().err


@pytest.mark.parametrize("path", ["/logs/plain", "/logs/a b,c", "/logs/it's", "C:\\logs\\x", "/logs/q$r", "/t\\"])
def test_paths_survive_hydra_sweep_quoting(path: str) -> None:
    """What the sweeper hands each job (its override string, re-parsed) is the folder itself."""
    override = OverridesParser.create().parse_overrides([f"data.dir={fleet.hydra_quoted(path)},other"])[0]
    jobs = list(override.sweep_string_iterator())
    assert OverridesParser.create().parse_override(f"data.dir={jobs[0]}").value() == path


def _job(root: Path, name: str, overrides: list[str], diagnosis: dict | None = None, error: str | None = None,
         job_name: str = "diagnose") -> Path:
    folder = root / name
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "hydra.yaml").write_text(yaml.safe_dump({"hydra": {"job": {"name": job_name}}}))
    (folder / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    if diagnosis is not None:
        (folder / "diagnosis.json").write_text(json.dumps(diagnosis))
    if error is not None:
        (folder / "error.json").write_text(json.dumps({"error": error, "user_error": True}))
    return folder


def _diagnosis(named: list[tuple[str, dict]], change: float, trained: float | None = None) -> dict:
    result = {"causes": [c for c, _ in named],
              "candidates": [{"cause": c, "estimate": e} for c, e in named]
              + [{"cause": "input_delay", "estimate": {"delay_s": 0.3}}],  # tested, not named
              "gain": {"all": {"overall": change}, "high_ay": {}}, "extended": {}}
    if trained is not None:
        result["extended"]["trained"] = {"gain": {"all": {"overall": trained}}}
    return result


def test_summary_builder_on_synthetic_jobs(tmp_path: Path) -> None:
    offset = ("sensor_offset", {"channel": "yaw_rate", "offset": 0.01})
    _job(tmp_path, "0", ["dataset=files", "data.dir=a"],
         _diagnosis([("input_delay", {"delay_s": 0.05}), offset, ("sensor_offset", {"channel": "side_slip",
                                                                                   "offset": -0.002})], -0.5))
    _job(tmp_path, "1", ["dataset=files", "data.dir=b"], _diagnosis([], 0.0))
    _job(tmp_path, "2", ["dataset=files", "data.dir=c"], error="c: no train* file")
    _job(tmp_path, "3", ["dataset=files", "data.dir=d"])  # killed before it wrote anything
    _job(tmp_path, "10", ["dataset=files", "data.dir='e f'"],
         _diagnosis([("input_delay", {"delay_s": 0.07}), ("discretization", {"hold": "foh"})], -0.8, trained=-0.9))
    _job(tmp_path / "10", "extended_run", ["model=diagnosed"], job_name="train")  # a trained extension, no job
    result = fleet.write_summary(tmp_path)
    assert [log.label for log in result.logs] == ["a", "b", "c", "d", "e f"]  # 10 after 3, train run left out
    assert [log.failed for log in result.logs] == [False, False, True, True, False]
    assert result.logs[2].error == "c: no train* file"
    assert "did not finish" in (result.logs[3].error or "")
    # a cause is counted once per log (two biased channels are one sensor_offset log)
    assert result.cause_counts() == {"input_delay": 2, "discretization": 1, "none": 1, "sensor_offset": 1}
    spreads = result.spreads()
    # in the order of the counts; the hold (text) is no quantity
    assert list(spreads) == ["input_delay: delay", "sensor_offset: side_slip", "sensor_offset: yaw_rate"]
    delay = spreads["input_delay: delay"]
    assert delay.unit == "ms" and delay.values == pytest.approx((50.0, None, None, None, 70.0))
    assert delay.stats() == pytest.approx({"logs": 2, "mean": 60.0, "std": 2 ** 0.5 * 10, "min": 50.0, "max": 70.0})
    assert spreads["sensor_offset: yaw_rate"].unit == "deg/s"
    assert spreads["sensor_offset: yaw_rate"].values[0] == pytest.approx(0.5730, rel=1e-3)
    assert spreads["sensor_offset: yaw_rate"].stats()["std"] is None  # one log: no spread
    report = (tmp_path / "fleet.md").read_text()
    assert "| 1 | b | none | +0.0 % |" in report
    assert "| 10 | e f | input_delay, discretization | -80.0 % |  | -90.0 % | 70.00 |" in report
    assert "| none | 1 / 3 | 33 % |" in report
    saved = json.loads((tmp_path / "fleet.json").read_text())
    assert saved["causes"]["input_delay"] == {"logs": 2, "share": pytest.approx(2 / 3)}
    assert saved["jobs"][4]["mse_change"] == {"all": -0.8, "high_ay": None, "trained": -0.9}


def test_summary_of_a_folder_without_jobs_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no hypa.diagnose jobs"):
        fleet.collect(tmp_path)


@pytest.mark.parametrize(("value", "text"), [(179525.95, "179500"), (61.234, "61.23"), (0.051234, "0.05123"),
                                             (-0.4, "-0.4000"), (0.0, "0"), (None, "")])
def test_numbers_are_rounded_to_four_digits(value, text) -> None:
    assert fleet.number(value) == text


def test_a_failed_extension_training_is_a_user_error() -> None:
    """hypa.diagnose reports it as ``hypa.diagnose: error: ...`` (the decorator's types), not a traceback."""
    assert issubclass(ExtensionTrainingError, UserError)
