"""ASAM MDF files as measured data: channels by name on time bases of their own, units from the
file, resampled onto one time base (anti-aliased where a channel is faster), and trained on
through ``hypa train dataset=files``.

The files are written with asammdf from systems whose responses are known in closed form (the
steady state of a mass-spring-damper and of a first-order yaw response to sums of sines), so
every value read can be checked against the truth at any time stamp."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

asammdf = pytest.importorskip("asammdf")

from hypa.data import ChannelSpec, DataError, decimate, find_split_files, load_record  # noqa: E402 -- after the importorskip
from hypa.data.decimation import lowpass  # noqa: E402 -- after the importorskip
from hypa.data.mdf import read_signals  # noqa: E402 -- after the importorskip

from cli_helpers import hypa_run  # noqa: E402 -- after the importorskip
from conftest import compose_config  # noqa: E402 -- after the importorskip

DEG = math.pi / 180.0

# mass-spring-damper m x'' + c x' + k x = F: natural frequency 3.2 Hz, damping ratio 0.1
MASS, DAMPING, STIFFNESS = 1.5, 6.0, 600.0  # [kg], [N s/m], [N/m]
FORCE_TONES = ((0.4, 20.0, 0.3), (1.1, 20.0, 1.9), (2.3, 15.0, 4.0), (3.0, 10.0, 2.2))  # Hz, N, rad


def _tones(t: np.ndarray, tones, response=lambda w: 1.0) -> np.ndarray:
    """Steady state of a linear system with frequency response ``response(jw)`` to a sum of
    sines ``(frequency [Hz], amplitude, phase [rad])``."""
    out = np.zeros_like(t, dtype=np.float64)
    for f, amplitude, phase in tones:
        w = 2 * np.pi * f
        h = complex(response(1j * w))
        out += abs(h) * amplitude * np.sin(w * t + phase + np.angle(h))
    return out


def force(t):  # [N]
    return _tones(t, FORCE_TONES)


def position(t):  # [m]
    return _tones(t, FORCE_TONES, lambda s: 1 / (MASS * s**2 + DAMPING * s + STIFFNESS))


def velocity(t):  # [m/s]
    return _tones(t, FORCE_TONES, lambda s: s / (MASS * s**2 + DAMPING * s + STIFFNESS))


def write_mdf(path: Path, groups: list[tuple[np.ndarray, dict[str, tuple[np.ndarray, str]]]],
              version: str = "4.10") -> Path:
    """One MDF group (its own time base) per ``(time, {name: (values, unit)})``."""
    mdf = asammdf.MDF(version=version)
    for time, signals in groups:
        mdf.append([asammdf.Signal(np.asarray(values, dtype=np.float64), time, name=name, unit=unit)
                    for name, (values, unit) in signals.items()])
    saved = Path(mdf.save(path, overwrite=True))
    mdf.close()
    return saved


def _jittered(start: float, rate_hz: float, duration_s: float, seed: int) -> np.ndarray:
    """Time stamps at about ``rate_hz``, each off its nominal instant by up to 20 % of a step."""
    n = int(duration_s * rate_hz)
    jitter = np.random.default_rng(seed).uniform(-0.2, 0.2, n)
    return start + (np.arange(n) + jitter) / rate_hz


# The mass-spring-damper's logger: force at 200 Hz, position at 1 kHz, velocity and a ramp at a
# jittered 100 Hz starting 13.7 ms late, each in a unit of its own.
T_FORCE = np.arange(2000) / 200.0
T_POSITION = np.arange(10000) / 1000.0
T_SLOW = _jittered(0.0137, 100.0, 9.95, seed=1)
MSD_CHANNELS = [
    ChannelSpec("force", "input", "N", column="Force"),  # the file says kN: the file wins
    ChannelSpec("position", "output", "m", column="Position"),  # the file says mm
    ChannelSpec("velocity", "output", "mm/s", column="Velocity"),
    ChannelSpec("ramp", "auxiliary", "deg", column="Ramp"),
    ChannelSpec("power", "auxiliary", "W", expression="Force * Velocity"),  # kN * mm/s = W
]


def _msd_file(path: Path, version: str = "4.10") -> Path:
    return write_mdf(path, [
        (T_FORCE, {"Force": (force(T_FORCE) / 1e3, "kN")}),
        (T_POSITION, {"Position": (position(T_POSITION) * 1e3, "mm")}),
        (T_SLOW, {"Velocity": (velocity(T_SLOW) * 1e3, "mm/s"), "Ramp": (10 + 30 * T_SLOW, "deg")}),
    ], version)


@pytest.fixture(scope="module")
def msd_file(tmp_path_factory) -> Path:
    return _msd_file(tmp_path_factory.mktemp("mdf") / "train.mf4")


def test_channels_at_three_rates_are_read_onto_one_time_base_in_si(msd_file: Path) -> None:
    record = load_record(msd_file, MSD_CHANNELS, sample_rate_hz=200.0)
    start, stop = T_SLOW[0], T_SLOW[-1]  # the span all channels cover (file time)
    n = math.floor((stop - start) * 200.0) + 1
    assert record.sample_rate_hz == 200.0 and len(record) == n
    np.testing.assert_array_equal(record.time, np.arange(n) / 200.0)
    t = start + record.time  # the file's time stamps of the record's samples
    assert record.names == ("force", "position", "velocity", "ramp", "power")
    # the jittered ramp is linear in the file's time stamps: interpolation is exact, and only
    # right if the stamps are the file's (an assumed regular 100 Hz is off by up to 2 ms * 30 deg/s)
    np.testing.assert_allclose(record["ramp"], (10 + 30 * t) * DEG, rtol=0, atol=1e-12)
    # slower or as fast: linear interpolation of the file's samples, converted to SI
    expected = np.interp(t, T_SLOW, velocity(T_SLOW) * 1e3) * 1e-3
    np.testing.assert_allclose(record["velocity"], expected, rtol=0, atol=1e-12)
    expected = np.interp(t, T_FORCE, force(T_FORCE) / 1e3) * 1e3
    np.testing.assert_allclose(record["force"], expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(record["power"], record["force"] * record["velocity"], rtol=1e-12)
    # and all of them close to the system's truth (linear interpolation between 100 Hz samples of
    # a 3 Hz resonance: 0.7 % at most)
    for name, truth, tolerance in (("force", force, 1e-3), ("velocity", velocity, 1e-2)):
        scale = np.abs(truth(t)).max()
        assert np.abs(record[name] - truth(t)).max() < tolerance * scale, name
    # position, 1 kHz -> 200 Hz, anti-aliased: its pass band (to 62.5 Hz) keeps it within 0.1 %
    scale = np.abs(position(t)).max()
    np.testing.assert_allclose(record["position"], position(t), rtol=0, atol=1e-3 * scale)


def test_without_a_rate_the_fastest_channel_sets_it_and_mdf3_reads_the_same(
        msd_file: Path, tmp_path: Path) -> None:
    record = load_record(msd_file, MSD_CHANNELS, sample_rate_hz=None)
    assert record.sample_rate_hz == pytest.approx(1000.0, rel=1e-9)
    t = T_SLOW[0] + record.time
    np.testing.assert_allclose(record["ramp"], (10 + 30 * t) * DEG, rtol=0, atol=1e-12)
    # position is read at its own rate: its samples interpolated, nothing filtered
    expected = np.interp(t, T_POSITION, position(T_POSITION))
    np.testing.assert_allclose(record["position"], expected, rtol=0, atol=1e-12)
    mdf3 = _msd_file(tmp_path / "train.mdf", version="3.30")
    assert mdf3.suffix == ".mdf"
    again = load_record(mdf3, MSD_CHANNELS, sample_rate_hz=200.0)
    reference = load_record(msd_file, MSD_CHANNELS, sample_rate_hz=200.0)
    for name in reference.names:
        np.testing.assert_allclose(again[name], reference[name], rtol=1e-6, atol=1e-12)


def test_a_tone_above_the_new_nyquist_frequency_is_removed(tmp_path: Path) -> None:
    """1 kHz -> 256 Hz (not an integer ratio): a 180 Hz tone would alias to 76 Hz."""
    time = np.arange(5000) / 1000.0
    wanted = np.sin(2 * np.pi * 3.0 * time)
    path = write_mdf(tmp_path / "tone.mf4", [
        (time, {"x": (wanted + np.sin(2 * np.pi * 180.0 * time + 0.4), "V")}),
        (time[::4], {"u": (np.zeros(time[::4].size), "V")}),  # a second, slower group
    ])
    channels = [ChannelSpec("u", "input", "V"), ChannelSpec("x", "output", "V")]
    record = load_record(path, channels, sample_rate_hz=256.0)
    t = record.time
    inner = (t > 0.3) & (t < t[-1] - 0.3)  # the ends: point-reflected, not exact for a sine
    error = record["x"] - np.sin(2 * np.pi * 3.0 * t)
    assert np.abs(error[inner]).max() < 2e-3  # the tone at -60 dB, the 3 Hz sine kept
    naive = np.interp(t, time, wanted + np.sin(2 * np.pi * 180.0 * time + 0.4))
    assert np.abs(naive - np.sin(2 * np.pi * 3.0 * t)).max() > 0.5  # what plain interpolation does


def test_lowpass_at_an_integer_ratio_is_the_decimation_filter() -> None:
    x = np.random.default_rng(0).standard_normal(3000)
    for q in (2, 5, 32):
        np.testing.assert_allclose(lowpass(x, q)[::q], decimate(x, q), rtol=0, atol=1e-12)


# -- errors ----------------------------------------------------------------------------------

def _one_group(path: Path, signals: dict[str, tuple[np.ndarray, str]], time=None) -> Path:
    time = np.arange(200) / 100.0 if time is None else time
    return write_mdf(path, [(time, {n: (np.broadcast_to(v, time.shape), u)
                                    for n, (v, u) in signals.items()})])


def test_a_unit_hypa_does_not_know_names_channel_and_unit(tmp_path: Path) -> None:
    path = _one_group(tmp_path / "a.mf4", {"u": (1.0, "V"), "Travel": (2.0, "furlongz")})
    channels = [ChannelSpec("u", "input", "V"), ChannelSpec("travel", "output", "m", column="Travel")]
    with pytest.raises(DataError, match=r"'Travel' \(channel 'travel'\) is in 'furlongz'"):
        load_record(path, channels)
    # the way out the message names: an expression takes the declared unit
    declared = [channels[0], ChannelSpec("travel", "output", "m", expression="Travel")]
    np.testing.assert_array_equal(load_record(path, declared, sample_rate_hz=100.0)["travel"], 2.0)


def test_a_file_unit_of_another_quantity_names_both(tmp_path: Path) -> None:
    path = _one_group(tmp_path / "a.mf4", {"u": (1.0, "V"), "angle": (2.0, "mm")})
    channels = [ChannelSpec("u", "input", "V"), ChannelSpec("angle", "output", "rad")]
    with pytest.raises(DataError, match=r"'mm' \(length\) in the file, but declared in 'rad' \(angle\)"):
        load_record(path, channels)


def test_a_channel_without_a_unit_in_the_file_takes_the_declared_one(tmp_path: Path) -> None:
    path = _one_group(tmp_path / "a.mf4", {"u": (1.0, ""), "angle": (90.0, "")})
    channels = [ChannelSpec("u", "input", "V"), ChannelSpec("angle", "output", "deg")]
    record = load_record(path, channels, sample_rate_hz=100.0)
    np.testing.assert_allclose(record["angle"], np.pi / 2, rtol=1e-15)


def test_a_missing_channel_is_named_with_what_the_file_has(tmp_path: Path) -> None:
    signals = {f"Signal_{i:02d}": (float(i), "V") for i in range(20)}
    path = _one_group(tmp_path / "a.mf4", {"YawRate": (0.1, "deg/s"), **signals})
    channels = [ChannelSpec("u", "input", "V", column="Signal_01"),
                ChannelSpec("yaw_rate", "output", "rad/s", column="Yaw_Rate")]
    with pytest.raises(DataError) as error:
        load_record(path, channels)
    message = str(error.value)
    assert "'Yaw_Rate' for 'yaw_rate'" in message and "did you mean 'YawRate'?" in message
    assert "it has 21 channel(s): YawRate, Signal_00," in message and "(9 more)" in message
    assert "data.channels.yaw_rate.column" in message
    # an evaluation channel the file lacks is left out, as with every other file type
    optional = [channels[0], ChannelSpec("yaw_rate", "output", "deg/s", column="YawRate"),
                ChannelSpec("truth", "evaluation", "rad", column="Truth")]
    assert load_record(path, optional, sample_rate_hz=100.0).names == ("u", "yaw_rate")


def test_an_ambiguous_name_and_a_gap_are_errors(tmp_path: Path) -> None:
    time = np.arange(100) / 100.0
    path = write_mdf(tmp_path / "twice.mf4", [(time, {"u": (time, "V")}), (time, {"u": (time, "V")})])
    with pytest.raises(DataError, match=r"'u' is in 2 groups \(0, 1\)"):
        read_signals(path, ["u"])
    gap = np.concatenate([time, 2.0 + time])  # one second without samples
    path = _one_group(tmp_path / "gap.mf4", {"u": (1.0, "V"), "y": (2.0, "V")}, time=gap)
    with pytest.raises(DataError, match=r"'u' \(group 0\): a gap of 1010 ms after 0.99 s"):
        load_record(path, [ChannelSpec("u", "input", "V"), ChannelSpec("y", "output", "V")])


def test_without_asammdf_the_error_says_what_to_install(tmp_path: Path, monkeypatch) -> None:
    path = _one_group(tmp_path / "a.mf4", {"u": (1.0, "V"), "y": (2.0, "V")})
    monkeypatch.setitem(sys.modules, "asammdf", None)  # import asammdf raises ImportError
    with pytest.raises(DataError, match=r"pip install 'hypa\[mdf\]'"):
        load_record(path, [ChannelSpec("u", "input", "V"), ChannelSpec("y", "output", "V")])


# -- a data folder of MDF files through the command line -------------------------------------

# A vehicle logger: steering wheel angle [deg] at 200 Hz, yaw rate [°/s] and side slip [deg] on
# the CAN bus at 100 Hz. Yaw rate and side slip are first-order responses to the steering.
STEERING_TONES = ((0.15, 40.0, 0.0), (0.4, 30.0, 1.0), (0.9, 20.0, 2.0), (1.6, 10.0, 0.5))  # deg


def _yaw_rate_deg(t):  # [deg/s] 0.4 1/s gain, 0.15 s lag
    return _tones(t, STEERING_TONES, lambda s: 0.4 / (0.15 * s + 1))


def _side_slip_deg(t):  # [deg]
    return _tones(t, STEERING_TONES, lambda s: -0.02 / (0.3 * s + 1))


def _vehicle_folder(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, seconds, offset in (("train", 20.0, 0.0), ("val", 10.0, 100.0)):
        fast = offset + np.arange(int(seconds * 200)) / 200.0  # an offset: a logger's clock
        slow = offset + 0.003 + np.arange(int(seconds * 100)) / 100.0
        write_mdf(folder / f"{name}.mf4", [
            (fast, {"SteeringWheelAngle": (_tones(fast, STEERING_TONES), "deg")}),
            (slow, {"YawRate": (_yaw_rate_deg(slow), "°/s"), "SideSlip": (_side_slip_deg(slow), "deg")}),
        ])
    return folder


# "+": files.yaml declares no column (it defaults to the channel's name), so the key is added
FILES_OVERRIDES = ["dataset=files", "+data.channels.steering_wheel_angle.column=SteeringWheelAngle",
                   "+data.channels.yaw_rate.column=YawRate", "+data.channels.side_slip.column=SideSlip"]


def test_dataset_files_reads_an_mdf_folder_in_si_at_the_model_rate(tmp_path: Path) -> None:
    """``conf/dataset/files.yaml`` as it is (units declared in rad, files at 1024 Hz, model at
    32 Hz) on MDF files in deg and °/s at 200 and 100 Hz: read in SI, resampled, decimated."""
    from hypa.data import datamodule_from_config

    folder = _vehicle_folder(tmp_path / "mdf")
    assert {s: [p.name for p in f] for s, f in find_split_files(folder).items()} == {
        "train": ["train.mf4"], "val": ["val.mf4"]}
    cfg = compose_config("train", [*FILES_OVERRIDES, f"data.dir={folder}"])
    dm = datamodule_from_config(cfg.data, folder)
    dm.setup()
    record = dm.records("val")[0]
    assert record.sample_rate_hz == 32.0 and dm.dt == 1 / 32
    t = 100.003 + record.time  # the val file's common span starts with its 100 Hz group
    inner = (record.time > 1.0) & (record.time < record.time[-1] - 1.0)  # decimation's ends
    for name, truth, scale in (("steering_wheel_angle", _tones, 100.0),
                               ("yaw_rate", _yaw_rate_deg, 40.0), ("side_slip", _side_slip_deg, 2.0)):
        args = (t, STEERING_TONES) if truth is _tones else (t,)
        error = record[name][inner] - truth(*args)[inner] * DEG
        assert np.abs(error).max() < 2e-3 * scale * DEG, name


def _train(folder: Path, run: Path, *overrides: str) -> subprocess.CompletedProcess:
    return hypa_run(["train", *FILES_OVERRIDES, f"data.dir={folder}", "model=blackbox", "ann=lstm",
                     "ann.hidden_size=8", "trainer.max_epochs=1", "trainer.enable_progress_bar=false",
                     "figures.enabled=false", *overrides, f"hydra.run.dir={run}"])


def test_train_on_an_mdf_folder_through_the_command_line(tmp_path: Path) -> None:
    result = _train(_vehicle_folder(tmp_path / "mdf"), tmp_path / "run")
    assert result.returncode == 0, result.stderr[-3000:]
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert math.isfinite(info["best_val_loss"])

