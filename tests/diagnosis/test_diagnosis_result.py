"""The diagnosis's result: diagnosis.json read into typed fields and written back unchanged, its
Markdown report from those fields alone, and an older report read back."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pytest

from hypa.diagnosis.result import Diagnosis, FindingRow, FreeRunMetrics, NetworkExplanation

DEG = 180 / math.pi
UNITS = {"yaw_rate": ("deg/s", DEG), "rear_wheel_angle": ("deg", DEG)}


def _row(cause: str, target: str, values: dict, units: dict, score: float, gain: float, text: str, **more) -> dict:
    """A row as :meth:`hypa.diagnosis.finding.Finding.to_dict` writes it."""
    row = {"cause": cause, "target": target, "values": values, "units": units, "score": score, "gain": gain,
           "seconds": 1.5, "error": None, "alternatives": [], "refined": {}, "steps": None, "z": None, "small": False,
           "too_short": "", "generic": None, "text": text, "folds": [values, values], "screened": False}
    return {**row, **more}


DELAY = _row("input_delay", "u", {"delay_u/delay_s": 0.06}, {"delay_u/delay_s": "s"}, 0.02, 0.8,
             "input_delay on u: delay 60 ms", generic=0.3, alternatives=["input_lag on u: tau 70 ms"])
OFFSET = _row("output_offset", "yaw_rate", {"yaw_rate": 0.0015}, {"yaw_rate": "rad/s"}, 0.019, 0.05,
              "output_offset on yaw_rate: 0.0859 deg/s", z=7.7, small=True)
DROPPED = _row("output_offset", "side_slip", {"side_slip": 1e-4}, {"side_slip": "rad"}, 0.019, 0.01,
               "output_offset on side_slip: 0.00573 deg, dropped: fitted together with the other offsets it is 1.2 "
               "standard errors from zero (they carry what it explained)")
FAILED = _row("input_lag", "u", {}, {}, math.inf, -math.inf, "input_lag on u: not fitted (diverged)",
              error="diverged", steps=[40, 100])
METRICS = {"yaw_rate": {"rmse": 0.01, "mse": 1e-4, "r2": 0.9}}
STRUCTURE = {"output": "yaw_rate", "unit": "rad/s", "share": 0.0015, "amplitude_edges": [0.0, 0.1, 0.2, 0.3, 0.4],
             "amplitude_rmse": [0.003, 0.004, 0.004, 0.006], "amplitude_ratio": 1.7,
             "bands_hz": [[0.0, 0.5], [0.5, 16.0]], "band_share": [0.001, 0.2], "worst_band_hz": [0.5, 16.0],
             "correlated": {"u": {"rho": -0.4, "lag_s": 0.28, "bound": 0.06}}, "unexplained": True,
             "where": ["correlated with u: ρ = -0.40 at 281 ms"]}
SCALES = {"dt": 0.03125, "slowest_s": 0.16, "fastest_s": 0.12, "period_s": 1.2, "integrating": False, "stretch": 392,
          "fit_window": 100, "max_lag": 16, "envelope": 117, "segment": 64, "band_edges_hz": [0.0, 0.5, 16.0],
          "stretch_s": 12.25}
WRITTEN = {  # every key of diagnosis.json (docs/diagnosis.md), in the order hypa diagnose writes them
    "cause": "input_delay", "estimate": DELAY["values"],
    "system": {"model": "plant", "inputs": ["u"], "outputs": ["yaw_rate"], "scheduling": []},
    "causes": ["input_delay", "output_offset"], "named": [DELAY, OFFSET], "dropped": [DROPPED],
    "candidates": [{"cause": "input_delay", "target": "u", "score": 0.8, "estimate": DELAY["values"],
                    "evidence": DELAY["text"], "alternatives": DELAY["alternatives"]}],
    "rounds": [[DELAY, FAILED], [OFFSET, DROPPED]],
    "score": {"nominal": 0.1, "extended": 0.019},
    "error": {"nominal": 0.1, "extended": 0.02, "trained": 0.015, "change": -0.8},
    "metrics": {"nominal": {"yaw_rate": {"rmse": 0.03, "mse": 9e-4, "r2": 0.9}},
                "extended": {"yaw_rate": {"rmse": 0.01, "mse": 1e-4, "r2": 0.98}},
                "trained": {"yaw_rate": {"rmse": 0.008, "mse": 6.4e-5, "r2": 0.985}}},
    "gain": {"all": {"yaw_rate": -0.89, "overall": -0.8}},
    "too_short": [], "generic": [{"score": 0.04, "gain": 0.5, "numbers": 6}], "standin": "",
    "coverage": [{"channel": "yaw_rate", "role": "output", "train": [-0.26, 0.27], "val": [-0.27, 0.29],
                  "covered": 1.0, "amplitude": 1.02, "short": False}],
    "not_covered": [], "unexplained": [STRUCTURE], "structure": {"yaw_rate": STRUCTURE},
    "extended": {"config": {"diagnosed": "/out/conf/model/diagnosed.yaml"},
                 "train_command": {"diagnosed": "hypa train model=diagnosed"},
                 "signals": {"rear_wheel_angle": {"correlation": 0.81, "rmse": 0.0016, "measured_rms": 0.0025}},
                 "trained": {"model": "diagnosed", "run": "/out/extended_run",
                             "metrics": {"yaw_rate": {"rmse": 0.008, "mse": 6.4e-5, "r2": 0.985}},
                             "gain": {"all": {"yaw_rate": -0.93, "overall": -0.85}},
                             "explained": [{"block": "correction", "signal": "yaw_rate_correction",
                                            "description": "yaw_rate_correction = 0.1 · u", "form": "linear",
                                            "r2_val": 0.9, "report": "/out/extended_run/explanation/explanation.md"}]}},
    "data": {"dt": 0.03125, "train_records": 2, "val_records": 1, "folds": 2, "blocks": 8, "train_s": 80.0,
             "train_windows": 24, "train_stretches": 8, "stretch_s": 12.25, "scales": SCALES},
    "seconds": 17.0, "figures": {"time_series": ["time_series_val.png"], "signals": []},
}


def test_diagnosis_json_reads_into_typed_fields_and_writes_back_unchanged(tmp_path: Path) -> None:
    (tmp_path / "diagnosis.json").write_text(json.dumps(WRITTEN, indent=2))
    diagnosis = Diagnosis.from_json(tmp_path / "diagnosis.json")
    assert diagnosis.named[0] == FindingRow.from_dict(DELAY) and diagnosis.named[1].small
    assert diagnosis.metrics["extended"]["yaw_rate"] == FreeRunMetrics(0.01, 1e-4, 0.98)
    assert diagnosis.error.change == -0.8 and diagnosis.change == -0.8 and diagnosis.score.nominal == 0.1
    assert diagnosis.extended.trained.change == -0.85
    assert diagnosis.extended.trained.explained[0] == NetworkExplanation(
        "correction", "yaw_rate_correction", "yaw_rate_correction = 0.1 · u", "linear", 0.9,
        "/out/extended_run/explanation/explanation.md")
    assert diagnosis.structure["yaw_rate"].worst_band_hz == (0.5, 16.0) and diagnosis.unexplained[0].unexplained
    assert diagnosis.data.time_scales().stretch_s == 12.25
    diagnosis.to_json(tmp_path / "again.json")
    text = (tmp_path / "again.json").read_text()
    again = json.loads(text)
    # the documented schema, key for key; the diverged fit's score and gain (not finite) as null, not Infinity
    assert "Infinity" not in text and "NaN" not in text
    assert again["rounds"][0][1]["score"] is None and again["rounds"][0][1]["gain"] is None
    written = copy.deepcopy(WRITTEN)
    written["rounds"][0][1].update(score=None, gain=None)
    assert again == written and list(again) == list(WRITTEN)
    assert json.loads(json.dumps(Diagnosis.from_json(tmp_path / "again.json").to_dict())) == written


def test_the_markdown_report_comes_from_the_fields_alone() -> None:
    report = Diagnosis.from_dict(WRITTEN).markdown(UNITS, min_gain=0.15)
    assert report.startswith("# Diagnosis of `plant`\n\nInputs u; outputs yaw_rate. 2 training and 1 validation "
                             "record(s) at 32 Hz.")
    assert "- nominal model: **10 %** (yaw_rate 10 %)" in report
    assert "- the trained extension: **1.5 %** (yaw_rate 1.5 %)" in report
    assert "- change with the named causes: **-80 %**" in report
    assert ("1. **input_delay** on `u`: delay 60 ms. Cross-validated error -80 % against the model before it; 80 % "
            "of the nominal error. A generic linear filter from the inputs in its place: -30 %.") in report
    assert "   The data cannot tell it from: input_lag on u: tau 70 ms." in report
    assert "Small (below the 15 % floor), but 8 standard errors from zero." in report
    assert ("- Named, then dropped: **output_offset** on `side_slip`; dropped: fitted together with the other "
            "offsets it is 1.2 standard errors from zero (they carry what it explained).") in report
    assert "| yaw_rate | 1.72 deg/s | 0.573 deg/s | 0.458 deg/s | 0.9000 | 0.9800 | 0.9850 |" in report
    assert "validation error -85 % against the nominal model" in report
    assert "- `correction`, yaw_rate_correction: yaw_rate_correction = 0.1 · u" in report
    assert "| rear_wheel_angle | 0.810 | 0.0917 deg | 0.143 deg |" in report
    assert "- `yaw_rate`: 0.15 % of its variance left; **unexplained structure**: correlated with u" in report
    assert ("| input_lag | u | not fitted (diverged) (stopped after 40 of at most 100 steps: gain at least "
            "this) | did not converge |") in report
    assert report.endswith("![time_series_val.png](time_series_val.png)\n")
    assert Diagnosis.from_dict(WRITTEN).headline() == {"nominal": "10 %", "extended": "2 %", "trained": "1.5 %",
                                                       "change": "-80 %"}


def test_a_report_without_trained_extension_or_named_rows_reads_back(tmp_path: Path) -> None:
    untrained = copy.deepcopy(WRITTEN)
    del untrained["extended"]["trained"], untrained["error"]["trained"], untrained["metrics"]["trained"]
    diagnosis = Diagnosis.from_dict(untrained)
    assert diagnosis.extended.trained is None and diagnosis.error.trained is None
    assert json.loads(json.dumps(diagnosis.to_dict())) == untrained and "trained" not in diagnosis.headline()
    old = {"causes": ["sensor_offset"], "cause": "sensor_offset",  # an older hypa's report
           "candidates": [{"cause": "sensor_offset", "estimate": {"channel": "yaw_rate", "offset": 0.01}}],
           "gain": {"all": {"overall": -0.3}, "high_ay": {"overall": -0.2}}, "extended": {}}
    diagnosis = Diagnosis.from_dict(old)
    assert diagnosis.named == [] and diagnosis.change == -0.3 and diagnosis.candidates[0].estimate["offset"] == 0.01
    with pytest.raises(KeyError, match="causes"):
        Diagnosis.from_dict({"named": []})


def test_a_number_that_is_not_finite_is_written_as_null_and_reads_back(tmp_path: Path) -> None:
    """A fit that diverged leaves NaN and infinite numbers: diagnosis.json holds null there (JSON has no
    NaN), a float field reads it back as NaN, and the report says "did not converge", never "-8.5e+19 %"."""
    diverged = copy.deepcopy(WRITTEN)
    diverged["metrics"]["extended"]["yaw_rate"] = {"rmse": math.nan, "mse": math.inf, "r2": -8.5e17}
    diverged["error"]["change"] = 8.5e17
    diagnosis = Diagnosis.from_dict(diverged)
    diagnosis.to_json(tmp_path / "diagnosis.json")
    text = (tmp_path / "diagnosis.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text)["metrics"]["extended"]["yaw_rate"] == {"rmse": None, "mse": None, "r2": -8.5e17}
    back = Diagnosis.from_json(tmp_path / "diagnosis.json")
    assert math.isnan(back.metrics["extended"]["yaw_rate"].rmse) and back.error.change == 8.5e17
    assert back.headline()["change"].startswith("did not converge")
    report = back.markdown(UNITS)
    assert "e+17 %" not in report and "e+19" not in report
    assert "- change with the named causes: **did not converge (error more than 100×)**" in report
