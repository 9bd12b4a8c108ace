"""The simulated test bench: excitation, truth, sensors, files, cache and CLI."""

from __future__ import annotations

import itertools
import json
import math
import runpy
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from omegaconf.errors import ConfigKeyError
from scipy.signal import lsim, welch

from hypa.paper.testbench import (
    TestbenchConfig,
    ensure_dataset,
    generate_dataset,
    load_description,
    read_record,
    simulate_record,
)
from hypa.paper.testbench import dataset as dataset_module
from hypa.paper.testbench.config import RecordConfig, SteeringConfig, StochasticConfig
from hypa.paper.testbench.excitation import stochastic_steering
from hypa.paper.testbench.records import COLUMNS, config_truth
from hypa.paper.testbench.truth import (
    axle_characteristic,
    front_wheel_angle,
    rear_steering_command,
    static_axle_loads,
)
from hypa.vehicle import VehicleParameters

from conftest import compose_config

FS = 1024.0


# Short records (20 s + 10 s stochastic, the val manoeuvres shrunk to 30 s) keep tests fast.
SHORT = {
    "records": {
        "train_1": {"stochastic_duration_s": 20.0},
        "train_2": {"stochastic_duration_s": 20.0},
        "val": {"stochastic_duration_s": 10.0},
    },
    "excitation": {
        "lane_change": {"duration_s": 10.0, "lead_s": 1.0},
        "step_steer": {"duration_s": 8.0, "lead_s": 1.0, "hold_s": 2.0},
        "sine_sweep": {"duration_s": 12.0},
    },
}


def short_config(overrides: dict | None = None, base: TestbenchConfig | None = None):
    return (base or TestbenchConfig()).merged(SHORT).merged(overrides)


truth_of = config_truth  # the test bench's truth for a whole config (hypa.paper.testbench.records)


def linear_single_track(vehicle: VehicleParameters) -> tuple[np.ndarray, np.ndarray]:
    """A, B of x = (yaw rate, side slip), u = front wheel angle (paper Sec. 5)."""
    m, izz, lf, lr, cf, cr, v = (
        vehicle.mass,
        vehicle.izz,
        vehicle.lf,
        vehicle.lr,
        vehicle.cf,
        vehicle.cr,
        vehicle.velocity,
    )
    a = np.array(
        [
            [-(cf * lf**2 + cr * lr**2) / (v * izz), -(cf * lf - cr * lr) / izz],
            [-1.0 - (cf * lf - cr * lr) / (v**2 * m), -(cf + cr) / (v * m)],
        ]
    )
    b = np.array([[cf * lf / izz], [cf / (v * m)]])
    return a, b


@pytest.fixture(scope="module")
def short_dataset(tmp_path_factory) -> tuple[TestbenchConfig, Path]:
    config = short_config()
    return config, generate_dataset(config, tmp_path_factory.mktemp("data"))


# --- config ----------------------------------------------------------------------------


def test_yaml_mirrors_the_dataclass_defaults():
    cfg = compose_config("testbench")
    assert TestbenchConfig.from_dict(cfg.testbench) == TestbenchConfig()
    assert cfg.out is None
    assert TestbenchConfig().vehicle == VehicleParameters()


def test_config_rejects_misspelled_keys_and_bad_values():
    with pytest.raises(ConfigKeyError, match="enabeld"):
        TestbenchConfig.from_dict({"tires": {"enabeld": False}})
    with pytest.raises(ValueError, match="maneuvers"):
        TestbenchConfig.from_dict({"records": {"val": {"maneuvers": ["slalom"]}}})
    with pytest.raises(ValueError, match="mass"):
        TestbenchConfig.from_dict({"vehicle": {"mass": -1.0}})
    config = TestbenchConfig.from_dict({"vehicle": {"cf": 1.0e5}})
    assert config.vehicle.cf == 1.0e5 and TestbenchConfig().vehicle.cf == 150000.0


def test_linear_config_switches_every_effect_off():
    config = TestbenchConfig.linear()
    assert not (config.tires.enabled or config.relaxation.enabled)
    assert not (config.rear_steering.enabled or config.sensors.enabled)
    assert TestbenchConfig.linear(noise=True).sensors.enabled
    assert TestbenchConfig.linear(noise=True).sensors.bias_scale == 0.0


# --- excitation ------------------------------------------------------------------------


@pytest.mark.parametrize("crest_factor", [2.3, None])
def test_excitation_spectrum_is_flat_then_rolls_off_and_stops_at_cutoff(crest_factor):
    config = StochasticConfig(crest_factor=crest_factor)
    signal = stochastic_steering(300.0, FS, seed=7, break_hz=1.0, config=config)
    frequency, psd = welch(signal, FS, nperseg=8192)

    def level(low: float, high: float) -> float:
        return float(np.mean(psd[(frequency >= low) & (frequency <= high)]))

    flat = level(0.1, 0.9)
    assert 0.7 < level(0.1, 0.5) / level(0.5, 0.9) < 1.4
    assert 0.25 * 0.6 < level(1.9, 2.1) / flat < 0.25 * 1.5  # PSD ~ (f_b / f)^2
    assert 0.0625 * 0.6 < level(3.8, 4.2) / flat < 0.0625 * 1.5
    assert level(6.0, 500.0) < 1e-6 * flat
    assert np.max(np.abs(signal)) == pytest.approx(config.amplitude, rel=1e-12)
    assert signal[0] == pytest.approx(0.0, abs=1e-6) and abs(signal[-1]) < 1e-6
    if crest_factor is not None:
        assert np.max(np.abs(signal)) / np.std(signal) == pytest.approx(crest_factor, rel=0.05)


def test_same_seed_is_identical_and_other_seeds_differ():
    config = short_config()
    first, again = simulate_record(config, "train_1"), simulate_record(config, "train_1")
    other = simulate_record(config, "train_2")
    for name in COLUMNS:
        np.testing.assert_array_equal(first.columns[name], again.columns[name])
    assert np.max(np.abs(first.steering_wheel_angle - other.steering_wheel_angle)) > 0.1


def test_default_training_record_reaches_35_deg_and_about_7_m_s2():
    record = simulate_record(TestbenchConfig(), "train_1")  # the real 300 s record
    assert record.duration_s == 300.0
    assert np.degrees(np.max(np.abs(record.steering_wheel_angle))) == pytest.approx(35.0, abs=0.1)
    max_ay = np.max(np.abs(record.truth.lateral_acceleration))
    assert 5.5 < max_ay < 8.5
    # the data leave the linear single-track range (about 4 m/s^2) for a real share of time
    assert np.mean(np.abs(record.truth.lateral_acceleration) > 4.0) > 0.03


# --- truth -----------------------------------------------------------------------------


def test_linear_truth_equals_linear_single_track_model():
    config = short_config(base=TestbenchConfig.linear())
    record = simulate_record(config, "val")  # stochastic + lane change, step, sweep
    a, b = linear_single_track(config.vehicle)
    u = record.steering_wheel_angle / config.vehicle.steering_ratio
    time = record.columns["time"]
    _, _, x = lsim((a, b, np.eye(2), np.zeros((2, 1))), u, time)
    ay = config.vehicle.velocity * ((x @ a.T)[:, 1] + (b[1, 0] * u) + x[:, 0])
    for name, expected in (
        ("yaw_rate", x[:, 0]),
        ("side_slip", x[:, 1]),
        ("lateral_acceleration", ay),
    ):
        error = np.max(np.abs(record.columns[name] - expected))
        assert error < 1e-3 * np.max(np.abs(expected)), name
    np.testing.assert_array_equal(record.columns["rear_wheel_angle"], 0.0)
    np.testing.assert_array_equal(record.columns["velocity"], config.vehicle.velocity)


def test_magic_formula_slope_at_zero_is_the_cornering_stiffness():
    config = TestbenchConfig()
    load_f, load_r = static_axle_loads(config.vehicle)
    assert load_f + load_r == pytest.approx(config.vehicle.mass * 9.81)
    h = 1e-7
    for stiffness, load in ((config.vehicle.cf, load_f), (config.vehicle.cr, load_r)):
        slope = (
            axle_characteristic(h, stiffness, load, config.tires)
            - axle_characteristic(-h, stiffness, load, config.tires)
        ) / (2 * h)
        assert slope == pytest.approx(stiffness, rel=1e-6)
        alpha = np.linspace(0.0, 0.4, 4001)
        force = axle_characteristic(alpha, stiffness, load, config.tires)
        assert np.max(force) == pytest.approx(config.tires.mu * load, rel=1e-4)  # D = mu Fz
        assert np.all(force[1:] < stiffness * alpha[1:])  # saturating, never above linear
        linear = axle_characteristic(alpha, stiffness, load, TestbenchConfig.linear().tires)
        np.testing.assert_allclose(linear, stiffness * alpha)


def test_integration_loop_uses_the_documented_tyre_and_ecu_laws():
    config = TestbenchConfig().merged({"relaxation": {"enabled": False}, "load_transfer": {"enabled": False}})
    vehicle, v = config.vehicle, config.vehicle.velocity
    t = np.arange(int(20 * FS)) / FS
    sw = 0.6 * np.sin(2 * np.pi * 0.3 * t) * np.minimum(t / 5.0, 1.0)
    truth = truth_of(config, sw)
    load_f, load_r = static_axle_loads(vehicle)
    alpha_f = truth.front_wheel_angle - truth.side_slip - vehicle.lf / v * truth.yaw_rate
    alpha_r = truth.rear_wheel_angle - truth.side_slip + vehicle.lr / v * truth.yaw_rate
    forces = axle_characteristic(alpha_f, vehicle.cf, load_f, config.tires) + axle_characteristic(
        alpha_r, vehicle.cr, load_r, config.tires
    )
    np.testing.assert_allclose(truth.lateral_acceleration, forces / vehicle.mass, atol=1e-9)
    rws = config.rear_steering
    assert rws.transient_ratio > 0  # the default ECU's phase reversal is part of the check
    lowpassed = front_wheel_angle(sw, FS, vehicle.steering_ratio, SteeringConfig(lag_tau_s=rws.transient_tau_s))
    command = rear_steering_command(sw / vehicle.steering_ratio, truth.yaw_rate, v, rws, lowpassed)
    expected_rate = np.clip(
        (command - truth.rear_wheel_angle) / rws.actuator_tau_s, -rws.rate_limit, rws.rate_limit
    )
    rate = np.gradient(truth.rear_wheel_angle, 1 / FS)
    assert np.max(np.abs(rate - expected_rate)[1:-1]) < 1e-3 * np.max(np.abs(expected_rate))


def test_load_transfer_in_steady_cornering_follows_the_documented_wheel_laws():
    # a held steer: the roll mode settles (a_roll = a_y), so each axle is its two wheels at
    # static load +- share m h a_y / track
    config = TestbenchConfig().merged({"relaxation": {"enabled": False}, "rear_steering": {"enabled": False}})
    vehicle, v, lt = config.vehicle, config.vehicle.velocity, config.load_transfer
    sw = np.minimum(np.arange(int(8 * FS)) / FS, 1.0) * 0.5  # ramp to 0.5 rad, held
    truth = truth_of(config, sw)
    a_y = truth.lateral_acceleration[-1]
    assert a_y > 5.0
    load_f, load_r = static_axle_loads(vehicle)
    alpha_f = truth.front_wheel_angle[-1] - truth.side_slip[-1] - vehicle.lf / v * truth.yaw_rate[-1]
    alpha_r = -truth.side_slip[-1] + vehicle.lr / v * truth.yaw_rate[-1]
    shift_f = lt.front_roll_share * vehicle.mass * lt.cg_height_m * a_y / lt.track_front_m
    shift_r = (1 - lt.front_roll_share) * vehicle.mass * lt.cg_height_m * a_y / lt.track_rear_m
    forces = (axle_characteristic(alpha_f, vehicle.cf, load_f, config.tires, lt, shift_f)
              + axle_characteristic(alpha_r, vehicle.cr, load_r, config.tires, lt, shift_r))
    assert forces / vehicle.mass == pytest.approx(a_y, rel=1e-6)
    # degressive in load: a loaded axle has less slope and less peak than the same axle unloaded
    h, alpha = 1e-7, np.linspace(0.0, 0.4, 4001)
    for transfer in (0.0, shift_f):
        slope = (axle_characteristic(h, vehicle.cf, load_f, config.tires, lt, transfer)
                 - axle_characteristic(-h, vehicle.cf, load_f, config.tires, lt, transfer)) / (2 * h)
        peak = np.max(axle_characteristic(alpha, vehicle.cf, load_f, config.tires, lt, transfer))
        if transfer == 0.0:
            assert slope == pytest.approx(vehicle.cf, rel=1e-6)
            assert peak == pytest.approx(config.tires.mu * load_f, rel=1e-4)
        else:
            assert 0.8 * vehicle.cf < slope < 0.97 * vehicle.cf
            assert 0.9 * config.tires.mu * load_f < peak < 0.99 * config.tires.mu * load_f
    # and switched off, the truth is the plain axle (static loads) again
    plain = truth_of(config.merged({"load_transfer": {"enabled": False}}), sw)
    assert abs(plain.lateral_acceleration[-1]) > abs(a_y)


def test_rear_steering_off_gives_zero_rear_angle():
    config = short_config({"rear_steering": {"enabled": False}})
    record = simulate_record(config, "train_1")
    np.testing.assert_array_equal(record.truth.rear_wheel_angle, 0.0)
    noise = config.sensors.rear_wheel_angle.noise_std
    assert np.max(np.abs(record.columns["rear_wheel_angle"])) < 6 * noise


def test_rear_steering_is_in_phase_at_speed_and_counter_phase_when_slow():
    step = np.minimum(np.arange(int(6 * FS)) / FS, 1.0) * 0.2  # ramp to 0.2 rad, held
    for speed, sign in ((33.3, 1.0), (8.3, -1.0)):
        config = TestbenchConfig().merged({"vehicle": {"velocity": speed}})
        truth = truth_of(config, step)
        ratio = truth.rear_wheel_angle[-1] / truth.front_wheel_angle[-1]
        assert sign * ratio > 0.05, speed


def test_rear_steering_rate_and_angle_limits_hold_and_bind():
    # feedforward only, so the command (~ square wave) does not depend on the car's response
    feedforward = {"strength": 30.0, "yaw_rate_ratio_gain": 0.0, "yaw_rate_feedback_s": 0.0}
    config = TestbenchConfig().merged({"rear_steering": feedforward})
    t = np.arange(int(10 * FS)) / FS
    truth = truth_of(config, 0.3 * np.sin(2 * np.pi * 0.5 * t))  # command ~ square wave
    rws, rear = config.rear_steering, truth.rear_wheel_angle
    rate = np.abs(np.diff(rear)) * FS
    assert np.max(np.abs(rear)) <= rws.angle_limit * (1 + 1e-9)
    assert np.max(rate) <= rws.rate_limit * (1 + 1e-9)
    assert np.max(np.abs(rear)) > 0.95 * rws.angle_limit  # the limits are reached, not idle
    assert np.mean(rate > 0.999 * rws.rate_limit) > 0.1


def test_steering_dead_time_and_lag():
    config = TestbenchConfig().merged({"steering": {"delay_s": 0.05, "lag_tau_s": 0.1}})
    step = np.where(np.arange(int(2 * FS)) >= FS / 2, 1.5, 0.0)  # steering wheel step at 0.5 s
    delta_f = front_wheel_angle(step, FS, 15.0, config.steering)
    t = np.arange(len(step)) / FS
    expected = np.where(t >= 0.55, 0.1 * (1 - np.exp(-(t - 0.55) / 0.1)), 0.0)
    np.testing.assert_allclose(
        delta_f, expected, atol=0.02 * 0.1
    )  # a sampled step is not linear in between


def test_sensor_noise_and_bias_match_the_config():
    config = short_config()
    record = simulate_record(config, "train_1")
    error = record.columns["yaw_rate"] - record.truth.yaw_rate
    assert np.mean(error) == pytest.approx(config.sensors.yaw_rate.bias, abs=1e-4)
    assert np.std(error) == pytest.approx(config.sensors.yaw_rate.noise_std, rel=0.05)
    noisefree = simulate_record(short_config({"sensors": {"noise_scale": 0.0}}), "train_1")
    bias = config.sensors.lateral_acceleration.bias
    np.testing.assert_allclose(
        noisefree.columns["lateral_acceleration"], noisefree.truth.lateral_acceleration + bias
    )


# --- files and cache -------------------------------------------------------------------


def test_files_hold_the_exact_columns_at_1024_hz(short_dataset):
    config, folder = short_dataset
    for name in config.records:
        table = pq.read_table(folder / f"{name}.parquet")
        assert tuple(table.column_names) == COLUMNS
        columns = read_record(folder / f"{name}.parquet")
        assert all(values.dtype == np.float64 for values in columns.values())
        assert columns["time"][0] == 0.0
        np.testing.assert_array_equal(np.diff(columns["time"]), 1.0 / 1024.0)


def test_dataset_json_segments_cover_every_file(short_dataset):
    config, folder = short_dataset
    description = load_description(folder)
    assert description["config"] == json.loads(json.dumps(config.to_dict()))
    for file, info in description["files"].items():
        segments = info["segments"]
        samples = len(read_record(folder / file)["time"])
        assert segments[0]["start_s"] == 0.0
        assert segments[-1]["end_s"] == pytest.approx(samples / 1024.0)
        for before, after in itertools.pairwise(segments):
            assert before["end_s"] == after["start_s"]
    val = [s["name"] for s in description["files"]["val.parquet"]["segments"]]
    assert val == ["stochastic", "lane_change", "step_steer", "sine_sweep"]
    assert [s["name"] for s in description["files"]["train_1.parquet"]["segments"]] == [
        "stochastic"
    ]


def test_ensure_dataset_is_cached_bit_identical_and_atomic(short_dataset, tmp_path, monkeypatch):
    config, reference = short_dataset
    monkeypatch.setenv("HYPA_CACHE_DIR", str(tmp_path))
    folder = ensure_dataset(config)
    assert folder.parent == tmp_path / "testbench"
    for file in ["dataset.json", *(f"{name}.parquet" for name in config.records)]:
        assert (folder / file).read_bytes() == (reference / file).read_bytes(), file
    assert sorted(p.name for p in folder.parent.iterdir()) == [folder.name]  # no temp left

    def must_not_run(*args, **kwargs):
        raise AssertionError("regenerated a cached dataset")

    monkeypatch.setattr(dataset_module, "generate_dataset", must_not_run)
    assert ensure_dataset(config) == folder
    other = config.merged({"records": {"train_1": {"seed": 11}}})
    with pytest.raises(AssertionError, match="regenerated"):
        ensure_dataset(other, cache_dir=tmp_path / "elsewhere")
    assert not any((tmp_path / "elsewhere").iterdir())  # the failed run left nothing


def test_cli_writes_the_folder_and_prints_a_summary(tmp_path, monkeypatch, capsys):
    overrides = [f"testbench.records.{n}.stochastic_duration_s=5" for n in ("train_1", "train_2")]
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "hypa testbench",
            f"out={tmp_path / 'data'}",
            f"hydra.run.dir={tmp_path / 'run'}",
            "testbench.records.val.maneuvers=[]",
            "testbench.records.val.stochastic_duration_s=5",
            "plot=true",
            *overrides,
        ],
    )
    monkeypatch.setattr(sys, "argv", [sys.argv[0], "testbench", *sys.argv[1:]])
    with pytest.raises(SystemExit) as ended:
        runpy.run_module("hypa", run_name="__main__")  # as python -m hypa testbench
    assert ended.value.code == 0
    printed = capsys.readouterr().out
    assert "val.parquet" in printed and "train_2.parquet" in printed and "deg" in printed
    assert (tmp_path / "data" / "dataset.json").is_file()
    assert (tmp_path / "run" / "val_overview.png").stat().st_size > 10_000
    assert math.isclose(
        load_description(tmp_path / "data")["files"]["val.parquet"]["duration_s"], 5
    )


def test_simulate_record_accepts_a_record_config():
    record = simulate_record(
        TestbenchConfig.linear(), RecordConfig(seed=5, stochastic_duration_s=3)
    )
    assert len(record.columns["time"]) == 3 * 1024 and record.segments[0].end_s == 3.0


def test_a_record_removed_on_the_command_line_is_not_generated() -> None:
    """``~testbench.records.train_2`` drops the record (the schema's defaults must not bring it back)."""
    cfg = compose_config("testbench", ["~testbench.records.train_2"])
    assert sorted(TestbenchConfig.from_hydra(cfg.testbench).records) == ["train_1", "val"]
    assert sorted(TestbenchConfig.from_dict(cfg.testbench).records) == ["train_1", "train_2", "val"]  # a partial update
