"""The evaluation's result: metrics.json written and read back, metrics.csv and summary.md from the typed metrics."""

from __future__ import annotations

import json
from pathlib import Path

from hypa.evaluation.result import Evaluation, OutputMetrics, RunMetrics, SignalMetrics, SplitMetrics

OLD = {  # metrics.json as hypa evaluate wrote it before the typed result
    "model": "v1-lstm", "checkpoint": "checkpoints/best.ckpt",
    "splits": {
        "val": {"windowed": {"all": {"yaw_rate": {"mae": 0.01, "mse": 0.0004, "mape": 5.0, "r2": 0.98},
                                     "overall": {"mae": 0.01, "mse": 0.0004, "mape": 5.0, "r2": 0.98}}},
                "free_run": {"all": {"yaw_rate": {"mae": 0.02, "mse": 0.0009, "mape": 9.0, "r2": 0.95},
                                     "overall": {"mae": 0.02, "mse": 0.0009, "mape": 9.0, "r2": 0.95}},
                             "maneuvers": {"yaw_rate": {"mae": 0.03, "mse": 0.0016, "mape": 12.0, "r2": 0.9},
                                           "overall": {"mae": 0.03, "mse": 0.0016, "mape": 12.0, "r2": 0.9}}},
                "signals": {"rear_wheel_angle": {"corr": 0.97, "rmse": 0.001}}},
        "test/a": {"windowed": {"all": {"yaw_rate": {"mae": 0.01, "mse": 0.0004, "mape": 5.0, "r2": 0.98}}},
                   "free_run": {"all": {"yaw_rate": {"mae": 0.02, "mse": 0.0009, "mape": 9.0, "r2": 0.95}}}}},
    "units": {"yaw_rate": "rad/s", "rear_wheel_angle": "rad"},
}


def test_an_old_metrics_json_reads_back_typed_and_writes_the_same_json(tmp_path: Path) -> None:
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps(OLD, indent=2))
    metrics = RunMetrics.from_json(path)
    val = metrics.splits["val"]
    assert val.free_run["maneuvers"]["yaw_rate"] == OutputMetrics(0.03, 0.0016, 12.0, 0.9)
    assert val.free_run["all"]["yaw_rate"].rmse == 0.03
    assert val.signals == {"rear_wheel_angle": SignalMetrics(0.97, 0.001)}
    assert metrics.splits["test/a"].signals == {} and metrics.units["yaw_rate"] == "rad/s"
    metrics.to_json(tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text()) == OLD  # the schema is unchanged
    assert RunMetrics.from_json(tmp_path / "again.json") == metrics
    assert Evaluation.from_json(path).metrics == metrics


def test_csv_and_summary_come_from_the_typed_metrics(tmp_path: Path) -> None:
    metrics = RunMetrics.from_dict(OLD)
    metrics.write_csv(tmp_path / "metrics.csv")
    lines = (tmp_path / "metrics.csv").read_text().splitlines()
    assert lines[0] == "model,split,mode,segment,channel,metric,value (SI)"
    assert "v1-lstm,val,free_run,all,rear_wheel_angle,corr,0.97" in lines
    assert len(lines) == 1 + 4 * 6 + 2 + 4 * 2  # val: 6 (segment, output) pairs, its signal; test/a: 2
    evaluation = Evaluation(metrics, display_units={"yaw_rate": "deg/s"}, display_factors={"yaw_rate": 57.29577951})
    text = evaluation.markdown(["free_run.png"])
    assert "| free_run | maneuvers | yaw_rate | 1.72 deg/s | 2.29 deg/s | 12 | 0.9000 |" in text
    assert "correlation 0.970, RMSE 0.001 SI" in text and text.endswith("![free_run.png](free_run.png)\n")
    assert SplitMetrics().to_dict() == {"windowed": {}, "free_run": {}}


def test_reproduce_aggregates_the_typed_metrics_over_seeds() -> None:
    from hypa.commands.reproduce import aggregate

    second = json.loads(json.dumps(OLD))
    second["splits"]["val"]["free_run"]["all"]["overall"]["r2"] = 0.97
    second["splits"]["val"]["signals"]["rear_wheel_angle"]["corr"] = 0.99
    evaluations = [Evaluation(RunMetrics.from_dict(OLD)), Evaluation(RunMetrics.from_dict(second))]
    row = aggregate({"V1 LSTM": evaluations})[0]
    assert row["model"] == "V1 LSTM" and row["seeds"] == 2
    mean, std = row["free_run/all/r2"]
    assert mean == 0.96 and abs(std - 0.02 / 2**0.5) < 1e-12
    assert row["free_run/maneuvers/mape"] == (12.0, 0.0) and row["rear_wheel_angle/corr"][0] == 0.98
