"""Splits from pieces, named test sets, `select` cuts, past samples and scheduling signals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from hypa.data import ChannelSpec, DataError, HypaDataModule, Piece, SplitSpec

from data_helpers import write_table

RATE = 50.0  # [Hz] any rate works; no decimation unless asked
N = 1000  # samples per file
CHANNELS = (
    ChannelSpec("force", "input", "kN", display_unit="N"),
    ChannelSpec("position", "output", "mm", column="pos", display_unit="mm"),
    ChannelSpec("speed", "scheduling", "km/h", column="v"),
    ChannelSpec("reference", "evaluation", "mm", column="ref"),
)


def _speed(n: int) -> np.ndarray:
    """[km/h] about 36 (10 m/s) but for a dip to standstill over samples 400..459 and a short
    stretch above 5 m/s (samples 420..429) inside it."""
    v = 36.0 + 5.0 * np.sin(2 * np.pi * np.arange(n) / 200)
    v[400:460] = 0.0
    v[420:430] = 36.0
    return v


def _columns(n: int = N, seed: int = 0, time: bool = True) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {"time": np.arange(n) / RATE} if time else {}
    out.update(force=rng.normal(size=n), pos=np.cumsum(rng.normal(size=n)), v=_speed(n),
               ref=rng.normal(size=n))
    return out


@pytest.fixture
def folder(tmp_path) -> Path:
    write_table(tmp_path / "run.csv", _columns())
    write_table(tmp_path / "other.parquet", _columns(600, seed=1))
    return tmp_path


def _module(folder: Path, **kwargs) -> HypaDataModule:
    options = {"channels": CHANNELS, "sample_rate_hz": RATE, "rate_hz": None, "window": 20, "stride": 1,
               "eval_stride": 1, "batch_size": 8}
    options.update(kwargs)
    dm = HypaDataModule(folder, **options)
    dm.setup()
    return dm


SPLITS = SplitSpec.of(
    train=[Piece("run.csv", 0, 0.6)],
    val=[Piece("run.csv", 0.6, 0.8)],
    test={"tail": [Piece("run.csv", 0.8)], "other": [Piece("other.parquet", 100, 500)]},
)


def test_pieces_named_test_sets_and_si_values(folder):
    dm = _module(folder, splits=SPLITS)
    assert dm.dt == 1 / RATE
    assert [(r.name, len(r), r.start) for r in dm.records("train")] == [("run.csv[0:600]", 600, 0)]
    assert [(r.name, len(r)) for r in dm.records("val")] == [("run.csv[600:800]", 200)]
    sets = dm.test_sets()
    assert list(sets) == ["tail", "other"]
    assert [r.name for r in sets["tail"]] == ["run.csv[800:1000]"]
    assert [r.name for r in sets["other"]] == ["other.parquet[100:500]"]
    assert dm.records("test") == [*sets["tail"], *sets["other"]]
    val = dm.records("val")[0]
    np.testing.assert_allclose(val.time, np.arange(600, 800) / RATE)  # the file's time base
    raw = _columns()
    np.testing.assert_array_equal(val["force"], raw["force"][600:800] * 1e3)  # kN -> N
    np.testing.assert_array_equal(val["position"], raw["pos"][600:800] * 1e-3)  # mm -> m
    np.testing.assert_allclose(val["speed"], raw["v"][600:800] / 3.6)
    assert "reference" in val and "reference" not in dm.records("train")[0]
    assert dm.channels["position"].display_factor == pytest.approx(1e3)
    located = [(b["record"], b["start"]) for b in dm.test_dataloader()]
    records = torch.cat([r for r, _ in located]).tolist()
    assert sorted(set(records)) == [0, 1]  # windows of both test sets, indexed into records("test")


def test_unnamed_test_pieces_and_files_without_time_column(tmp_path):
    write_table(tmp_path / "a.csv", _columns(time=False))
    splits = SplitSpec.of([Piece("a.csv", 0, 500)], [Piece("a.csv", 500, 700)], [Piece("a.csv", 700)])
    dm = _module(tmp_path, splits=splits, time_column=None, sample_rate_hz=610.3515625)
    assert list(dm.test_sets()) == ["test"]
    np.testing.assert_allclose(dm.records("val")[0].time, np.arange(500, 700) / 610.3515625)
    assert dm.dt == pytest.approx(1 / 610.3515625)


def test_mixed_piece_bounds_are_checked_against_the_file(folder):
    splits = SplitSpec.of([Piece("run.csv", 0.9, 100)], [Piece("run.csv", 0.6, 0.8)])
    with pytest.raises(DataError, match=r"piece run.csv\[0.9:100\]: is empty \(samples 900:100 of 1000\)"):
        _module(folder, splits=splits)
    splits = SplitSpec.of([Piece("run.csv", 0, 2000)], [Piece("run.csv", 0.6, 0.8)])
    with pytest.raises(DataError, match=r"stop 2000 lies beyond the file's 1000 samples"):
        _module(folder, splits=splits)
    splits = SplitSpec.of([Piece("nope.csv")], [Piece("run.csv", 0.6, 0.8)])
    with pytest.raises(DataError, match=r"nope.csv: no such file.*has: other.parquet, run.csv"):
        _module(folder, splits=splits)


def test_select_cuts_records_and_no_window_crosses_a_cut(folder):
    splits = SplitSpec.of([Piece("run.csv", 0, 700)], [Piece("run.csv", 700)])
    dm = _module(folder, splits=splits, select=["speed > 5"], past=3)
    # samples 0..399 and 460..699 hold; the 10-sample stretch 420..429 is shorter than one window
    assert [r.name for r in dm.records("train")] == ["run.csv[0:400]", "run.csv[460:700]"]
    assert [r.name for r in dm.records("val")] == ["run.csv[700:1000]"]  # uncut: whole piece
    dataset = dm.dataset("train")
    assert len(dataset) == (400 - 23) + (240 - 23)
    for i in range(len(dataset)):
        item = dataset[i]
        assert item["u"].shape == (3 + 20 + 1, 1) and item["s"].shape == (24, 1)
        assert torch.all(item["s"] > 5.0)  # SI [m/s], standstill never inside a window
    record, start = dataset.index[-1]
    np.testing.assert_allclose(dataset[len(dataset) - 1]["s"][:, 0].numpy(),
                               dm.records("train")[record]["speed"][start:start + 24], rtol=1e-6)
    # the normalization covers inputs, outputs and scheduling signals, fitted on training only
    assert dm.normalization.names == ("force", "position", "speed")
    speed = np.concatenate([r["speed"] for r in dm.records("train")])
    assert dm.normalization.mean[2].item() == pytest.approx(speed.mean())


def test_select_with_a_unit_and_an_auxiliary_channel(folder):
    channels = (*CHANNELS[:2], ChannelSpec("v", "auxiliary", "km/h"))
    dm = _module(folder, channels=channels, splits=SPLITS, select=["v >= 18 km/h", "v < 100"])
    assert [r.name for r in dm.records("train")] == ["run.csv[0:400]", "run.csv[460:600]"]
    assert dm.scheduling_names == () and dm.dataset("train")[0]["s"].shape == (21, 0)


def test_selection_that_leaves_no_window_says_how_long_the_longest_stretch_was(folder):
    splits = SplitSpec.of([Piece("run.csv", 0, 700)], [Piece("run.csv", 410, 440)])
    with pytest.raises(DataError, match=r"select \[speed > 5\] leaves no window in the validation split: "
                                        r"its longest stretch holds 10 samples \(0.2 s at 50 Hz\), one "
                                        r"window needs past \+ window \+ 1 = 21"):
        _module(folder, splits=splits, select=["speed > 5"])
    with pytest.raises(DataError, match=r"uses the evaluation channel 'reference'"):
        _module(folder, splits=splits, select=["reference > 0"])
    with pytest.raises(DataError, match=r"'deg' is a unit of angle, but 'speed' is in 'm/s'"):
        _module(folder, splits=splits, select=["speed > 5 deg"])


def test_decimation_only_when_asked_and_per_piece(folder):
    splits = SplitSpec.of([Piece("run.csv", 0, 600)], [Piece("run.csv", 600)])
    dm = _module(folder, splits=splits, rate_hz=25.0, window=10)
    train, val = dm.records("train")[0], dm.records("val")[0]
    assert (len(train), len(val), dm.dt) == (300, 200, 1 / 25)
    np.testing.assert_allclose(val.time, np.arange(600, 1000, 2) / RATE)
    assert val.name == "run.csv[600:1000]"
    with pytest.raises(DataError, match="must be a positive integer"):
        HypaDataModule(folder, channels=CHANNELS, sample_rate_hz=RATE, rate_hz=30.0)
