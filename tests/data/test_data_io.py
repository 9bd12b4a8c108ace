"""Reading and validating measured files: formats, units, and clear errors for bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hypa.data import (
    ChannelSpec,
    DataError,
    find_split_files,
    load_dataset,
    load_record,
    read_columns,
    unit_factor,
)
from hypa.paper.testbench.sensors import TESTBENCH_CHANNELS

from data_helpers import (
    fake_mat73,
    make_data_dir,
    synthetic_channels,
    write_csv_text,
    write_table,
)

BENCH = {c.name: c for c in TESTBENCH_CHANNELS}
MODEL = ["steering_wheel_angle", "yaw_rate", "side_slip"]
SPECS = [BENCH[name] for name in MODEL]


def _specs(**changes: dict) -> list[ChannelSpec]:
    """The test bench's model channels, some declared differently."""
    return [ChannelSpec(**{"name": c.name, "role": c.role, "file_unit": c.file_unit,
                           **changes.get(c.name, {})}) for c in SPECS]


def _record_file(tmp_path, name="train_a.csv", duration_s=1.0, **kwargs):
    return write_table(tmp_path / name, synthetic_channels(duration_s, **kwargs))


@pytest.mark.parametrize("suffix", [".parquet", ".mat"])
def test_csv_parquet_and_mat_read_the_same_content(tmp_path, suffix):
    data = synthetic_channels(1.0, seed=3)
    specs = [*SPECS, BENCH["rear_wheel_angle"]]
    reference = load_record(write_table(tmp_path / "a.csv", data), specs)
    other = load_record(write_table(tmp_path / f"a{suffix}", data), specs)
    np.testing.assert_array_equal(other.time, reference.time)
    assert other.names == reference.names == (*MODEL, "rear_wheel_angle")
    for name in reference.names:
        np.testing.assert_array_equal(other[name], reference[name])
        np.testing.assert_array_equal(other[name], data[name])


def test_mat_column_vectors_are_read_like_row_vectors(tmp_path):
    data = synthetic_channels(0.5)
    rows = load_record(write_table(tmp_path / "r.mat", data, mat_oned_as="row"), SPECS)
    cols = load_record(write_table(tmp_path / "c.mat", data, mat_oned_as="column"), SPECS)
    for name in MODEL:
        np.testing.assert_array_equal(rows[name], cols[name])


def test_file_in_degrees_with_declared_units_gives_the_same_si_values(tmp_path):
    data = synthetic_channels(1.0)
    si = load_record(write_table(tmp_path / "si.csv", data), SPECS)
    in_deg = dict(data, SWA_deg=np.degrees(data["steering_wheel_angle"]))
    del in_deg["steering_wheel_angle"]
    in_deg["yaw_rate"] = np.degrees(data["yaw_rate"])
    in_deg["time"] = data["time"] * 1e3
    path = write_table(tmp_path / "deg.csv", in_deg)
    specs = _specs(steering_wheel_angle={"column": "SWA_deg", "file_unit": "deg"},
                   yaw_rate={"file_unit": "deg/s"})
    converted = load_record(path, specs, time_unit="ms")
    np.testing.assert_allclose(converted.time, si.time, rtol=1e-15, atol=1e-15)
    for name in MODEL:
        np.testing.assert_allclose(converted[name], si[name], rtol=1e-14, atol=1e-16)


@pytest.mark.parametrize(
    ("unit", "factor"),
    [("rad", 1.0), ("deg", math.pi / 180), ("deg/s", math.pi / 180), ("m/s2", 1.0),
     ("g", 9.80665), ("km/h", 1 / 3.6), ("ms", 1e-3), ("mV", 1e-3), ("mm", 1e-3), ("kN", 1e3),
     ("kPa", 1e3), ("bar", 1e5), ("%", 0.01), ("-", 1.0), ("Nm", 1.0), ("kg", 1.0)],
)
def test_unit_factors(unit, factor):
    assert unit_factor(unit, "x") == pytest.approx(factor, rel=1e-15)


def test_unknown_unit_names_the_channel_and_lists_the_known_ones():
    with pytest.raises(DataError, match=r"unknown unit 'gradd' of channel 'steering'.*deg/s.*data.units"):
        unit_factor("gradd", "steering")
    with pytest.raises(DataError, match=r"unknown unit 'deg/' of channel 'yaw_rate'"):
        ChannelSpec("yaw_rate", "output", "deg/")


@pytest.mark.parametrize("name, factor, offset, si", [
    ("degC", 1.0, 273.15, "K"), ("degF", 5 / 9, 255.3722222, "K"), ("delta_degC", 1.0, 0.0, "K"), ("K", 1.0, 0.0, "K"),
    ("psi", 6894.757293, 0.0, "Pa"), ("l/min", 1e-3 / 60, 0.0, "m^3/s"), ("mA", 1e-3, 0.0, "A"),
    ("N*m", 1.0, 0.0, "Nm"), ("kW", 1e3, 0.0, "W"), ("g", 9.80665, 0.0, "m/s^2"),
    ("1/min", 2 * np.pi / 60, 0.0, "rad/s"),
])
def test_units_for_any_field_convert_to_si(name, factor, offset, si):
    from hypa.core.units import unit

    found = unit(name, "x")
    assert (found.factor, found.offset, found.si) == (pytest.approx(factor, rel=1e-9), pytest.approx(offset), si)


def test_a_temperature_in_degc_is_read_as_kelvin_and_its_display_must_not_shift(tmp_path):
    spec = ChannelSpec("t", "output", "degC")
    assert (spec.unit, spec.factor, spec.offset, spec.display_unit) == ("K", 1.0, 273.15, "K")
    assert ChannelSpec("t", "output", "degC", display_unit="delta_degC").display_factor == 1.0
    with pytest.raises(DataError, match=r"display unit 'degC' of channel 't' has an offset"):
        ChannelSpec("t", "output", "K", display_unit="degC")
    with pytest.raises(DataError, match=r"display unit 'kPa' of channel 't' is a unit of pressure"):
        ChannelSpec("t", "output", "degC", display_unit="kPa")


def test_a_data_sets_own_unit_names(tmp_path):
    from hypa.core.units import define_units, unit

    define_units({"counts": "0.001 * m"})
    define_units({"counts": "0.001 * m"})  # the same definition again: fine (several data modules)
    assert unit("counts").factor == pytest.approx(1e-3) and unit("counts/s").si == "m/s"
    with pytest.raises(DataError, match=r"data.units.counts: 'counts' is already a unit"):
        define_units({"counts": "0.002 * m"})
    with pytest.raises(DataError, match=r"data.units.ticks: cannot define 'ticks'"):
        define_units({"ticks": "0.001 * blorp"})


def test_display_unit_of_another_dimension_is_rejected():
    with pytest.raises(DataError, match=r"display unit 'deg' of channel 'yaw_rate' is a unit of angle"
                                        r".*'rad/s'.*deg/s"):
        ChannelSpec("yaw_rate", "output", "rad/s", display_unit="deg")
    spec = ChannelSpec("velocity", "scheduling", "m/s", display_unit="km/h")
    assert (spec.unit, spec.display_unit, spec.display_factor) == ("m/s", "km/h", pytest.approx(3.6))
    spec = ChannelSpec("position", "output", "mm")
    assert (spec.unit, spec.factor, spec.display_unit, spec.display_factor) == ("m", 1e-3, "m", 1.0)


def test_missing_column_suggests_the_closest_and_lists_the_file(tmp_path):
    data = synthetic_channels(0.5)
    data["yawrate"] = data.pop("yaw_rate")
    path = write_table(tmp_path / "train_x.csv", data)
    with pytest.raises(DataError) as error:
        load_record(path, SPECS)
    message = str(error.value)
    assert "train_x.csv" in message and "'yaw_rate'" in message
    assert "did you mean 'yawrate'" in message
    assert "steering_wheel_angle, side_slip" in message  # what the file has
    assert "data.channels.yaw_rate.column" in message


def test_declared_column_that_is_missing_names_both_names(tmp_path):
    path = _record_file(tmp_path)
    with pytest.raises(DataError, match=r"column 'SWA' for channel 'steering_wheel_angle'"):
        load_record(path, _specs(steering_wheel_angle={"column": "SWA"}))


def test_missing_scheduling_channel_names_file_column_and_closest_match(tmp_path):
    data = synthetic_channels(0.5)
    data["vx"] = data.pop("velocity")
    path = write_table(tmp_path / "train_v.csv", data)
    specs = [*SPECS, ChannelSpec("velocity", "scheduling", "m/s", column="v_x")]
    with pytest.raises(DataError, match=r"train_v.csv: column 'v_x' for channel 'velocity' not "
                                        r"found \(did you mean 'vx'\?\)"):
        load_record(path, specs)


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".mat"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_values_name_file_column_first_row_and_count(tmp_path, suffix, bad):
    data = synthetic_channels(0.5)
    data["side_slip"][[17, 40, 41]] = bad
    path = write_table(tmp_path / f"val_1{suffix}", data)
    with pytest.raises(DataError) as error:
        load_record(path, SPECS)
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
        load_record(write_csv_text(tmp_path / "a.csv", header, rows), SPECS)
    rows[5][2] = "0.2"
    rows[6][3] = "n/a?"
    with pytest.raises(DataError, match=r"'side_slip'.*row 6.*'n/a\?' is not a number"):
        load_record(write_csv_text(tmp_path / "b.csv", header, rows), SPECS)


def test_comment_header_trailing_commas_and_no_time_column(tmp_path):
    """A '# ' header line (as the race car's logger writes it) is the header; an unnamed empty
    column from trailing commas (as in Silverbox's CSV) is dropped; without a time column
    sample i lies at i / sample_rate_hz."""
    path = tmp_path / "log.csv"
    path.write_text("# t(s),vx(m/s),u\n" + "".join(f"{1.7e9 + i / 25!r},{i},{i * i}\n" for i in range(6)))
    assert list(read_columns(path)) == ["t(s)", "vx(m/s)", "u"]
    channels = [ChannelSpec("u", "input", "-"), ChannelSpec("v", "output", "m/s", column="vx(m/s)")]
    record = load_record(path, channels, time_column="t(s)", sample_rate_hz=25.0)
    np.testing.assert_allclose(record.time, np.arange(6) / 25, atol=1e-6)  # Unix time starts at 0
    np.testing.assert_array_equal(record["v"], np.arange(6.0))
    path = tmp_path / "sb.csv"
    path.write_text('"V1","V2",\n' + "".join(f"{i},{-i},\n" for i in range(5)) + "\n")
    assert list(read_columns(path)) == ["V1", "V2"]
    channels = [ChannelSpec("u", "input", "V", column="V1"),
                ChannelSpec("y", "output", "mV", column="V2")]
    record = load_record(path, channels, time_column=None, sample_rate_hz=4.0)
    np.testing.assert_array_equal(record.time, np.arange(5) / 4.0)
    np.testing.assert_array_equal(record["y"], -np.arange(5) * 1e-3)


def test_non_increasing_time_names_the_row(tmp_path):
    data = synthetic_channels(0.5)
    data["time"][100] = data["time"][99]
    path = write_table(tmp_path / "train_t.parquet", data)
    expected = r"train_t.parquet: column 'time', row 100: time is not strictly increasing"
    with pytest.raises(DataError, match=expected):
        load_record(path, SPECS)


def test_sample_rate_other_than_configured_is_rejected(tmp_path):
    path = write_table(tmp_path / "a.csv", synthetic_channels(0.5, sample_rate_hz=1000.0))
    expected = r"a.csv.*measured sample rate 1000 Hz.*sample_rate_hz=1024"
    with pytest.raises(DataError, match=expected):
        load_record(path, SPECS, sample_rate_hz=1024.0)
    load_record(path, SPECS, sample_rate_hz=1000.0)  # the right configuration reads it


def test_irregular_time_step_names_the_first_row(tmp_path):
    data = synthetic_channels(0.5)
    data["time"][300:] += 0.5 / 1024  # a gap of half a step
    path = write_table(tmp_path / "a.mat", data)
    with pytest.raises(DataError, match=r"a.mat: column 'time', row 300: irregular time step"):
        load_record(path, SPECS)


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
        load_record(fake_mat73(tmp_path / "a.mat"), SPECS)


def test_dataset_keeps_eval_channels_out_of_training_records(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", n_test=1, duration_s=1.0)
    dataset = load_dataset(data_dir, BENCH)
    assert all("rear_wheel_angle" not in r for r in dataset["train"])
    assert all("rear_wheel_angle" in r and "lateral_acceleration" in r for r in dataset["val"])
    assert len(dataset["test"]) == 1 and dataset.metadata == {}
    assert list(dataset.test_sets) == ["test"]


def test_metadata_is_read_when_present(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", duration_s=0.5)
    meta = {"segments": {"val_00.csv": [[0.0, 0.25, "lane change"]]}}
    (data_dir / "dataset.json").write_text(json.dumps(meta))
    dataset = load_dataset(data_dir, {c.name: c for c in SPECS})
    assert dataset.metadata == meta
