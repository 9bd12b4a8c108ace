"""hypa diagnose on records too short to trust: refused, or not named, and said why.

The data are the test bench with its effects off and its sensors on (white noise and the
yaw-rate and side-slip biases), written as files so that one training record can be given
alone (``dataset=files``), at ``data.window=20`` (21 samples, 0.66 s at 32 Hz):

- 1 s of training data hold one window without overlap: nothing with even one number can be
  fitted, so the command refuses in one line;
- 1.5 s in one record are 2 windows (a fit of one number is allowed) but one stretch (the
  scoring free runs last 10 of the vehicle's slowest decay times, at least 50 samples: 1.6 s
  here), too few to judge an offset's standard error (clustered by stretch, it needs 2): no
  offset is named on "N standard errors from zero" (before, one stretch gave a standard error
  of 0 and offsets 10^15 standard errors from zero).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
from pathlib import Path

import pytest

from hypa.paper.testbench import TestbenchConfig
from hypa.paper.testbench.config import RecordConfig
from hypa.paper.testbench.dataset import generate_dataset

from cli_helpers import hypa_run

EFFECTS_OFF = {"tires": {"enabled": False}, "relaxation": {"enabled": False},
               "load_transfer": {"enabled": False}, "rear_steering": {"enabled": False}}
SHORT = ["data.window=20", "plot=false", "diagnosis.workers=1"]


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    """``tiny``: 1 s of training data; ``short``: 1.5 s; each with 3 s of validation data."""
    root = tmp_path_factory.mktemp("short_records")
    out = {}
    for name, seconds in (("tiny", 1.0), ("short", 1.5)):
        # records replaced, not merged: the default train_2 would add a second (300 s) record
        config = dataclasses.replace(TestbenchConfig.from_dict(EFFECTS_OFF),
                                     records={"train_1": RecordConfig(seed=1, stochastic_duration_s=seconds),
                                              "val": RecordConfig(seed=3, stochastic_duration_s=3.0)})
        out[name] = generate_dataset(config, root / name)
    return out


def diagnose(folder: Path, run: Path, *overrides: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HYPA_CACHE_DIR": str(run.parent / "cache")}
    return hypa_run(["diagnose", f"hydra.run.dir={run}", "dataset=files", f"data.dir={folder}", *SHORT, *overrides],
                    env=env)


def test_records_too_short_for_any_fit_are_refused_in_one_line(folders, tmp_path: Path) -> None:
    result = diagnose(folders["tiny"], tmp_path / "run")
    assert result.returncode == 1, result.stdout[-2000:] + result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("hypa diagnose: error:")]
    assert len(errors) == 1 and errors[0] == result.stderr.strip().splitlines()[-1], result.stderr[-2000:]
    assert "1 s of training data in 1 record: 1 window of 17 samples" in errors[0]
    assert "too short to fit even one number" in errors[0] and "give at least 1.06 s" in errors[0]
    assert "step 1/4" not in result.stdout  # refused before any work is announced
    assert not (tmp_path / "run" / "diagnosis.json").exists()


def test_no_standard_error_from_fewer_stretches_than_offsets(folders, tmp_path: Path) -> None:
    """With the gain floor out of reach (min_gain 1), an offset can only be named as a small bias
    far from zero by its standard error; one training stretch cannot judge that."""
    result = diagnose(folders["short"], tmp_path / "run", "diagnosis.min_gain=1.0")
    assert result.returncode == 0, result.stderr[-3000:]
    report = (tmp_path / "run" / "diagnosis.md").read_text()
    assert "standard errors from zero" not in result.stdout and "standard errors from zero" not in report
    diagnosis = json.loads((tmp_path / "run" / "diagnosis.json").read_text())
    assert diagnosis["causes"] == [], diagnosis["causes"]
    offsets = [f for r in diagnosis["rounds"] for f in r if f["cause"].endswith("_offset")]
    assert offsets and all(f["z"] is None for f in offsets), [(f["text"], f["z"]) for f in offsets]
    assert diagnosis["data"]["train_stretches"] == 1 and diagnosis["data"]["train_windows"] == 2
    # the side-slip bias lowers the validation error most: the report says why it is not named
    why = "its standard error is not judged: 1 training stretch for 1 offset"
    line = next(line for line in result.stdout.splitlines() if line.startswith("too little data: output_offset on "
                                                                                 "side_slip"))
    assert why in line and "not named as a small bias" in line
    assert "## Too little data" in report and "output_offset on side_slip lowers the cross-validated error" in report
    assert why in report
    # the fit windows are the model's 3 decay times (16 samples), not data.window (20), as the folds
    # would hold too few of those: the rear steering's 4 numbers may be fitted (the data hold enough
    # windows for them), and are not named; with min_gain 1 the screen may leave it unfitted, for
    # what its first step promises, never for too little data
    assert diagnosis["data"]["scales"]["fit_window"] == 16
    first = {f["cause"] + ":" + f["target"]: f for f in diagnosis["rounds"][0]}
    rear = first["unmodeled_input:single_track"]
    assert rear["error"] is None or rear["error"].startswith("its first Gauss-Newton step promises"), rear["error"]
    assert rear["error"] is not None or rear["gain"] < 0.15
    refit = first["parameter_mismatch:cf"]["error"]
    assert refit is None or refit.startswith("its first Gauss-Newton step promises"), refit


def test_the_printed_summary_gives_the_reports_headline_figures(folders, tmp_path: Path) -> None:
    """The last line's error figures are diagnosis.md's headline, which is the mean over outputs of
    the table's 1 - R²."""
    result = diagnose(folders["short"], tmp_path / "run")
    assert result.returncode == 0, result.stderr[-3000:]
    printed = re.search(r"^named causes: .*; validation error (\S+ %) → (\S+ %) of the output variance "
                        r"\((\S+ %)\) with them applied;", result.stdout, re.MULTILINE)
    assert printed, result.stdout[-2000:]
    report = (tmp_path / "run" / "diagnosis.md").read_text()
    headline = [re.search(rf"^- {label}: \*\*(\S+ %)\*\*", report, re.MULTILINE)
                for label in ("nominal model", "with the named causes", "change with the named causes")]
    assert all(headline), report[:1500]
    assert printed.groups() == tuple(h.group(1) for h in headline)
    assert printed.group(3) != "+0.0 %"  # something was named: the figures differ
    diagnosis = json.loads((tmp_path / "run" / "diagnosis.json").read_text())
    for model, figure in zip(("nominal", "extended"), printed.groups()):
        table = [1 - m["r2"] for m in diagnosis["metrics"][model].values()]
        assert float(figure.split()[0]) == pytest.approx(100 * sum(table) / len(table), rel=5e-3)
    assert float(printed.group(3).split()[0]) == pytest.approx(100 * diagnosis["gain"]["all"]["overall"], abs=0.5)


def test_a_folds_shortfall_says_it_is_the_folds() -> None:
    """A fit refused in one cross-validation fold names the fold's data, not the whole training
    data's (EMPS: the fold fitted on its 5 s validation block, while 20 s train)."""
    from hypa.diagnosis.problem import Evidence

    fold = Evidence(seconds=4.97, records=1, windows=3, window_samples=1421, dt=1e-3, stretches=1, stretch_s=19.9,
                    fold=True)
    assert fold.fit_shortfall(2) is None
    assert fold.fit_shortfall(3) == ("3 numbers to fit from 3 training windows without overlap (1.42 s each) in a "
                                     "cross-validation fold fitted on 4.97 s of the data: needs 4, about 5.68 s")
    whole = Evidence(seconds=4.97, records=1, windows=3, window_samples=1421, dt=1e-3, stretches=1, stretch_s=19.9)
    assert "in 4.97 s of training data: needs 4" in whole.fit_shortfall(3)
