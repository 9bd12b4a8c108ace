"""Compositions from YAML: wiring, scaling and alignment checked against the physics itself."""


import numpy as np
import pytest
import torch
import yaml

from hypa.conf import CONF
from hypa.models import ComposedModel, ModelSpecError, parse_model_spec
from hypa.vehicle import VehicleParameters

from vehicle_reference import simulate_vehicle

MODELS = CONF / "model"
INPUTS, STATES = ("steering_wheel_angle",), ("yaw_rate", "side_slip")
INPUT_SCALE = {"steering_wheel_angle": (0.01, 0.15)}
STATE_SCALE = {"yaw_rate": (0.002, 0.09), "side_slip": (-0.0005, 0.012)}


def load(name: str) -> dict:
    """A shipped model YAML with ``${channels:...}`` resolved for the test bench's channels."""
    roles = {"input": INPUTS, "output": STATES, "scheduling": ()}

    def resolve(node):
        if isinstance(node, dict):
            return {k: resolve(v) for k, v in node.items()}
        if isinstance(node, str) and node.startswith("${channels:"):
            return [n for role in node[len("${channels:"):-1].split(",") for n in roles[role]]
        return node

    return resolve(yaml.safe_load((MODELS / f"{name}.yaml").read_text()))


def build(config: dict, hold: str = "zoh", values: VehicleParameters = VehicleParameters(), **kw) -> ComposedModel:
    return ComposedModel(parse_model_spec(config), values.as_dict(), INPUTS, STATES, INPUT_SCALE, STATE_SCALE,
                         dt=1 / 32, horizon=100, hold=hold, ann_name=kw.pop("ann", "lstm"),
                         ann_hparams=kw.pop("ann_hparams", {"hidden_size": 8}), **kw)


def normalized_window(length: int = 101, batch: int = 3, seed: int = 0):
    rng = np.random.default_rng(seed)
    swa = np.cumsum(rng.normal(size=(batch, length)), axis=1) * 0.01
    x0 = rng.normal(size=(batch, 2)) * np.array([0.05, 0.005])
    u = torch.tensor((swa[..., None] - 0.01) / 0.15, dtype=torch.float64)
    mean = np.array([m for m, _ in STATE_SCALE.values()])
    std = np.array([s for _, s in STATE_SCALE.values()])
    return swa, x0, u, torch.tensor((x0 - mean) / std, dtype=torch.float64), mean, std


@pytest.mark.parametrize("hold", ["zoh", "foh", "cubic"])
@pytest.mark.parametrize("length", [101, 345])
def test_physical_composition_equals_the_physics_chain(hold: str, length: int) -> None:
    """Normalized signals through gains and the single track, de-normalized, equal the SI physics."""
    model = build(load("physical"), hold=hold).double()
    swa, x0, u, x0_hat, mean, std = normalized_window(length)
    with torch.no_grad():
        pred = model(u, x0_hat).numpy() * std + mean
    expected = simulate_vehicle(VehicleParameters(), swa, x0, 1 / 32, hold=hold, rear_steering="fixed")[:, 1:]
    np.testing.assert_allclose(pred, expected, rtol=1e-9, atol=1e-12)


def test_v1_starts_without_rear_steering_and_v2_starts_as_v1() -> None:
    torch.manual_seed(0)
    v1, v2 = build(load("v1")).double(), build(load("v2")).double()
    swa, x0, u, x0_hat, mean, std = normalized_window()
    with torch.no_grad():
        p1, p2 = v1(u, x0_hat), v2(u, x0_hat)
        rear = v1.signals(u, x0_hat)["rear_wheel_angle"][0]
    assert torch.count_nonzero(rear) == 0  # zero-initialized head: δr = 0 rad at start
    torch.testing.assert_close(p1, p2)  # zero-initialized correction: V2 = V1 at start
    expected = simulate_vehicle(VehicleParameters(), swa, x0, 1 / 32, rear_steering="none")[:, 1:]
    np.testing.assert_allclose(p1.numpy() * std + mean, expected, rtol=1e-9, atol=1e-12)


def test_learned_rear_angle_is_physical_through_the_front_angle_scale() -> None:
    model = build(load("v1")).double()
    front_mean, front_std = model.scales["front_wheel_angle"]
    assert model.scales["rear_wheel_angle"] == (0.0, front_std)
    assert front_std == pytest.approx(0.15 / VehicleParameters().steering_ratio)
    assert front_mean == pytest.approx(0.01 / VehicleParameters().steering_ratio)
    value = model.to_physical("rear_wheel_angle", torch.tensor(1.0))
    assert float(value) == pytest.approx(front_std)


def test_stages_freeze_and_bypass() -> None:
    model = build(load("v2"))
    model.set_stage(["rear_steering"], ["correction"])
    assert all(p.requires_grad for p in model.blocks["rear_steering"].parameters())
    assert not any(p.requires_grad for p in model.blocks["correction"].parameters())
    _swa, _x0, u, x0_hat, *_ = normalized_window()
    signals = model.signals(u.float(), x0_hat.float())
    torch.testing.assert_close(signals["yaw_rate"][0], signals["yaw_rate_physics"][0])
    model.set_stage(["correction"])
    assert not any(p.requires_grad for p in model.blocks["rear_steering"].parameters())
    assert all(p.requires_grad for p in model.blocks["correction"].parameters())


def test_physical_model_fits_named_parameters_only() -> None:
    model = build(load("physical"))
    assert set(model.trainable_physics) == {"cf", "cr", "izz", "rws_ratio"}
    assert set(model.parameters_.trainable_names) == {"cf", "cr", "izz", "rws_ratio"}


def test_measured_states_never_enter_as_sequences() -> None:
    config = load("blackbox")
    config["blocks"]["network"]["inputs"] = ["steering_wheel_angle", "yaw_rate"]
    with pytest.raises(ModelSpecError, match="initial states only"):
        build(config)


@pytest.mark.parametrize("edit, message", [
    (lambda c: c["blocks"]["single_track"].update(system="single_trak"), "known: .*single_track"),
    (lambda c: c["blocks"]["single_track"].update(inputs=["front_wheel_angle", "rear_wheel"]), "available signals"),
    (lambda c: c["blocks"]["rear_steering"].update(kind="network"), "kind must be one of"),
    (lambda c: c["blocks"]["single_track"].update(trainable=["stiffness"]), "it has mass"),
    (lambda c: c["blocks"]["rear_steering"].update(scale_like=["x"]), "unknown keys"),
    (lambda c: c.update(outputs=["yaw_rate", "sideslip"]), "written by no block"),
    (lambda c: c.update(stages=[{"name": "a", "train": ["rear_steerin"]}]), "blocks: front_steering"),
])
def test_misspelled_configurations_fail_with_what_exists(edit, message: str) -> None:
    config = load("v1")
    edit(config)
    with pytest.raises(ModelSpecError, match=message):
        build(config)


def test_unstable_nominal_physics_is_refused() -> None:
    from hypa.physics import UnstablePhysicsError

    with pytest.raises(UnstablePhysicsError):
        build(load("physical"), values=VehicleParameters(cr=20000.0, velocity=60.0))


@pytest.mark.parametrize("name", ["v1", "v2", "v3", "physical", "blackbox"])
def test_every_shipped_model_runs_any_length(name: str) -> None:
    model = build(load(name))
    for length in (101, 250):
        _, _, u, x0_hat, *_ = normalized_window(length)
        out = model(u.float(), x0_hat.float())
        assert out.shape == (3, length - 1, 2)
        assert torch.isfinite(out).all()
