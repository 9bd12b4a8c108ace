"""``hypa timing fmu``: an FMU block's loops timed, C against Python; skipped in one line without an FMU."""

import shutil

import pytest

from hypa.commands.timing.fmu import main

pytest.importorskip("fmpy")


def test_without_an_fmu_the_part_is_skipped_in_one_line(capsys) -> None:
    assert main([]) == 0
    assert capsys.readouterr().out.startswith("fmu: skipped: give an FMU to time")


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_it_prints_each_interface_s_time_per_sample_and_the_ratio(tmp_path, capsys) -> None:
    from fmu_fixtures import build_fmu

    path = build_fmu("single_track", tmp_path)
    assert main(["--fmu", str(path), "--samples", "200", "--repeat", "1", "--reference", "single_track"]) == 0
    out = capsys.readouterr().out
    for row in ("model exchange: free run", "model exchange: sensitivities", "co simulation: free run",
                "an identification step (8 parameters), per record",
                "hypa's single-track class: free run, 32 record(s) at once"):
        assert row in out, out
    assert "goal: model exchange, Python loop / C loop" in out
