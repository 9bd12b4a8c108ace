"""python -m hypa.bench_diagnosis runs and reports both steps (no timing is asserted: CI machines are noisy)."""

from pathlib import Path

from hypa.bench_diagnosis import main


def test_benchmark_runs_on_short_records(tmp_path: Path, capsys) -> None:
    assert main(["--seconds", "20", "--cache-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "2 training records" in out and "1 validation records" in out
    assert "step 1 analyze_residuals" in out and "step 2 name_causes" in out and "named:" in out
    assert "judged only on the default data" in out
    assert "the one engine (hypa.diagnose model=vehicle_nominal), naming:" in out
