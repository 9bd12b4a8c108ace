"""hypa timing diagnosis runs the engine's naming and reports it (no timing is asserted:
CI machines are noisy)."""

from pathlib import Path

from hypa.commands.timing.diagnosis import main


def test_benchmark_runs_on_short_records(tmp_path: Path, capsys) -> None:
    assert main(["--seconds", "20", "--cache-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "2 training records" in out and "1 validation records" in out
    assert "the engine's naming (hypa diagnose model=vehicle_nominal)" in out
    assert "named causes (1):" in out and "  1. " in out  # the default bench hides effects: one is named
    assert "round 1 (" in out and "round 2" not in out and "total:" in out  # a quick check: the first round only
    assert "judged only on the default data" in out
    assert "analyze_residuals" not in out and "step 1" not in out
