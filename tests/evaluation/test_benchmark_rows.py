"""hypa benchmark keeps what it has: a row that fails is a row of the table ("failed: <why>") and the
others are written after each one; the table carries each model's training time and says where it
stopped at a cap; diagnose=PATH reuses a diagnosis folder, read as data."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from hypa.commands.benchmark import (
    Rows,
    diagnosis_folder,
    identified_start,
    model_file_override,
    reused_diagnosis,
    trust_of,
)
from hypa.core.errors import UserError
from hypa.evaluation.benchmark import Score, benchmark
from hypa.evaluation.benchmark_result import Benchmark

from conftest import ROOT

UNITS = {"y": ("mV", 1000.0)}
WHY = "block 'plant': unknown physics system 'nothing'"


def scores(model: str, seed: int = 0) -> list[Score]:
    return [Score(model, "multisine", "y", 0.004, 0.99, 100, seed), Score(model, "arrow", "y", 0.01, 0.95, 100, seed)]


def test_a_failed_model_is_a_row_of_the_table_with_its_reason(tmp_path: Path) -> None:
    result = benchmark("silverbox", [*scores("physical"), *scores("hybrid")],
                       {"physical": 75.0, "lstm": None, "hybrid": 1234.0}, {}, UNITS,
                       capped={"hybrid": ["training ran trainer.max_epochs=2 epochs without early stopping"]},
                       failed={"lstm": WHY})
    assert result.models == ["physical", "lstm", "hybrid"]  # the order they were benchmarked in
    table = result.markdown()
    assert "| multisine | y | 4 mV | failed: block 'plant': unknown physics system 'nothing' | 4 mV |" in table
    assert "| training time |  | 1.2 min | – | 21 min (capped) |" in table  # beside the errors, rounded with its unit
    assert "(capped) hybrid: training ran trainer.max_epochs=2 epochs without early stopping" in table
    path = tmp_path / "benchmark.json"
    result.to_json(path)
    models = json.loads(path.read_text())["silverbox"]["models"]
    assert models["lstm"] == {"training_time_s": None, "kept_physics_seeds": [], "capped": [], "failed": WHY,
                              "extends": None, "test_sets": {}}
    assert models["hybrid"]["capped"] == ["training ran trainer.max_epochs=2 epochs without early stopping"]
    assert Benchmark.from_json(path) == result and Benchmark.from_json(path).markdown() == table


def test_every_model_failed_is_still_a_table() -> None:
    table = benchmark("silverbox", [], {"physical": None}, {}, UNITS, failed={"physical": "a | b"}).markdown()
    assert "| – | – | failed: a \\| b | – |" in table


def test_a_score_that_is_not_finite_is_null_in_the_json(tmp_path: Path) -> None:
    result = benchmark("silverbox", [Score("m", "t", "y", math.inf, -math.inf, 10)], {"m": math.nan}, {}, UNITS)
    path = tmp_path / "benchmark.json"
    result.to_json(path)
    text = path.read_text()
    assert "Infinity" not in text and "NaN" not in text
    back = Benchmark.from_json(path)
    assert math.isnan(back.rows[("m", "t", "y")].rms) and back.training_time_s["m"] is None


def test_the_rows_done_are_written_after_each_and_a_failed_seed_keeps_the_others(tmp_path: Path) -> None:
    rows = Rows("silverbox", ["physical", "lstm"], [0, 1], {}, UNITS, tmp_path)
    rows.add("physical", 0, scores("physical"), 10.0, kept=False, caps=[])
    rows.write()
    first = json.loads((tmp_path / "benchmark.json").read_text())["silverbox"]["models"]
    assert list(first) == ["physical"] and "| multisine | y | 4 mV |" in (tmp_path / "benchmark.md").read_text()
    rows.fail("physical", 1, "interrupted")
    rows.add("lstm", 0, scores("lstm"), 20.0, kept=False, caps=["identification stopped at x"])
    rows.add("lstm", 1, scores("lstm", 1), 40.0, kept=False, caps=[])
    table, data = rows.write()
    models = json.loads(data.read_text())["silverbox"]["models"]
    assert models["physical"]["failed"] == "seed 1 failed: interrupted" and models["physical"]["test_sets"]
    assert models["lstm"]["training_time_s"] == 30.0  # the mean per seed
    assert models["lstm"]["capped"] == ["seed 0: identification stopped at x"]
    text = table.read_text()
    assert "physical: seed 1 failed: interrupted" in text and "| training time |  | 10 s | 30 s (capped) |" in text
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]  # replaced whole, nothing left over


MODEL = """name: diagnosed
blocks:
  oscillator:
    kind: physics
    system: mass_spring_damper
    inputs: [u]
    outputs: [y]
    initial_state: estimate
    trainable: [mass, stiffness, damping, offset_force]
outputs: [y]
parameters: {mass: 5.1e-6, stiffness: 0.98, damping: 2.2e-4, offset_force: -5.4e-3}
"""
DATA = SimpleNamespace(input_names=["u"], output_names=["y"])


def diagnosis(folder: Path, inputs: list[str] = ("u",), outputs: list[str] = ("y",)) -> Path:
    """A diagnosis folder as hypa diagnose leaves it (the parts the benchmark reads)."""
    (folder / "conf" / "model").mkdir(parents=True)
    (folder / "diagnosis.json").write_text(json.dumps({"causes": ["hardening"], "system": {
        "model": "silverbox_physical", "inputs": list(inputs), "outputs": list(outputs), "scheduling": []}}))
    for name in ("diagnosed", "diagnosed_hybrid"):
        (folder / "conf" / "model" / f"{name}.yaml").write_text(MODEL.replace("name: diagnosed", f"name: {name}"))
    return folder


def test_a_diagnosis_folder_is_reused(tmp_path: Path, capsys) -> None:
    folder = diagnosis(tmp_path / "received")
    files = reused_diagnosis(folder, ["diagnosed"], DATA, ())
    assert files == {"diagnosed": folder / "conf" / "model" / "diagnosed.yaml"}
    assert "diagnosis of silverbox_physical reused from" in capsys.readouterr().out
    assert model_file_override(files["diagnosed"]) == f"model_file={files['diagnosed']}"
    assert diagnosis_folder(str(folder), {"silverbox_physical"}) == folder
    assert diagnosis_folder("silverbox_physical", {"silverbox_physical"}) is None  # a model name: diagnosed anew
    with pytest.raises(UserError, match="no such folder"):
        diagnosis_folder(str(tmp_path / "missing"), set())
    assert trust_of(["seed=1", "trust=[mypkg, other.mod:Cls]"]) == ("mypkg", "other.mod:Cls")


def test_a_diagnosis_of_other_outputs_is_refused_in_one_line(tmp_path: Path) -> None:
    folder = diagnosis(tmp_path / "received", outputs=["yaw_rate"])
    with pytest.raises(UserError, match=r"its diagnosis is of outputs yaw_rate, this benchmark's data have y") as error:
        reused_diagnosis(folder, ["diagnosed"], DATA, ())
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("link", ["diagnosis.json", "conf", "conf/model/diagnosed.yaml"])
def test_a_symbolic_link_in_a_diagnosis_folder_is_not_followed(tmp_path: Path, link: str) -> None:
    outside = diagnosis(tmp_path / "elsewhere")
    folder = diagnosis(tmp_path / "received")
    target = folder / link
    if target.is_dir():
        import shutil

        shutil.rmtree(target)
    else:
        target.unlink()
    os.symlink(outside / link, target)
    with pytest.raises(UserError, match="symbolic link"):
        reused_diagnosis(folder, ["diagnosed"], DATA, ())


def test_a_crafted_model_file_is_refused_before_any_row_trains(tmp_path: Path) -> None:
    folder = diagnosis(tmp_path / "received")
    (folder / "conf" / "model" / "diagnosed.yaml").write_text(MODEL.replace("mass_spring_damper", "evil.mod:Plant"))
    with pytest.raises(UserError, match=r"evil.mod:Plant.*trust="):
        reused_diagnosis(folder, ["diagnosed"], DATA, ())
    (folder / "conf" / "model" / "diagnosed_hybrid.yaml").unlink()
    with pytest.raises(UserError, match=r"no conf/model/diagnosed_hybrid\.yaml"):
        reused_diagnosis(folder, ["diagnosed_hybrid"], DATA, ())


@pytest.mark.slow  # about 30 s: two rows through hypa train (make test-slow)
@pytest.mark.shared_data
def test_a_row_that_fails_leaves_the_others_in_the_table(tmp_path: Path) -> None:
    """The first model cannot be built: its row says why, the next one trains and is scored, both files
    hold them, and the command ends with exit status 1 naming the failed row."""
    conf = tmp_path / "conf" / "model"
    conf.mkdir(parents=True)
    (conf / "broken.yaml").write_text(MODEL.replace("mass_spring_damper", "no_such_system").replace(
        "name: diagnosed", "name: broken"))
    result = subprocess.run(
        [sys.executable, "-m", "hypa", "benchmark", "--config-dir", str(tmp_path / "conf"), "dataset=racecar",
         "models=[broken,physical]", "train_overrides=['identification.max_evaluations=3']",
         f"hydra.run.dir={tmp_path / 'run'}"], cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 1, result.stderr[-3000:]
    assert result.stderr.strip().splitlines()[-1].startswith("hypa benchmark: error: 1 of 2 models failed (broken)")
    assert "[1/2] broken failed: " in result.stdout and "[2/2] physical: trained in " in result.stdout
    table = (tmp_path / "run" / "benchmark.md").read_text()
    assert "failed: block 'oscillator': unknown physics system 'no_such_system'" in table
    assert "(capped) physical: identification stopped at identification.max_evaluations (not converged)" in table
    models = json.loads((tmp_path / "run" / "benchmark.json").read_text())["racecar"]["models"]
    assert models["physical"]["test_sets"]["test"]["yaw_rate"]["r2"] > 0.5 and models["broken"]["failed"]


def test_a_hybrids_later_seeds_start_from_its_first_seeds_identified_physics(tmp_path: Path) -> None:
    """``identified_start``: identification.start at the first seed's run, and the hold the data
    chose there (so no second hold is fitted); nothing for a run that identified nothing, and a
    hold the model fixed is not passed on."""
    info = {"identification": {"parameters": {"k": {"value": 1.0}}}, "hold": {"chosen": "foh", "by": "identification"}}
    assert identified_start(tmp_path, info) == [f"identification.start={tmp_path}", "physics.hold=foh"]
    assert identified_start(tmp_path, {**info, "hold": {"chosen": "zoh", "by": "model"}}) == [
        f"identification.start={tmp_path}"]
    assert identified_start(tmp_path, {**info, "hold": {"chosen": "os.system", "by": "identification"}}) == [
        f"identification.start={tmp_path}"]
    assert identified_start(tmp_path, {"best_val_loss": 0.1}) == []
    assert identified_start(tmp_path, {"identification": {"parameters": {}}}) == []
    spaced = tmp_path / "a run"
    assert identified_start(spaced, info)[0] == f"identification.start='{spaced}'"
