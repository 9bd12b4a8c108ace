"""The vehicle through the one diagnosis engine: ``hypa diagnose model=vehicle_nominal``.

The test bench hides effects (one at a time, or two at once) in data of a nonlinear truth with
its own ECU and tire models; the nominal model is the linear front-steered single track. The
generic catalogue plus the vehicle's entries (``hypa/vehicle/catalogue.yaml``) must name them,
with estimates, and name no proxy (a dead time for a tire relaxation).
"""

from __future__ import annotations

import json
import math
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from hypa.physics import LTIBlock, PhysicalParameters
from hypa.vehicle import SingleTrack, SingleTrackRelaxation

from cli_helpers import hypa_run
from conftest import ROOT

SHORT = [f"testbench.records.{name}.stochastic_duration_s={d}" for name, d in
         (("train_1", 40), ("train_2", 40), ("val", 30))] + ["testbench.records.val.maneuvers=[]"]
LINEAR = ["testbench.tires.enabled=false", "testbench.relaxation.enabled=false",
          "testbench.load_transfer.enabled=false", "testbench.rear_steering.transient_ratio=0",
          "testbench.rear_steering.enabled=false", "testbench.sensors.bias_scale=0"]


def diagnose(tmp_path: Path, *overrides: str) -> dict:
    env = {**os.environ, "HYPA_CACHE_DIR": str(tmp_path / "cache")}
    result = hypa_run(["diagnose", "model=vehicle_nominal", "plot=false", f"hydra.run.dir={tmp_path / 'run'}", *SHORT,
                       *overrides], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads((tmp_path / "run" / "diagnosis.json").read_text())


def named(result: dict) -> dict[str, dict]:
    return {f"{n['cause']}:{n['target']}": n for n in result["named"]}


def test_relaxation_tends_to_the_single_track_as_the_length_vanishes() -> None:
    """σ → 0: the relaxed slip follows the kinematic one at once, the single track exactly."""
    values = {**SingleTrack().nominal_values(), "relaxation_length": 1e-3}
    u = torch.sin(torch.linspace(0, 20, 400, dtype=torch.float64))[None, :, None] * 0.02
    plain = LTIBlock(SingleTrack(rear_steering=False), PhysicalParameters(
        SingleTrack(rear_steering=False).parameter_specs(values)), dt=1 / 32, horizon=400, hold="foh")
    relaxed = LTIBlock(SingleTrackRelaxation(rear_steering=False), PhysicalParameters(
        SingleTrackRelaxation(rear_steering=False).parameter_specs(values)), dt=1 / 32, horizon=400, hold="foh")
    with torch.no_grad():  # the states (physical units: identity scaling) over the same FOH input
        y_plain = plain.states(torch.zeros(1, 2, dtype=torch.float64), u)
        y_relaxed = relaxed.states(torch.zeros(1, 4, dtype=torch.float64), u)[..., :2]
    assert torch.allclose(y_relaxed, y_plain, atol=2e-3 * float(y_plain.abs().max()))


def test_rear_steering_is_named_with_its_ratio_and_lag(tmp_path: Path) -> None:
    """The ECU's ratio at 33.3 m/s is 0.12 (plus a yaw-rate term), its actuator lag 70 ms.
    One round (later rounds fit the nonlinear saturation candidates jointly: minutes).

    The nominal cf and cr are identified first, and the rear-steering path re-fits them: the
    ECU's yaw-rate term, which no catalogue path expresses, then goes partly into cr (a rear
    steer proportional to the yaw rate changes the rear slip as a stiffer or softer rear axle
    would), and the ratio comes out lower than 0.12 where cr is named beside it."""
    result = diagnose(tmp_path, *LINEAR, "testbench.rear_steering.enabled=true", "diagnosis.max_causes=1")
    first = result["named"][0]
    assert (first["cause"], first["target"]) == ("unmodeled_input", "single_track"), result["named"]
    rear_axle = any(n["cause"] == "parameter_mismatch" and n["target"] == "cr" for n in result["named"])
    assert first["values"]["diagnosed_rear_steering/gain"] == pytest.approx(0.12, rel=0.5 if rear_axle else 0.25), \
        result["named"]
    assert first["values"]["diagnosed_rear_steering/tau_s"] == pytest.approx(0.07, rel=0.5)
    assert result["score"]["extended"] < 0.1 * result["score"]["nominal"]
    # the rear steering as a network inside the diagnosed physics, every physical value frozen
    learned = yaml.safe_load(Path(result["extended"]["config"]["diagnosed_learned"]).read_text())
    block = learned["blocks"]["diagnosed_rear_steering"]
    assert block["kind"] == "ann" and block["inputs"] == ["front_wheel_angle"]
    assert block["outputs"] == ["diagnosed_rear_wheel_angle"] and block["scale_as"] == ["front_wheel_angle"]
    assert all(not b.get("trainable") for b in learned["blocks"].values())
    assert learned["blocks"]["single_track"]["system"] == "single_track" and learned["hold"] == "foh"
    assert "diagnosed_learned.yaml" in result["extended"]["train_command"]["diagnosed_learned"]


def test_tire_relaxation_is_named_and_no_dead_time_stands_in(tmp_path: Path) -> None:
    """Relaxation beats the dead time and the lag that stood in for it (one round, as above)."""
    result = diagnose(tmp_path, *LINEAR, "testbench.relaxation.enabled=true", "diagnosis.max_causes=1")
    causes = [n["cause"] for n in result["named"]]
    assert causes == ["tire_relaxation"], result["named"]
    # a rival not fitted (its first step promises nothing over the model as it was) has no gain: -inf
    gains = {f["cause"]: -math.inf if f["gain"] is None else f["gain"] for f in result["rounds"][0]}
    assert gains["tire_relaxation"] > max(gains["input_delay"], gains["input_lag"])
    length = result["named"][0]["values"]["relaxation_length"]
    assert 0.4 < length < 1.0  # the truth's 0.7 m front, 0.6 m rear, as one length
    # the relaxed slips are two more states than the measured outputs determine at the window
    # start (data.past=0): the written train command raises data.past, and it trains
    command = result["extended"]["train_command"]["diagnosed"]
    assert "data.past=7" in shlex.split(command), command
    env = {**os.environ, "HYPA_CACHE_DIR": str(tmp_path / "cache")}
    arguments = [*shlex.split(command)[4:], f"hydra.run.dir={tmp_path / 'trained'}", "trainer.max_epochs=1",
                 "trainer.limit_train_batches=2", "trainer.limit_val_batches=2", "trainer.enable_progress_bar=false",
                 "figures.enabled=false"]
    trained = hypa_run(["train", *arguments], env=env)
    assert trained.returncode == 0, trained.stderr[-3000:]


def test_saturating_tires_are_named_with_their_friction(tmp_path: Path) -> None:
    result = diagnose(tmp_path, *LINEAR, "testbench.tires.enabled=true", "testbench.tires.mu=0.85",
                      "diagnosis.max_causes=1")  # one round: every later candidate carries the nonlinear fit
    first = result["named"][0]
    assert first["cause"] == "tire_saturation", result["named"]
    assert first["values"]["mu"] == pytest.approx(0.85, rel=0.1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(4))
def test_rear_steering_and_saturating_tires_at_once_are_both_named(tmp_path: Path, seed: int) -> None:
    """The issue's first two-cause case: rear steering at a ratio of 0.15-0.3 with tires at μ 0.8-0.9."""
    rng = np.random.default_rng(20 + seed)
    strength, mu = rng.uniform(0.15, 0.3) / 0.12, rng.uniform(0.8, 0.9)
    result = diagnose(tmp_path, *LINEAR, "testbench.rear_steering.enabled=true", "testbench.tires.enabled=true",
                      f"testbench.rear_steering.strength={strength:.3f}", f"testbench.tires.mu={mu:.3f}")
    found = {n["cause"]: n for n in result["named"]}
    assert {"unmodeled_input", "tire_saturation"} <= set(found), result["named"]
    # judged on all records, a cornering-stiffness refit after the saturation can lower the error
    # further (hypa's saturation curve is not the bench's tire): μ, fitted with it, trades against it
    refits = [n for n in result["named"] if n["cause"] == "parameter_mismatch" and n["target"] in ("cf", "cr")]
    assert found["tire_saturation"]["values"]["mu"] == pytest.approx(mu, rel=0.25 if refits else 0.15)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(4))
def test_delay_and_yaw_rate_bias_at_once_are_both_named(tmp_path: Path, seed: int) -> None:
    """The issue's second two-cause case: a 60-120 ms delay with a 0.01-0.02 rad/s gyro bias."""
    rng = np.random.default_rng(seed)
    delay, bias = rng.uniform(0.06, 0.12), rng.uniform(0.01, 0.02) * rng.choice([-1, 1])
    result = diagnose(tmp_path, *LINEAR, "testbench.sensors.bias_scale=1",
                      f"testbench.steering.delay_s={delay:.4f}", f"testbench.sensors.yaw_rate.bias={bias:.5f}",
                      "testbench.sensors.side_slip.bias=0", "testbench.sensors.lateral_acceleration.bias=0")
    found = named(result)
    assert "input_delay:steering_wheel_angle" in found, result["named"]
    assert found["input_delay:steering_wheel_angle"]["values"][
        "diagnosed_delay_steering_wheel_angle/delay_s"] == pytest.approx(delay, rel=0.15)
    assert "output_offset:yaw_rate" in found, result["named"]
    assert found["output_offset:yaw_rate"]["values"]["yaw_rate"] == pytest.approx(bias, rel=0.2)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(4))
def test_rear_steering_at_random_strength_is_named(tmp_path: Path, seed: int) -> None:
    strength = np.random.default_rng(10 + seed).uniform(0.6, 1.6)
    result = diagnose(tmp_path, *LINEAR, "testbench.rear_steering.enabled=true",
                      f"testbench.rear_steering.strength={strength:.3f}")
    first = result["named"][0]
    assert first["cause"] == "unmodeled_input", result["named"]
    assert first["values"]["diagnosed_rear_steering/gain"] == pytest.approx(0.12 * strength, rel=0.3)


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow), pytest.param(2, marks=pytest.mark.slow),
                                  pytest.param(3, marks=pytest.mark.slow)])
def test_sensor_biases_of_the_default_benchs_size_are_named(tmp_path: Path, seed: int) -> None:
    """Gyro and side-slip biases of the default bench's size (0.05-0.15 deg/s, 0.01-0.03 deg) are
    named with their estimates (on linear data they are large causes; next to the default bench's
    bigger effects they are small ones, see the default-bench test). Measured states
    start every stretch, so a steering offset gives the same constant output offsets as a pair of
    sensor biases: where one is named in place of a bias, the report must say that the data
    cannot tell the two apart."""
    rng = np.random.default_rng(40 + seed)
    yaw, slip = (rng.uniform(lo, hi) * rng.choice([-1, 1]) for lo, hi in ((0.0009, 0.0026), (0.00017, 0.0005)))
    result = diagnose(tmp_path, *LINEAR, "testbench.sensors.bias_scale=1", f"testbench.sensors.yaw_rate.bias={yaw:.6f}",
                      f"testbench.sensors.side_slip.bias={slip:.6f}", "testbench.sensors.lateral_acceleration.bias=0")
    found = named(result)
    assert set(found) <= {"output_offset:yaw_rate", "output_offset:side_slip", "input_offset:steering_wheel_angle"}
    assert all(n["z"] >= 5 for n in found.values()), result["named"]
    for channel in ("yaw_rate", "side_slip"):
        key = f"output_offset:{channel}"
        told = key in found or any(f"output_offset on {channel}" in a
                                   for n in found.values() for a in n["alternatives"])
        assert told, result["named"]
    if set(found) == {"output_offset:yaw_rate", "output_offset:side_slip"}:
        assert found["output_offset:yaw_rate"]["values"]["yaw_rate"] == pytest.approx(yaw, rel=0.2)
        assert found["output_offset:side_slip"]["values"]["side_slip"] == pytest.approx(slip, rel=0.3)


def test_clean_data_names_nothing(tmp_path: Path) -> None:
    """The linear truth the nominal model describes, with sensor noise and no bias: nothing to name."""
    result = diagnose(tmp_path, *LINEAR)
    assert result["causes"] == [], result["named"]
    assert result["cause"] == "none"


@pytest.mark.slow
def test_the_default_bench_names_every_effect_and_no_proxy(tmp_path: Path) -> None:
    """The default test bench (conf/testbench/default.yaml, full length): rear steering with its
    phase reversal, tire relaxation, saturation and both sensor biases; no dead time or lag."""
    env = {**os.environ, "HYPA_CACHE_DIR": str(tmp_path / "cache")}
    result = subprocess.run([sys.executable, "-m", "hypa", "diagnose",
                             "plot=false", f"hydra.run.dir={tmp_path / 'run'}"],
                            cwd=ROOT, env=env, capture_output=True, text=True, timeout=900, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    found = named(json.loads((tmp_path / "run" / "diagnosis.json").read_text()))
    assert {"unmodeled_input:single_track", "tire_relaxation:single_track", "tire_saturation:single_track",
            "output_offset:yaw_rate", "output_offset:side_slip"} <= set(found), list(found)
    assert not {"input_delay:steering_wheel_angle", "input_lag:steering_wheel_angle"} & set(found), list(found)
    assert found["output_offset:yaw_rate"]["values"]["yaw_rate"] == pytest.approx(0.0017, rel=0.2)
    assert found["output_offset:side_slip"]["values"]["side_slip"] == pytest.approx(0.00035, rel=0.3)
    assert found["tire_relaxation:single_track"]["values"]["relaxation_length"] == pytest.approx(0.6, rel=0.3)
