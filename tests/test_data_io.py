"""Reading and validating measured files: formats, units, and clear errors for bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from data_helpers import (
    fake_mat73,
    make_data_dir,
    synthetic_channels,
    write_csv_text,
    write_table,
)

from hypa.data import DataError, find_split_files, load_dataset, load_record, unit_factor

MODEL = ["steering_wheel_angle", "yaw_rate", "side_slip"]


def _record_file(tmp_path, name="train_a.csv", duration_s=1.0, **kwargs):
    return write_table(tmp_path / name, synthetic_channels(duration_s, **kwargs))


@pytest.mark.parametrize("suffix", [".parquet", ".mat"])
def test_csv_parquet_and_mat_read_the_same_content(tmp_path, suffix):
    data = synthetic_channels(1.0, seed=3)
    reference = load_record(write_table(tmp_path / "a.csv", data), MODEL, ["rear_wheel_angle"])
    other = load_record(write_table(tmp_path / f"a{suffix}", data), MODEL, ["rear_wheel_angle"])
    np.testing.assert_array_equal(other.time, reference.time)
    assert other.names == reference.names == (*MODEL, "rear_wheel_angle")
    for name in reference.names:
        np.testing.assert_array_equal(other[name], reference[name])
        np.testing.assert_array_equal(other[name], data[name])


def test_mat_column_vectors_are_read_like_row_vectors(tmp_path):
    data = synthetic_channels(0.5)
    rows = load_record(write_table(tmp_path / "r.mat", data, mat_oned_as="row"), MODEL)
    cols = load_record(write_table(tmp_path / "c.mat", data, mat_oned_as="column"), MODEL)
    for name in MODEL:
        np.testing.assert_array_equal(rows[name], cols[name])


def test_file_in_degrees_with_unit_override_gives_the_same_si_values(tmp_path):
    data = synthetic_channels(1.0)
    si = load_record(write_table(tmp_path / "si.csv", data), MODEL)
    in_deg = dict(data, SWA_deg=np.degrees(data["steering_wheel_angle"]))
    del in_deg["steering_wheel_angle"]
    in_deg["yaw_rate"] = np.degrees(data["yaw_rate"])
    in_deg["time"] = data["time"] * 1e3
    path = write_table(tmp_path / "deg.csv", in_deg)
    converted = load_record(
        path,
        MODEL,
        columns={"steering_wheel_angle": "SWA_deg"},
        units={"steering_wheel_angle": "deg", "yaw_rate": "deg/s", "time": "ms"},
    )
    np.testing.assert_allclose(converted.time, si.time, rtol=1e-15, atol=1e-15)
    for name in MODEL:
        np.testing.assert_allclose(converted[name], si[name], rtol=1e-14, atol=1e-16)


@pytest.mark.parametrize(
    ("unit", "channel", "factor"),
    [("rad", "side_slip", 1.0), ("deg", "steering_wheel_angle", math.pi / 180),
     ("deg/s", "yaw_rate", math.pi / 180), ("m/s2", "lateral_acceleration", 1.0),
     ("g", "lateral_acceleration", 9.80665), ("km/h", "velocity", 1 / 3.6), ("ms", "time", 1e-3),
     (0.5, "yaw_rate", 0.5), ("2.5", "velocity", 2.5)],
)
def test_unit_factors(unit, channel, factor):
    assert unit_factor(unit, channel) == pytest.approx(factor, rel=1e-15)


def test_unknown_unit_lists_the_known_ones():
    with pytest.raises(DataError, match=r"unknown unit 'grad'.*deg/s.*km/h"):
        unit_factor("grad", "steering_wheel_angle")


def test_unit_of_the_wrong_dimension_is_rejected():
    with pytest.raises(DataError, match=r"'deg' is a unit of angle.*'yaw_rate'.*deg/s"):
        unit_factor("deg", "yaw_rate")


def test_missing_column_suggests_the_closest_and_lists_the_file(tmp_path):
    data = synthetic_channels(0.5)
    data["yawrate"] = data.pop("yaw_rate")
    path = write_table(tmp_path / "train_x.csv", data)
    with pytest.raises(DataError) as error:
        load_record(path, MODEL)
    message = str(error.value)
    assert "train_x.csv" in message and "'yaw_rate'" in message
    assert "did you mean 'yawrate'" in message
    assert "steering_wheel_angle, side_slip" in message  # what the file has


def test_mapped_column_that_is_missing_names_both_names(tmp_path):
    path = _record_file(tmp_path)
    with pytest.raises(DataError, match=r"column 'SWA' for channel 'steering_wheel_angle'"):
        load_record(path, MODEL, columns={"steering_wheel_angle": "SWA"})


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".mat"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_values_name_file_column_first_row_and_count(tmp_path, suffix, bad):
    data = synthetic_channels(0.5)
    data["side_slip"][[17, 40, 41]] = bad
    path = write_table(tmp_path / f"val_1{suffix}", data)
    with pytest.raises(DataError) as error:
        load_record(path, MODEL)
    message = str(error.value)
    assert f"val_1{suffix}" in message and "'side_slip'" in message
    assert "3 missing or non-finite" in message and "row 17" in message
    if suffix == ".csv":
        assert "line 19" in message


def test_empty_and_text_cells_in_csv(tmp_path):
    header = ["time", *MODEL]
    rows = [[f"{i / 1024!r}", "0.1", "0.2", "0.3"] for i in range(8)]
    rows[5][2] = ""
    with pytest.raises(DataError, match=r"'yaw_rate'.*1 missing.*row 5"):
        load_record(write_csv_text(tmp_path / "a.csv", header, rows), MODEL)
    rows[5][2] = "0.2"
    rows[6][3] = "n/a?"
    with pytest.raises(DataError, match=r"'side_slip'.*row 6.*'n/a\?' is not a number"):
        load_record(write_csv_text(tmp_path / "b.csv", header, rows), MODEL)


def test_non_increasing_time_names_the_row(tmp_path):
    data = synthetic_channels(0.5)
    data["time"][100] = data["time"][99]
    path = write_table(tmp_path / "train_t.parquet", data)
    expected = r"train_t.parquet: column 'time', row 100: time is not strictly increasing"
    with pytest.raises(DataError, match=expected):
        load_record(path, MODEL)


def test_sample_rate_other_than_configured_is_rejected(tmp_path):
    path = write_table(tmp_path / "a.csv", synthetic_channels(0.5, sample_rate_hz=1000.0))
    expected = r"a.csv.*measured sample rate 1000 Hz.*sample_rate_hz=1024"
    with pytest.raises(DataError, match=expected):
        load_record(path, MODEL, sample_rate_hz=1024.0)
    load_record(path, MODEL, sample_rate_hz=1000.0)  # the right configuration reads it


def test_irregular_time_step_names_the_first_row(tmp_path):
    data = synthetic_channels(0.5)
    data["time"][300:] += 0.5 / 1024  # a gap of half a step
    path = write_table(tmp_path / "a.mat", data)
    with pytest.raises(DataError, match=r"a.mat: column 'time', row 300: irregular time step"):
        load_record(path, MODEL)


def test_folder_errors(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        find_split_files(tmp_path / "nowhere")
    write_table(tmp_path / "train_1.csv", synthetic_channels(0.5))
    with pytest.raises(DataError, match=r"no val\* file.*train_1.csv"):
        find_split_files(tmp_path)
    (tmp_path / "train_1.csv").rename(tmp_path / "val_1.csv")
    with pytest.raises(DataError, match=r"no train\* file"):
        find_split_files(tmp_path)
    write_table(tmp_path / "train_1.csv", synthetic_channels(0.5))
    (tmp_path / "test_1.xlsx").write_text("not a table")
    with pytest.raises(DataError, match=r"test_1.xlsx: unsupported file type '.xlsx'"):
        find_split_files(tmp_path)


def test_split_files_are_sorted_and_test_is_optional(tmp_path):
    for name in ("val_b.csv", "train_2.parquet", "train_1.mat", "notes.txt", "val_a.csv"):
        (tmp_path / name).touch()
    found = find_split_files(tmp_path)
    assert [p.name for p in found["train"]] == ["train_1.mat", "train_2.parquet"]
    assert [p.name for p in found["val"]] == ["val_a.csv", "val_b.csv"]
    assert "test" not in found


def test_matlab_v73_file_asks_for_v7(tmp_path):
    with pytest.raises(DataError, match=r"a.mat.*v7.3.*-v7.*CSV"):
        load_record(fake_mat73(tmp_path / "a.mat"), MODEL)


def test_dataset_keeps_eval_channels_out_of_training_records(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", n_test=1, duration_s=1.0)
    dataset = load_dataset(data_dir, ["steering_wheel_angle"], ["yaw_rate", "side_slip"],
                           ["rear_wheel_angle", "lateral_acceleration"])
    assert all("rear_wheel_angle" not in r for r in dataset["train"])
    assert all("rear_wheel_angle" in r and "lateral_acceleration" in r for r in dataset["val"])
    assert len(dataset["test"]) == 1 and dataset.metadata == {}


def test_metadata_is_read_when_present(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", duration_s=0.5)
    meta = {"segments": {"val_00.csv": [[0.0, 0.25, "lane change"]]}}
    (data_dir / "dataset.json").write_text(json.dumps(meta))
    dataset = load_dataset(data_dir, ["steering_wheel_angle"], ["yaw_rate"])
    assert dataset.metadata == meta


def test_evaluation_only_channel_cannot_be_a_model_channel(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", duration_s=0.5)
    with pytest.raises(DataError, match="rear_wheel_angle.*evaluation only"):
        load_dataset(data_dir, ["steering_wheel_angle", "rear_wheel_angle"], ["yaw_rate"])


def test_misspelled_mapping_key_and_bad_unit_fail_before_reading(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", duration_s=0.5)
    with pytest.raises(DataError, match=r"data.units has unknown channel name\(s\) \['steering'\]"):
        load_dataset(data_dir, ["steering_wheel_angle"], ["yaw_rate"], units={"steering": "deg"})
    with pytest.raises(DataError, match="unknown unit 'degree'"):
        load_dataset(data_dir, ["steering_wheel_angle"], ["yaw_rate"],
                     units={"steering_wheel_angle": "degree"})
