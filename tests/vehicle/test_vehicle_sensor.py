"""The side slip where it is measured (``side_slip_at_sensor``): a lever arm from the centre of gravity.

The race car's side slip comes from its localization's v_y, taken at the sensor. A single track
fitted to it without the lever arm ran its rear cornering stiffness to the edge of its search
range; with it, the identification recovers the stiffnesses and the arm on data simulated from a
known truth, and the diagnosis has it in its catalogue.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from hypa.conf import CONF
from hypa.physics import LTIBlock, PhysicalParameters
from hypa.physics.scheduled import batch_decisions
from hypa.vehicle import SideSlipAtSensor

from cli_helpers import hypa_run
from conftest import ROOT, compose_config


def test_the_lever_arm_moves_the_side_slip_by_x_yaw_rate_over_v() -> None:
    """y = β + x ψ̇ / v per sample of a scheduled velocity, the batched matrices equal to vmap's."""
    system = SideSlipAtSensor()
    params = PhysicalParameters(system.parameter_specs({"sensor_x": 0.6, "velocity": 20.0}))
    block = LTIBlock(system, params, dt=0.04, horizon=50, scheduled=("velocity",))
    generator = torch.Generator().manual_seed(0)
    u = torch.randn(3, 50, 2, generator=generator, dtype=torch.float64)  # [ψ̇ (rad/s), β (rad)], identity scaling
    v = 5.0 + 25.0 * torch.rand(3, 50, 1, generator=generator, dtype=torch.float64)
    y = block(None, u, v)
    assert y.shape == (3, 50, 1)
    torch.testing.assert_close(y[..., 0], u[..., 1] + 0.6 * u[..., 0] / v[..., 0], rtol=1e-14, atol=1e-14)
    assert all(batch_decisions(system).values())  # one plain call for all samples, verified against vmap


def test_a_point_ahead_of_the_centre_of_gravity_slips_like_a_rigid_body() -> None:
    """Kinematics: the point x ahead moves sideways at v_y + x ψ̇, so its slip angle is
    atan((v_y + x ψ̇) / v_x); the block's small-angle form agrees to second order."""
    system = SideSlipAtSensor()
    vx, vy, yaw_rate, x = 25.0, 0.2, 0.3, 0.8
    params = PhysicalParameters(system.parameter_specs({"sensor_x": x, "velocity": vx}))
    block = LTIBlock(system, params, dt=0.04, horizon=1)
    beta = math.atan2(vy, vx)
    y = float(block(None, torch.tensor([[[yaw_rate, beta]]], dtype=torch.float64))[0, 0, 0])
    exact = math.atan2(vy + x * yaw_rate, vx)
    assert y == pytest.approx(exact, abs=(abs(exact) ** 3 + abs(beta) ** 3))


@pytest.mark.shared_data("racecar")
def test_stiffnesses_and_lever_arm_are_recovered_from_30_percent_off(monkeypatch) -> None:
    """The race car's measured steering and speed, its outputs simulated by racecar_physical at a
    known truth; identified from 30 % off: every parameter within 2 %, deterministic, no warning."""
    from hypa.data import datamodule_from_config
    from hypa.data.from_config import data_dir_from_config
    from hypa.identification import Stretches, identify
    from hypa.training import HybridModule

    monkeypatch.chdir(ROOT)
    monkeypatch.delenv("HYPA_DATA", raising=False)
    cfg = compose_config("train", ["dataset=racecar", "model=racecar_physical"])
    dm = datamodule_from_config(cfg.data, data_dir_from_config(cfg))
    dm.setup()
    config = OmegaConf.to_container(cfg.model, resolve=True)
    vehicle = {k: float(v) for k, v in OmegaConf.to_container(cfg.vehicle, resolve=True).items()
               if isinstance(v, (int, float))}
    truth = {"cf": 80000.0, "cr": 140000.0, "sensor_x": 0.6}
    start = {"cf": 80000.0 * 1.3, "cr": 140000.0 * 0.7, "sensor_x": 0.6 * 0.7}

    def model_at(values: dict[str, float]):
        return HybridModule.from_data(dm, {**config, "parameters": values}, physical_values=vehicle).model.double()

    measured = Stretches.cut(dm, dm.records("train"), 10**9).to(torch.float64)
    simulated = [p for p, _ in measured.predict(model_at(truth))]  # the truth's free runs
    batches = tuple({**b, "y": torch.cat([b["y"][:, : measured.first], p.to(b["y"].dtype)], 1)}
                    for b, p in zip(measured.batches, simulated))
    data = Stretches(batches, measured.first, measured.positions)
    moved = model_at(start)  # built at other nominal values: the sensor's output keeps the data's scale
    moved.parameters_.set_values(truth)
    assert data.score(moved) < 1e-20
    results = [identify(model_at(start), data) for _ in range(2)]
    found = results[0].values()
    for name, value in truth.items():
        assert found[name] == pytest.approx(value, rel=0.02), (name, found)
    assert results[1].values() == found
    assert results[0].converged and results[0].warnings == ()


DATASET = """\
# @package _global_
defaults:
  - /hypa/data_schema@data
  - override /vehicle: indy_av21
  - _self_
data:
  source: files
  dir: ???
  time: {column: time, unit: s}
  sample_rate_hz: 25.0
  channels:
    steering_angle: {role: input, unit: rad, display_unit: deg}
    yaw_rate: {role: output, unit: rad/s, display_unit: deg/s}
    side_slip: {role: output, unit: rad, display_unit: deg}
    velocity: {role: scheduling, unit: m/s}
  splits:
    train: [{file: car.csv, start: 0.0, stop: 0.7}]
    val: [{file: car.csv, start: 0.7, stop: 1.0}]
  window: 100
  past: 10
  stride: 5
"""
NOMINAL = """\
# @package model
name: car_nominal
blocks:
  single_track:
    kind: physics
    system: single_track_front
    inputs: [steering_angle]
    outputs: [yaw_rate, side_slip]
    scheduling: {velocity: velocity}
outputs: [yaw_rate, side_slip]
stages: []
"""


def _car_log(path: Path, sensor_x: float, seed: int) -> None:
    """600 s at 25 Hz of the race car's single track (indy_av21) at its nominal stiffnesses, its side
    slip taken ``sensor_x`` ahead of the centre of gravity; random steering, speed 8-30 m/s, turning
    mostly one way round (as on a course), 1 % noise on both outputs."""
    import numpy as np
    import yaml

    from hypa.vehicle import SingleTrack

    rng = np.random.default_rng(seed)
    dt, count = 0.04, 15000
    t = np.arange(count) * dt
    steer = 0.01 + np.convolve(rng.standard_normal(count + 50), np.ones(50) / 50, "valid")[:count] * 0.15
    speed = 19 + 8 * np.sin(2 * np.pi * t / 47) + 3 * np.sin(2 * np.pi * t / 13 + 1)
    values = yaml.safe_load((CONF / "vehicle" / "indy_av21.yaml").read_text())
    system = SingleTrack(rear_steering=False)
    block = LTIBlock(system, PhysicalParameters(system.parameter_specs(values)), dt=dt, horizon=count, hold="foh",
                     scheduled=("velocity",))
    with torch.no_grad():
        states = block.simulate_physical(torch.zeros(1, 2, dtype=torch.float64),
                                         torch.tensor(steer, dtype=torch.float64)[None, :, None],
                                         torch.tensor(speed, dtype=torch.float64)[None, :, None])[0].numpy()
    yaw_rate = np.concatenate([[0.0], states[:, 0]])  # x_0 = 0, then x_1 .. x_{N-1} (the hold reads u_{k+1})
    slip = np.concatenate([[0.0], states[:, 1]]) + sensor_x * yaw_rate / speed
    yaw_rate = yaw_rate + 0.01 * yaw_rate.std() * rng.standard_normal(count)
    slip = slip + 0.01 * slip.std() * rng.standard_normal(count)
    table = np.column_stack([t, steer, yaw_rate, slip, speed])
    np.savetxt(path, table, delimiter=",", header="time,steering_angle,yaw_rate,side_slip,velocity", comments="")


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])  # about 12 s each
def test_the_diagnosis_names_a_side_slip_sensor_off_the_centre_of_gravity(tmp_path: Path, seed: int) -> None:
    """A lever arm of random length and sign (0.3-1 m) hidden in a simulated log; the nominal model is
    the scheduled single track at the true stiffnesses. ``hypa diagnose`` names sensor_location
    with its length."""
    import json
    import random

    rng = random.Random(seed)
    sensor_x = rng.choice([-1, 1]) * rng.uniform(0.3, 1.0)
    data, conf = tmp_path / "data", tmp_path / "conf"
    data.mkdir()
    (conf / "dataset").mkdir(parents=True)
    (conf / "model").mkdir()
    (conf / "dataset" / "car.yaml").write_text(DATASET)
    (conf / "model" / "car_nominal.yaml").write_text(NOMINAL)
    _car_log(data / "car.csv", sensor_x, seed)
    result = hypa_run(["diagnose", "--config-dir", str(conf), "dataset=car", "model=car_nominal", f"data.dir={data}",
                       "plot=false", "diagnosis.max_causes=1", f"hydra.run.dir={tmp_path / 'run'}"])
    assert result.returncode == 0, result.stderr[-3000:]
    diagnosis = json.loads((tmp_path / "run" / "diagnosis.json").read_text())
    first = diagnosis["named"][0]
    assert (first["cause"], first["target"]) == ("sensor_location", "single_track"), diagnosis["named"]
    assert first["values"]["sensor_x"] == pytest.approx(sensor_x, rel=0.1), (sensor_x, first["values"])
