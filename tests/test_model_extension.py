"""Step 3 of the diagnosis as a hypa model: the config written from named causes.

The diagnosis measures its gain with its own numpy model (``hypa.diagnosis.model``); the model
it writes for ``hypa.train`` must be the same physics. So for every cause that physics can
express, the written YAML, built as a ``ComposedModel`` and free-run over a record, must equal
the numpy model with the same estimates to round-off (both are exact for the hold's input).
"""

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from scipy.signal import lfilter

from hypa.diagnosis.config import describe, extension_model, train_command, write_model
from hypa.diagnosis.extension import apply_cause
from hypa.diagnosis.model import ModelSpec, simulate_batch
from hypa.models import ComposedModel, ModelSpecError, parse_model_spec
from hypa.vehicle import VehicleParameters

DT, VEHICLE = 1 / 32, VehicleParameters()
STATE_SCALE = {"yaw_rate": (0.01, 0.1), "side_slip": (0.0, 0.01)}
ESTIMATES = {
    "parameter_mismatch": {"parameter": "cf", "value": 130000.0},
    "input_delay": {"delay_s": 0.047},
    "unmodeled_lag": {"tau_s": 0.08},
    "sensor_offset": {"channel": "side_slip", "offset": 3e-4},
    "unmodeled_input": {"channel": "rear_wheel_angle", "ratio": 0.12, "tau_s": 0.2},
}
GYRO_BIAS = {"cause": "sensor_offset", "estimate": {"channel": "yaw_rate", "offset": 2e-3}}


def steering(length: int = 700, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return lfilter([0.05], [1, -0.95], rng.normal(size=length)) * 3


def build(config: dict, swa: np.ndarray, hold: str = "zoh", **kw) -> ComposedModel:
    scale = (float(swa.mean()), float(swa.std()))
    return ComposedModel(parse_model_spec(config), VEHICLE.as_dict(), ["steering_wheel_angle"], list(STATE_SCALE),
                         {"steering_wheel_angle": scale}, STATE_SCALE, DT, 100, hold, **kw).double()


def free_run(model: ComposedModel, swa: np.ndarray, x0: np.ndarray) -> np.ndarray:
    mean, std = (np.array([v[i] for v in STATE_SCALE.values()]) for i in (0, 1))
    (u_mean, u_std), = [model.scales["steering_wheel_angle"]]
    u = torch.tensor((swa - u_mean) / u_std)[None, :, None]
    with torch.no_grad():
        return model(u, torch.tensor((x0 - mean) / std)[None])[0].numpy() * std + mean


CASES = [[c] for c in ESTIMATES] + [list(ESTIMATES)]


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("causes", CASES, ids=["+".join(c) for c in CASES])
def test_written_physics_equals_the_diagnosed_model(hold: str, causes: list[str]) -> None:
    rows = [{"cause": c, "estimate": ESTIMATES[c]} for c in causes]
    if "sensor_offset" in causes:
        rows.append(GYRO_BIAS)  # a second biased channel: one row per channel
    spec = ModelSpec(VEHICLE, hold=hold)
    for row in rows:
        spec = apply_cause(spec, row["cause"], row["estimate"])
    swa, x0 = steering(), np.array([0.02, -0.003])
    expected = simulate_batch([spec], swa, x0, DT)[0, 1:]
    config = extension_model(rows, hold, "none", unmodeled_input="physics")
    got = free_run(build(config, swa, hold="zoh" if hold == "foh" else "foh"), swa, x0)  # the model's hold wins
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-11)


def test_written_yaml_round_trips_and_describes_itself(tmp_path: Path) -> None:
    rows = [{"cause": c, "estimate": e} for c, e in ESTIMATES.items()]
    config = extension_model(rows, "foh", "none", unmodeled_input="physics")
    path = write_model(config, tmp_path / "conf", header=["made by a test"])
    assert path == tmp_path / "conf" / "model" / "diagnosed.yaml"
    text = path.read_text()
    assert text.startswith("# @package model\n# made by a test\n")
    assert yaml.safe_load(text) == config
    lines = describe(config)
    assert any("dead_time" in line and "delay_s = 0.047" in line for line in lines)
    assert "sensor offsets side_slip = 0.0003" in lines[-1] and "cf = 130000" in lines[-1]
    command = train_command(tmp_path / "conf", ["dataset=files", "data.dir=/my data"])
    assert command == f"python -m hypa.train --config-dir {tmp_path / 'conf'} model=diagnosed dataset=files 'data.dir=/my data'"


def test_unmodeled_input_becomes_v1_and_saturation_a_v2_correction() -> None:
    rows = [{"cause": "unmodeled_input", "estimate": ESTIMATES["unmodeled_input"]},
            {"cause": "saturation", "estimate": {"mu": 1.1, "ay_threshold": 4.5}}]
    config = extension_model(rows, "foh", "none")
    blocks = config["blocks"]
    assert blocks["rear_steering"]["kind"] == "ann" and blocks["rear_steering"]["outputs"] == ["rear_wheel_angle"]
    assert blocks["correction"]["residual_of"] == ["yaw_rate_physics", "side_slip_physics"]
    assert [s["name"] for s in config["stages"]] == ["physics", "correction"]
    assert config["stages"][0]["bypass"] == ["correction"]
    torch.manual_seed(0)
    swa, x0 = steering(300), np.array([0.0, 0.0])
    model = build(config, swa, ann_name="lstm", ann_hparams={"hidden_size": 4})
    nominal = simulate_batch([ModelSpec(VEHICLE, hold="foh")], swa, x0, DT)[0, 1:]
    np.testing.assert_allclose(free_run(model, swa, x0), nominal, atol=1e-12)  # zero-initialized networks


def test_causes_without_parameters_still_train_something() -> None:
    """Offsets and the hold are fixed values: the single track's cf, cr, izz are re-fitted."""
    for rows in ([], [{"cause": "none", "estimate": {}}], [{"cause": "discretization", "estimate": {"hold": "foh"}}]):
        config = extension_model(rows, "zoh", "fixed")
        assert config["blocks"]["single_track"]["trainable"] == ["cf", "cr", "izz"]
        assert config["blocks"]["rear_steering"]["system"] == "rear_steering"
    assert extension_model(rows, "zoh", "none")["hold"] == "foh"


@pytest.mark.parametrize("edit, message", [
    (lambda c: c.update(frobnicate=1), "unknown keys"),
    (lambda c: c.update(hold="cubic"), "hold must be one of"),
    (lambda c: c.update(parameters={"nonsense": 1.0}), "read by no block"),
    (lambda c: c.update(parameters={"cf": "stiff"}), "must be a number"),
    (lambda c: c.update(sensor_offsets={"lateral_acceleration": 0.1}), "not measured signals"),
    (lambda c: c["blocks"]["dead_time"].pop("parameters"), "needs parameters: {delay_s"),
    (lambda c: c["blocks"]["dead_time"].update(trainable=["tau_s"]), "not parameters of delay"),
    (lambda c: c["blocks"]["steering_lag"].update(parameters={"delay_s": 0.1}), "not its own"),
    (lambda c: c["blocks"]["steering_lag"].update(parameters={"tau_s": -0.1}), "must be positive"),
])
def test_bad_extension_configs_fail_clearly(edit, message: str) -> None:
    rows = [{"cause": c, "estimate": ESTIMATES[c]} for c in ("input_delay", "unmodeled_lag")]
    config = extension_model(rows, "foh", "none")
    edit(config)
    with pytest.raises((ModelSpecError, ValueError), match=message):
        build(config, steering(200))
