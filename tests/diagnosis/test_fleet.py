"""A fleet of logs: ``hypa diagnose -m data.dir=A,B,C`` diagnoses each log, then one summary.

End to end: three test-bench logs whose rear cornering stiffness wears from 180 to 140 kN/rad
(linear truth, white sensor noise, nothing else hidden; the nominal model ``vehicle_nominal``
believes 200 kN/rad), plus an empty folder as a bad log. The summary must name
``parameter_mismatch`` on cr first in every good log with the estimate falling monotonically,
show the spread of that drift, and show the bad log as failed with its one-line error. The
search may name more after it (on the 140 kN/rad log: ``tire_relaxation``, 0.066 m, for the last
0.03 % of the output variance), but nothing that explains more than 1 % of the nominal error.
Records of 20 + 20 s train and 15 s validation keep each job at ~5 s; cr is refit to within
0.3 % at that length, so 3 % on each log still separates steps of 20 kN/rad (11-14 %).

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

from hypa.commands import fleet as fleet_command
from hypa.core.errors import UserError
from hypa.diagnosis import fleet
from hypa.diagnosis.result import FindingRow
from hypa.diagnosis.trained import ExtensionTrainingError
from hypa.paper.testbench import TestbenchConfig
from hypa.paper.testbench.dataset import generate_dataset
from hypa.reporting.numbers import plain

from conftest import ROOT

WORN_CR = (180_000.0, 160_000.0, 140_000.0)  # [N/rad] the truth's rear axle, log by log
RECORDS = {"train_1": {"seed": 1, "stochastic_duration_s": 20.0, "maneuvers": []},
           "train_2": {"seed": 2, "stochastic_duration_s": 20.0, "maneuvers": []},
           "val": {"seed": 3, "stochastic_duration_s": 15.0, "maneuvers": []}}


def write_logs(root: Path) -> list[Path]:
    """One test-bench log folder per worn cr (what ``hypa testbench out=DIR`` writes)."""
    return [generate_dataset(TestbenchConfig.linear(noise=True).merged({"records": RECORDS, "vehicle": {"cr": cr}}),
                             root / f"log_{i}") for i, cr in enumerate(WORN_CR)]


def run(module: str, *args: str) -> subprocess.CompletedProcess:
    # one thread: the search's small tensors gain nothing from more, and on a loaded machine
    # OpenMP's spinning threads made a job 20-90x slower (same results)
    return subprocess.run([sys.executable, "-m", *module.split(), *args],
                          check=False, cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "HYDRA_FULL_ERROR": "0", "OMP_NUM_THREADS": "1"})


def explained(diagnosis: dict) -> dict[str, float]:
    """Each named cause's share of the nominal model's validation error, removed when it was named."""
    nominal = before = diagnosis["score"]["nominal"]
    out = {}
    for row in diagnosis["named"]:
        out[f"{row['cause']}: {row['target']}"], before = (before - row["score"]) / nominal, row["score"]
    return out


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path, list[Path]]:
    tmp = tmp_path_factory.mktemp("fleet")
    logs = write_logs(tmp)
    bad = tmp / "empty_log"
    bad.mkdir()
    folders = [logs[0], logs[1], bad, logs[2]]
    result = run("hypa diagnose", "-m", f"hydra.sweep.dir={tmp / 'sweep'}", "dataset=files",
                 "data.dir=" + ",".join(str(f) for f in folders), "plot=false")
    return result, tmp / "sweep", folders


def test_fleet_summary_counts_causes_and_shows_the_drift(sweep) -> None:
    result, folder, logs = sweep
    assert (folder / "fleet.json").is_file(), result.stderr[-3000:]
    summary = json.loads((folder / "fleet.json").read_text())
    assert (summary["logs"], summary["diagnosed"], summary["failed"]) == (4, 3, 1)
    assert [job["log"] for job in summary["jobs"]] == [str(f) for f in logs]
    assert summary["causes"]["parameter_mismatch"] == {"logs": 3, "share": 1.0}
    cr = summary["estimates"]["parameter_mismatch: cr"]
    assert cr["unit"] == "N/rad" and cr["logs"] == 3
    values = [v for v in cr["values"] if v is not None]
    assert cr["values"][2] is None  # the failed log
    assert values == pytest.approx(list(WORN_CR), rel=0.03)
    assert values[0] > values[1] > values[2]  # the wear, log by log
    assert (cr["min"], cr["max"]) == (min(values), max(values))
    assert cr["mean"] == pytest.approx(160_000, rel=0.03)
    assert cr["std"] == pytest.approx(20_000, rel=0.15)  # the drift's spread, far above the ~0.3 % estimate noise
    for job in summary["jobs"]:
        if job["status"] == "diagnosed":
            assert job["causes"][0] == "parameter_mismatch"
            assert job["mse_change"]["all"] < -0.9  # the refit cr removes nearly all of the error
            shares = explained(json.loads((folder / job["folder"] / "diagnosis.json").read_text()))
            assert next(iter(shares)) == "parameter_mismatch: cr" and shares["parameter_mismatch: cr"] > 0.95
            assert all(share < 0.01 for share in list(shares.values())[1:]), shares  # no more than noise after it


def test_fleet_markdown_has_a_row_per_log_and_the_spread(sweep) -> None:
    result, folder, logs = sweep
    report = (folder / "fleet.md").read_text()
    rows = [line for line in report.splitlines() if line.startswith("| ") and str(logs[0].parent) in line]
    assert len(rows) == 4
    header = next(line for line in report.splitlines() if line.startswith("| job | log |"))
    assert "parameter_mismatch: cr [N/rad]" in header
    estimate = json.loads((folder / "fleet.json").read_text())["jobs"][0]["estimates"]["parameter_mismatch: cr"]
    assert f"| {plain(estimate['value'])} |" in rows[0]  # rounded to 4 digits, no exponent
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
    assert f"hypa diagnose: error: {failed['error']}" in result.stderr
    assert "Traceback" not in result.stderr


def test_summary_command_rebuilds_the_same_summary(sweep, capsys) -> None:
    _, folder, _ = sweep
    written = (folder / "fleet.json").read_text(), (folder / "fleet.md").read_text()
    (folder / "fleet.json").unlink()
    (folder / "fleet.md").unlink()
    assert fleet_command.main(["summary", str(folder)]) == 0
    assert ((folder / "fleet.json").read_text(), (folder / "fleet.md").read_text()) == written
    assert "fleet of 4 logs (1 failed" in capsys.readouterr().out


def test_run_command_expands_a_glob_into_the_sweep(tmp_path: Path, capfd, monkeypatch) -> None:
    """The glob helper end to end, fast: a catalogue that does not exist makes every job fail
    before it reads its log, and the summary lists each matched folder with the error."""
    logs = [tmp_path / "logs" / name for name in ("run 1", "run,2", "run_10")]
    for log in logs:
        log.mkdir(parents=True)
    (tmp_path / "logs" / "notes.txt").write_text("not a log")
    missing = tmp_path / "missing.yaml"
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("HYDRA_FULL_ERROR", "0")
    code = fleet_command.main(["run", str(tmp_path / "logs" / "*"), f"diagnosis.catalogue=['{missing}']",
                       f"hydra.sweep.dir={tmp_path / 'sweep'}"])
    out, err = capfd.readouterr()
    assert code == 1, err[-3000:]
    assert out.startswith("python -m hypa diagnose -m dataset=files ")
    summary = json.loads((tmp_path / "sweep" / "fleet.json").read_text())
    assert [job["log"] for job in summary["jobs"]] == [str(log) for log in logs]
    assert {job["error"] for job in summary["jobs"]} == {f"catalogue {missing} does not exist"}
    assert err.count(f"hypa diagnose: error: catalogue {missing} does not exist") == 3
    assert "Traceback" not in err


def test_run_command_without_a_match_is_a_one_line_error(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        fleet_command.main(["run", str(tmp_path / "nothing*")])
    assert exit_.value.code == 1
    assert "hypa fleet: error: no log folder matches" in capsys.readouterr().err


@pytest.mark.parametrize("path", ["/logs/plain", "/logs/a b,c", "/logs/it's", "C:\\logs\\x", "/logs/q$r", "/t\\"])
def test_paths_survive_hydra_sweep_quoting(path: str) -> None:
    """What the sweeper hands each job (its override string, re-parsed) is the folder itself."""
    override = OverridesParser.create().parse_overrides([f"data.dir={fleet_command.hydra_quoted(path)},other"])[0]
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


def _named(cause: str, target: str, values: dict[str, float], units: dict[str, str]) -> dict:
    """A ``named`` row of diagnosis.json (:meth:`hypa.diagnosis.finding.Finding.to_dict`, the keys read here)."""
    return {"cause": cause, "target": target, "values": values, "units": units, "score": 0.01, "gain": 0.5,
            "text": f"{cause} on {target}"}


def _row(*args) -> FindingRow:
    """The same row as diagnosis.json reads back."""
    return FindingRow.from_dict(_named(*args))


def _diagnosis(named: list[dict], change: float, trained: float | None = None) -> dict:
    tested = _named("input_lag", "u", {"diagnosed_lag_u/tau_s": 0.3}, {"diagnosed_lag_u/tau_s": "s"})
    result = {"cause": named[0]["cause"] if named else "none", "estimate": named[0]["values"] if named else {},
              "causes": [n["cause"] for n in named], "named": named,
              "candidates": [{"cause": n["cause"], "target": n["target"], "score": n["gain"], "estimate": n["values"],
                              # tested, not named
                              "evidence": n["text"], "alternatives": []} for n in [*named, tested]],
              "rounds": [[*named, tested]],
              "gain": {"all": {"yaw_rate": change, "overall": change}}, "extended": {"config": {}, "signals": {}}}
    if trained is not None:
        result["extended"]["trained"] = {"model": "diagnosed", "gain": {"all": {"yaw_rate": trained,
                                                                                 "overall": trained}}}
    return result


DELAY = "diagnosed_delay_steering_wheel_angle/delay_s"
REAR = {"diagnosed_rear_steering/gain": "-", "diagnosed_rear_steering/tau_s": "s"}


def test_summary_builder_on_synthetic_jobs(tmp_path: Path) -> None:
    _job(tmp_path, "0", ["dataset=files", "data.dir=a"], _diagnosis(
        [_named("input_delay", "steering_wheel_angle", {DELAY: 0.05}, {DELAY: "s"}),
         _named("output_offset", "yaw_rate", {"yaw_rate": 0.01}, {"yaw_rate": "rad/s"}),
         _named("output_offset", "side_slip", {"side_slip": -0.002}, {"side_slip": "rad"})], -0.5))
    _job(tmp_path, "1", ["dataset=files", "data.dir=b"], _diagnosis([], 0.0))
    _job(tmp_path, "2", ["dataset=files", "data.dir=c"], error="c: no train* file")
    _job(tmp_path, "3", ["dataset=files", "data.dir=d"])  # killed before it wrote anything
    _job(tmp_path, "4", ["dataset=files", "data.dir=old"],  # a report of the old diagnosis: no "named" rows
         {"causes": ["sensor_offset"], "cause": "sensor_offset",
          "candidates": [{"cause": "sensor_offset", "estimate": {"channel": "yaw_rate", "offset": 0.01}}],
          "gain": {"all": {"overall": -0.3}, "high_ay": {"overall": -0.2}}, "extended": {}})
    _job(tmp_path, "10", ["dataset=files", "data.dir='e f'"], _diagnosis(
        [_named("input_delay", "steering_wheel_angle", {DELAY: 0.07}, {DELAY: "s"}),
         _named("unmodeled_input", "single_track", dict(zip(REAR, (0.12, 0.08))), REAR),
         _named("parameter_mismatch", "cr", {"cr": 150_000.0}, {"cr": "N/rad"})], -0.8, trained=-0.9))
    _job(tmp_path / "10", "extended_run", ["model=diagnosed"], job_name="train")  # a trained extension, no job
    result = fleet.write_summary(tmp_path)
    assert [log.label for log in result.logs] == ["a", "b", "c", "d", "old", "e f"]  # 10 after 4, train run left out
    assert [log.failed for log in result.logs] == [False, False, True, True, False, False]
    assert result.logs[2].error == "c: no train* file"
    assert "did not finish" in (result.logs[3].error or "")
    assert result.logs[4].causes == ("sensor_offset",) and result.logs[4].estimates == {}
    # a cause is counted once per log (two biased channels are one output_offset log)
    assert result.cause_counts() == {"input_delay": 2, "none": 1, "output_offset": 1, "parameter_mismatch": 1,
                                     "sensor_offset": 1, "unmodeled_input": 1}
    spreads = result.spreads()
    # in the order of the counts; a value that is its target by the target, a block's knobs by their name
    assert list(spreads) == ["input_delay: delay", "output_offset: side_slip", "output_offset: yaw_rate",
                             "parameter_mismatch: cr", "unmodeled_input: gain", "unmodeled_input: tau"]
    delay = spreads["input_delay: delay"]
    assert delay.unit == "ms" and delay.values == pytest.approx((50.0, None, None, None, None, 70.0))
    assert delay.stats() == pytest.approx({"logs": 2, "mean": 60.0, "std": 2 ** 0.5 * 10, "min": 50.0, "max": 70.0})
    units = {k: s.unit for k, s in spreads.items()}
    assert units == {"input_delay: delay": "ms", "output_offset: side_slip": "deg", "output_offset: yaw_rate": "deg/s",
                     "parameter_mismatch: cr": "N/rad", "unmodeled_input: gain": "-", "unmodeled_input: tau": "ms"}
    assert spreads["output_offset: yaw_rate"].values[0] == pytest.approx(0.5730, rel=1e-3)
    assert spreads["output_offset: side_slip"].values[0] == pytest.approx(-0.1146, rel=1e-3)
    assert spreads["output_offset: yaw_rate"].stats()["std"] is None  # one log: no spread
    assert [spreads[k].values[5] for k in list(spreads)[3:]] == pytest.approx([150_000.0, 0.12, 80.0])
    report = (tmp_path / "fleet.md").read_text()
    assert "| 1 | b | none | 0 % |" in report
    assert "| 4 | old | sensor_offset | -30 % |  |" in report
    assert ("| 10 | e f | input_delay, unmodeled_input, parameter_mismatch | -80 % | -90 % | 70.00 |  |  "
            "| 150000 | 0.1200 | 80.00 |") in report
    assert "| unmodeled_input: tau [ms] |" in report and "a_y" not in report
    assert "| none | 1 / 4 | 25 % |" in report
    saved = json.loads((tmp_path / "fleet.json").read_text())
    assert saved["causes"]["input_delay"] == {"logs": 2, "share": pytest.approx(2 / 4)}
    assert saved["jobs"][5]["mse_change"] == {"all": -0.8, "trained": -0.9}
    assert saved["jobs"][4]["mse_change"] == {"all": -0.3, "trained": None}
    assert saved["estimates"]["unmodeled_input: gain"]["values"] == [None] * 5 + [0.12]


def test_estimates_of_any_system_in_display_units() -> None:
    """Units from the row itself: a plant parameter in kg stays kg, an angle offset goes to deg;
    a cause named on two targets in one log keeps both, told apart by the target."""
    mass = fleet.estimates(_row("parameter_mismatch", "cart/mass", {"cart/mass": 2.5}, {"cart/mass": "kg"}))
    assert mass == {"parameter_mismatch: cart/mass": fleet.Estimate(2.5, "kg")}
    angle = fleet.estimates(_row("input_offset", "theta", {"theta": 0.01}, {"theta": "rad"}))
    assert angle["input_offset: theta"].unit == "deg"
    assert angle["input_offset: theta"].value == pytest.approx(0.5730, rel=1e-3)
    assert fleet.estimates(_row("discretization", "plant", {}, {})) == {}  # a cause without a quantity


def test_same_cause_on_two_targets_and_an_unreadable_report(tmp_path: Path) -> None:
    lag = {"diagnosed_lag_u1/tau_s": "s"}, {"diagnosed_lag_u2/tau_s": "s"}
    _job(tmp_path, "0", ["data.dir=a"], _diagnosis(
        [_named("input_lag", "u1", {"diagnosed_lag_u1/tau_s": 0.02}, lag[0]),
         _named("input_lag", "u2", {"diagnosed_lag_u2/tau_s": 0.03}, lag[1])], -0.5))
    _job(tmp_path, "1", ["data.dir=b"], {"named": []})  # no "causes": not a diagnosis.json
    logs = fleet.collect(tmp_path).logs
    assert logs[0].estimates == {"input_lag: tau": fleet.Estimate(pytest.approx(20.0), "ms"),
                                 "input_lag on u2: tau": fleet.Estimate(pytest.approx(30.0), "ms")}
    assert logs[1].failed
    assert "diagnosis.json: not a diagnosis.json of hypa diagnose (causes is missing)" in (logs[1].error or "")


def test_a_summary_that_cannot_be_written_ends_the_sweep_with_one_line(tmp_path: Path, capsys) -> None:
    """Hydra turns an error raised in a callback into a warning (and exit status 0): the callback says it itself."""
    from omegaconf import OmegaConf

    with pytest.raises(SystemExit) as exit_:
        fleet_command.FleetSummary().on_multirun_end(OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}}))
    assert exit_.value.code == 1
    err = capsys.readouterr().err
    assert f"hypa diagnose: error: fleet summary: {tmp_path} holds no hypa diagnose jobs" in err
    assert "Traceback" not in err


def test_summary_of_a_folder_without_jobs_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match=r"no hypa diagnose jobs"):
        fleet.collect(tmp_path)


@pytest.mark.parametrize(("value", "text"), [(179525.95, "179500"), (61.234, "61.23"), (0.051234, "0.05123"),
                                             (-0.4, "-0.4000"), (0.0, "0"), (None, "")])
def test_numbers_are_rounded_to_four_digits(value, text) -> None:
    assert plain(value) == text


def test_a_failed_extension_training_is_a_user_error() -> None:
    """hypa diagnose reports it as ``hypa diagnose: error: ...`` (the decorator's types), not a traceback."""
    assert issubclass(ExtensionTrainingError, UserError)
