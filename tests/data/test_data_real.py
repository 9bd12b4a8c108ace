"""The bundled real data sets load through the shipped conf/dataset/*.yaml, as they are on disk.

Reads ../shared/data (without it these fail, unless HYPA_SKIP_SHARED_DATA=1: tests/conftest.py); expected
counts follow from the data's README and the standard splits (the nonlinear_benchmarks package for Silverbox).
"""

from __future__ import annotations

import numpy as np
import pytest

from hypa.data import HypaDataModule, datamodule_from_config, read_columns
from hypa.data.from_config import data_dir_from_config

from conftest import ROOT, SHARED_DATA, compose_config

pytestmark = pytest.mark.shared_data


def _load(name: str, monkeypatch, *overrides: str) -> HypaDataModule:
    monkeypatch.chdir(ROOT)  # the YAMLs name ../shared/data relative to where hypa runs
    monkeypatch.delenv("HYPA_DATA", raising=False)
    cfg = compose_config("train", [f"dataset={name}", *overrides])
    dm = datamodule_from_config(cfg.data, data_dir_from_config(cfg))
    dm.setup()
    return dm


def _windows_stay_inside_their_records(dm: HypaDataModule, split: str) -> None:
    dataset, records = dm.dataset(split), dm.records(split)
    span = dm.past + dm.window + 1
    assert all(start + span <= len(records[r]) for r, start in dataset.index)


def test_silverbox_standard_split(monkeypatch):
    dm = _load("silverbox", monkeypatch)
    assert dm.dt == pytest.approx(2**14 / 1e7) and dm.past == 49
    assert (dm.input_names, dm.output_names, dm.scheduling_names) == (("u",), ("y",), ())
    assert [(r.name, len(r)) for r in dm.records("train")] == [("SNLS80mV.csv[40650:95950]", 55300)]
    assert [(r.name, len(r)) for r in dm.records("val")] == [("SNLS80mV.csv[95950:105712]", 9762)]
    sets = {name: [(r.name, len(r)) for r in records] for name, records in dm.test_sets().items()}
    assert sets == {"multisine": [("SNLS80mV.csv[105712:127400]", 21688)],
                    "arrow_full": [("SNLS80mV.csv[100:40575]", 40475)],
                    "arrow_no_extrapolation": [("SNLS80mV.csv[100:32100]", 32000)]}
    # train + val = the first 75 % of the multisine [40650, 127400), as nonlinear_benchmarks
    assert int(0.75 * (127400 - 40650)) == 55300 + 9762
    raw = read_columns(SHARED_DATA / "silverbox" / "SNLS80mV.csv")
    assert list(raw) == ["V1", "V2"]  # the trailing comma's empty column is gone
    test = dm.test_sets()["multisine"][0]
    np.testing.assert_array_equal(test["u"], raw["V1"][105712:127400])  # volts, no decimation
    np.testing.assert_array_equal(test["y"], raw["V2"][105712:127400])
    assert test.time[0] == pytest.approx(105712 / (1e7 / 2**14))
    assert dm.channels["y"].display_unit == "mV" and dm.channels["y"].display_factor == 1e3
    assert len(dm.dataset("train")) == len(range(0, 55300 - (dm.past + dm.window), 5))
    _windows_stay_inside_their_records(dm, "train")


def test_emps_force_from_gain_and_voltage(monkeypatch):
    dm = _load("emps", monkeypatch)
    assert dm.dt == pytest.approx(1e-3) and dm.past == 20
    assert [(r.name, len(r)) for r in dm.records("train")] == [("DATA_EMPS.mat[0:19873]", 19873)]
    assert [(r.name, len(r)) for r in dm.records("val")] == [("DATA_EMPS.mat[19873:24841]", 4968)]
    assert {k: [(r.name, len(r)) for r in v] for k, v in dm.test_sets().items()} == {
        "test": [("DATA_EMPS_PULSES.mat", 24841)]}
    raw = read_columns(SHARED_DATA / "emps" / "DATA_EMPS_PULSES.mat")
    test = dm.records("test")[0]
    np.testing.assert_allclose(test["force"], raw["gtau"].item() * raw["vir"].ravel(), rtol=1e-15)
    np.testing.assert_array_equal(test["position"], raw["qm"].ravel())
    np.testing.assert_allclose(test.time, raw["t"].ravel(), atol=1e-12)
    assert dm.channels["position"].display_unit == "mm"
    _windows_stay_inside_their_records(dm, "val")


def test_racecar_without_standstill(monkeypatch):
    dm = _load("racecar", monkeypatch)
    assert dm.dt == pytest.approx(0.04) and dm.scheduling_names == ("velocity",)
    assert dm.output_names == ("yaw_rate", "side_slip")
    # the car stands still for the first 394 samples; above 5 m/s it keeps moving to the end of
    # the log, so each split keeps one stretch
    names = {split: [(r.name, len(r)) for r in dm.records(split)] for split in ("train", "val", "test")}
    assert names == {"train": [("putnam_park_2023_run4_2.csv[394:7140]", 6746)],
                     "val": [("putnam_park_2023_run4_2.csv[7140:8330]", 1190)],
                     "test": [("putnam_park_2023_run4_2.csv[8330:11900]", 3570)]}
    raw = read_columns(SHARED_DATA / "racecar" / "putnam_park_2023_run4_2.csv")
    assert list(raw)[:5] == ["time(s)", "x(m)", "y(m)", "vx(m/s)", "vy(m/s)"]  # the '# ' header
    train = dm.records("train")[0]
    assert train.time[0] == pytest.approx(394 * 0.04, abs=1e-4)  # Unix time, offset removed
    for split in ("train", "val", "test"):
        assert all(np.all(r["velocity"] > 5.0) for r in dm.records(split))
        _windows_stay_inside_their_records(dm, split)
    stretch = slice(394, 7140)
    beta = np.arctan2(raw["vy(m/s)"][stretch], raw["vx(m/s)"][stretch])
    np.testing.assert_allclose(train["side_slip"], beta)
    np.testing.assert_array_equal(train["steering_angle"], raw["delta(rad)"][stretch])
    batch = next(iter(dm.train_dataloader()))
    assert batch["s"].shape == (32, dm.past + dm.window + 1, 1) and bool((batch["s"] > 5.0).all())  # SI speed


def test_racecar_selection_cuts_inside_a_split(monkeypatch):
    """Above 10 m/s the log falls apart into stretches; none is shorter than one window and no
    window crosses a cut."""
    dm = _load("racecar", monkeypatch, "data.select=['velocity > 10']")
    train = dm.records("train")
    assert len(train) >= 3 and all(len(r) >= dm.window + 1 for r in train)
    assert all(np.all(r["velocity"] > 10.0) for r in train)
    _windows_stay_inside_their_records(dm, "train")
