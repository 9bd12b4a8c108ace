"""The benchmark's table and JSON from synthetic scores: means and spreads over seeds, units, published figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hypa.evaluation.benchmark import Score, benchmark, summarize
from hypa.evaluation.benchmark_result import Benchmark, read_benchmarks

UNITS = {"position": ("mm", 1000.0)}
PUBLISHED = {"test": {"position": {"linear": 5.53}}}


def scores() -> list[Score]:
    return [Score("physical", "test", "position", 0.004, 0.99, 100, seed=0),
            Score("physical", "test", "position", 0.006, 0.98, 100, seed=1),
            Score("hybrid", "test", "position", 0.003, 0.995, 100, seed=0)]


def test_seeds_are_summarized_by_mean_and_sample_std() -> None:
    s = summarize(scores())
    physical = s[("physical", "test", "position")]
    assert physical.rms == pytest.approx(0.005) and physical.rms_std == pytest.approx(0.002 / 2**0.5)
    assert physical.r2 == pytest.approx(0.985) and physical.seeds == {0: (0.004, 0.99), 1: (0.006, 0.98)}
    assert s[("hybrid", "test", "position")].rms_std == 0.0  # one seed: no spread


def test_the_table_shows_mean_and_spread_in_display_units() -> None:
    table = benchmark("emps", scores(), {"physical": 80.0, "hybrid": 300.0}, PUBLISHED, UNITS).markdown()
    row = next(line for line in table.splitlines() if line.startswith("| test | position |"))
    assert "| 5 ± 1.4 mm | 3 mm | 0.9850 ± 0.0071 | 0.9950 |" in row and "| 5.53 mm |" in row
    tiny = [Score("m", "t", "position", 0.004, 0.99001, 100, 0), Score("m", "t", "position", 0.004, 0.99002, 100, 1)]
    assert "0.9900 ± 7e-06" in benchmark("emps", tiny, {}, {}, UNITS).markdown()  # not "± 0.0000"
    assert "mean ± standard deviation over seeds physical [0, 1], hybrid [0]" in table
    assert "| training time |  | 1.3 min | 5 min |  |  |  |" in table  # beside the errors, mean per seed


def test_one_seed_keeps_the_plain_table() -> None:
    table = benchmark("emps", scores()[2:], {"hybrid": 300.0}, PUBLISHED, UNITS).markdown()
    assert "| 3 mm |" in table and "±" not in table


def test_the_json_holds_means_in_si_units_and_every_seed(tmp_path: Path) -> None:
    path = tmp_path / "benchmark.json"
    benchmark("emps", scores(), {"physical": 80.0}, PUBLISHED, UNITS).to_json(path)
    content = json.loads(path.read_text())["emps"]
    entry = content["models"]["physical"]["test_sets"]["test"]["position"]
    assert entry["rms"] == pytest.approx(0.005) and entry["samples"] == 100
    assert entry["seeds"] == {"0": {"rms": 0.004, "r2": 0.99}, "1": {"rms": 0.006, "r2": 0.98}}
    assert content["published"] == PUBLISHED and content["display_units"]["position"]["unit"] == "mm"


def test_the_json_reads_back_and_keeps_other_data_sets(tmp_path: Path) -> None:
    path = tmp_path / "benchmark.json"
    emps = benchmark("emps", scores(), {"physical": 80.0, "hybrid": 300.0}, PUBLISHED, UNITS)
    other = benchmark("silverbox", scores()[2:], {"hybrid": 10.0}, {}, {})
    emps.to_json(path)
    other.to_json(path)
    assert read_benchmarks(path) == {"emps": emps, "silverbox": other}
    assert Benchmark.from_json(path, "emps") == emps
    assert Benchmark.from_json(path, "emps").markdown() == emps.markdown()
    with pytest.raises(ValueError, match="2 data sets"):
        Benchmark.from_json(path)


def test_a_file_written_before_the_typed_result_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "benchmark.json"
    path.write_text(json.dumps({"emps": {
        "models": {"physical": {"training_time_s": 80.0, "test_sets": {"test": {"position": {
            "rms": 0.005, "rms_std": 0.0014, "r2": 0.985, "r2_std": 0.007, "samples": 100,
            "seeds": {"0": {"rms": 0.004, "r2": 0.99}, "1": {"rms": 0.006, "r2": 0.98}}}}}}},
        "published": PUBLISHED, "display_units": {"position": {"unit": "mm", "factor": 1000.0}}}}))
    result = Benchmark.from_json(path)
    row = result.rows[("physical", "test", "position")]
    assert row.seeds == {0: (0.004, 0.99), 1: (0.006, 0.98)} and result.units == UNITS
    assert "| test | position | 5 ± 1.4 mm | 0.9850 ± 0.0070 | 5.53 mm |" in result.markdown()


def test_a_hybrid_that_kept_its_identified_physics_is_said_under_the_table(tmp_path: Path) -> None:
    """hypa benchmark passes the seeds whose run kept the model before its networks' first epoch."""
    result = benchmark("emps", scores(), {"physical": 80.0, "hybrid": 300.0}, PUBLISHED, UNITS,
                       kept_physics={"hybrid": [1, 0], "physical": []})
    table = result.markdown()
    assert "hybrid: no epoch of its networks beat its identified physics on validation (seed 0, 1)" in table
    assert "physical: no epoch" not in table
    path = tmp_path / "benchmark.json"
    result.to_json(path)
    models = json.loads(path.read_text())["emps"]["models"]
    assert models["hybrid"]["kept_physics_seeds"] == [0, 1] and models["physical"]["kept_physics_seeds"] == []
    assert Benchmark.from_json(path, "emps") == result
    assert "no epoch" not in benchmark("emps", scores(), {}, PUBLISHED, UNITS).markdown()


def test_the_diagnosed_row_is_set_against_the_identified_physics_it_extends(tmp_path: Path) -> None:
    """``extends``: under the table, each test set's RMS of the diagnosed row beside the nominal it
    extends (identified), "worse" in bold where it lost; the link reads back from the JSON."""
    rows = [Score("nominal", "test", "position", 0.006, 0.98, 100, 0),
            Score("diagnosed", "test", "position", 0.004, 0.99, 100, 0),
            Score("nominal", "other", "position", 0.002, 0.99, 100, 0),
            Score("diagnosed", "other", "position", 0.003, 0.98, 100, 0)]
    result = benchmark("emps", rows, {"nominal": 5.0, "diagnosed": 9.0}, {}, UNITS, extends={"diagnosed": "nominal"})
    line = next(x for x in result.markdown().splitlines() if x.startswith("diagnosed against nominal"))
    assert "test position 6 → 4 mm (-33 %)" in line and "other position 2 → 3 mm (+50 %) **worse**" in line
    assert line.count("**worse**") == 1
    path = tmp_path / "benchmark.json"
    result.to_json(path)
    assert json.loads(path.read_text())["emps"]["models"]["diagnosed"]["extends"] == "nominal"
    assert read_benchmarks(path)["emps"] == result
    # a row it names that did not run: no comparison, no link
    alone = benchmark("emps", rows[1:2], {"diagnosed": 9.0}, {}, UNITS, extends={"diagnosed": "nominal"})
    assert alone.extends == {} and "against" not in alone.markdown()
