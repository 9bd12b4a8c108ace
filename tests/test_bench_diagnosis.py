"""python -m hypa.speed diagnosis runs the engine's naming and reports it (no timing is asserted:
CI machines are noisy)."""

from pathlib import Path

from hypa.commands.speed.diagnosis import main


def test_benchmark_runs_on_short_records(tmp_path: Path, capsys) -> None:
    assert main(["--seconds", "20", "--cache-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "2 training records" in out and "1 validation records" in out
    assert "the engine's naming (hypa.diagnose model=vehicle_nominal)" in out
    assert "named causes (1):" in out and "  1. " in out  # the default bench hides effects: one is named
    assert "round 1 (" in out and "round 2" not in out and "total:" in out  # a quick check: the first round only
    assert "judged only on the default data" in out
    assert "analyze_residuals" not in out and "step 1" not in out


def test_speed_command_and_the_former_names():
    """``python -m hypa.speed`` picks its part; a misspelt part is one line and exit status 2; the
    former ``python -m hypa.bench`` still runs the physics part, saying it is deprecated."""
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=300, check=False)

    bad = run("hypa.speed", "physic")
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "physics, diagnosis" in bad.stderr
    helped = run("hypa.speed", "physics", "--help")
    assert helped.returncode == 0 and "--scheduled-only" in helped.stdout
    old = run("hypa.bench", "--help")
    assert old.returncode == 0 and "--scheduled-only" in old.stdout
    old = run("hypa.bench_diagnosis", "--help")
    assert old.returncode == 0 and "--seconds" in old.stdout
