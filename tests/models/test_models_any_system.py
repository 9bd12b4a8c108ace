"""Compositions of any system: outputs that are not states, unmeasured initial states estimated
from the past, and physics scheduled per sample by a measured signal, against exact references."""

import numpy as np
import pytest
import scipy.linalg
import torch

from hypa.models import ComposedModel, ModelSpecError, parse_model_spec
from hypa.physics.mass_spring_damper import MassSpringDamper
from hypa.vehicle import SingleTrack, VehicleParameters

DT = 1 / 610.35
MSD = {"mass": 5.1e-6, "stiffness": 0.98, "damping": 2.2e-4, "offset_force": -5.4e-3}


def msd_model(initial_state: str = "estimate", hold: str = "foh", **extra) -> ComposedModel:
    config = {"name": "oscillator", "outputs": ["y"], "hold": hold, "parameters": MSD, "blocks": {
        "oscillator": {"kind": "physics", "system": "mass_spring_damper", "inputs": ["u"], "outputs": ["y"],
                       "initial_state": initial_state, **extra}}}
    return ComposedModel(parse_model_spec(config), {}, ["u"], ["y"], {"u": (0.01, 0.05)}, {"y": (-0.004, 0.06)},
                         dt=DT, horizon=100, ann_hparams={"hidden_size": 4}).double()


def msd_truth(u: np.ndarray, x0: np.ndarray, hold: str) -> np.ndarray:
    """Position of the mass-spring-damper by the exact discretization, one step after another."""
    m, k, d, f0 = (MSD[n] for n in ("mass", "stiffness", "damping", "offset_force"))
    a = np.array([[0, 1], [-k / m, -d / m]])
    b = np.array([[0, 0], [1 / m, 1 / m]])  # inputs (u, the constant F0)
    n = 2
    big = np.zeros((6, 6))
    big[:2, :2], big[:2, 2:4] = a * DT, b * DT
    big[2:4, 4:6] = np.eye(2)  # first-order hold: the input ramps from u_k to u_{k+1}
    e = scipy.linalg.expm(big)
    phi, g1, g2 = e[:n, :n], e[:n, 2:4], e[:n, 4:6]
    gam0, gam1 = (g1 - g2, g2) if hold == "foh" else (g1, np.zeros_like(g1))
    if hold == "zoh":
        phi, gam0 = scipy.linalg.expm(a * DT), scipy.linalg.solve(a, (scipy.linalg.expm(a * DT) - np.eye(2)) @ b)
    x, out = x0.copy(), [x0[0]]
    for j in range(len(u) - 1):
        x = phi @ x + gam0 @ np.array([u[j], f0]) + gam1 @ np.array([u[j + 1], f0])
        out.append(x[0])
    return np.array(out)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_unmeasured_state_is_estimated_from_the_past_exactly(hold: str) -> None:
    """Position measured, velocity not: with 20 past samples of noise-free data the prediction
    after the window start is the exact continuation (the state is recovered by least squares)."""
    rng = np.random.default_rng(0)
    u = np.convolve(rng.normal(size=400), np.ones(8) / 8, mode="same") * 0.05 + 0.01
    x0 = np.array([0.03, 40.0])  # [V], [V/s]: far from rest
    y = msd_truth(u, x0, hold)
    model = msd_model(hold=hold)
    past = 20
    u_hat = torch.tensor((u - 0.01) / 0.05)[None, :, None]
    y_hat = torch.tensor((y[: past + 1] + 0.004) / 0.06)[None, :, None]
    with torch.no_grad():
        pred = model(u_hat, y_hat)[0, :, 0].numpy() * 0.06 - 0.004
    np.testing.assert_allclose(pred, y[past + 1 :], rtol=0, atol=1e-9 * np.abs(y).max())


def test_encoder_starts_as_the_least_squares_estimate() -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(1)
    u = torch.tensor(rng.normal(size=(3, 150, 1)))
    y = torch.tensor(rng.normal(size=(3, 31, 1)))
    with torch.no_grad():
        estimated = msd_model("estimate")(u, y)
        encoded = msd_model("encoder")(u, y)
    torch.testing.assert_close(encoded, estimated)


def test_scheduled_single_track_equals_the_per_sample_recursion() -> None:
    """The race car's composition: front steering -> single track whose matrices follow the
    measured speed sample by sample; against A(v_k), B(v_k) discretized one sample at a time."""
    values = VehicleParameters(mass=790.0, izz=1000.0, lf=1.248, lr=1.7328, cf=1e5, cr=1.2e5)
    config = {"name": "car", "outputs": ["yaw_rate", "side_slip"], "blocks": {
        "single_track": {"kind": "physics", "system": "single_track_front", "inputs": ["steering_angle"],
                         "outputs": ["yaw_rate", "side_slip"], "scheduling": {"velocity": "velocity"}}}}
    scale = {"yaw_rate": (0.01, 0.2), "side_slip": (0.0, 0.02)}
    dt, length = 1 / 25, 180
    model = ComposedModel(parse_model_spec(config), values.as_dict(), ["steering_angle"], list(scale),
                          {"steering_angle": (0.0, 0.05)}, scale, dt, horizon=100,
                          scheduling_names=["velocity"], scheduling_scale={"velocity": (20.0, 6.0)}).double()
    rng = np.random.default_rng(2)
    delta = np.convolve(rng.normal(size=length), np.ones(5) / 5, mode="same") * 0.05
    speed = 8.0 + 20.0 * (1 + np.sin(np.linspace(0, 3, length))) / 2
    x0 = np.array([0.05, -0.004])
    track = SingleTrack(rear_steering=False)
    x, expected = x0.copy(), []
    for k in range(length - 1):
        p = {**{n: torch.tensor(v, dtype=torch.float64) for n, v in values.as_dict().items()},
             "velocity": torch.tensor(speed[k], dtype=torch.float64)}
        ss = track.matrices(p)
        a, b = ss.a.numpy(), ss.b.numpy()
        big = np.zeros((3, 3))
        big[:2, :2], big[:2, 2:] = a * dt, b * dt
        e = scipy.linalg.expm(big)
        x = e[:2, :2] @ x + e[:2, 2:] @ np.array([delta[k]])
        expected.append(x)
    mean, std = np.array([0.01, 0.0]), np.array([0.2, 0.02])
    u_hat = torch.tensor(delta / 0.05)[None, :, None]
    y_hat = torch.tensor((x0 - mean) / std)[None]
    s = torch.tensor(speed)[None, :, None]
    with torch.no_grad():
        pred = model(u_hat, y_hat, s)[0].numpy() * std + mean
    np.testing.assert_allclose(pred, np.array(expected), rtol=1e-9, atol=1e-12)


def test_scheduling_and_estimation_errors_name_what_exists() -> None:
    config = {"name": "car", "outputs": ["yaw_rate", "side_slip"], "blocks": {
        "single_track": {"kind": "physics", "system": "single_track_front", "inputs": ["steering_angle"],
                         "outputs": ["yaw_rate", "side_slip"], "scheduling": {"velocity": "speed"}}}}
    scale = {"yaw_rate": (0.0, 0.2), "side_slip": (0.0, 0.02)}
    build = lambda cfg, sched: ComposedModel(parse_model_spec(cfg), VehicleParameters().as_dict(),  # noqa: E731
                                             ["steering_angle"], list(scale), {"steering_angle": (0.0, 0.05)},
                                             scale, 0.04, scheduling_names=sched,
                                             scheduling_scale=dict.fromkeys(sched, (20.0, 5.0)))
    with pytest.raises(ModelSpecError, match="not measured scheduling channels; the data declare: \\['velocity'\\]"):
        build(config, ["velocity"])
    config["blocks"]["single_track"]["scheduling"] = {"speed": "velocity"}
    with pytest.raises(ModelSpecError, match="scheduling \\['speed'\\] are not parameters"):
        build(config, ["velocity"])
    unobserved = {"name": "m", "outputs": ["y"], "parameters": MSD, "blocks": {  # q is nobody's measurement
        "osc": {"kind": "physics", "system": "mass_spring_damper", "inputs": ["u"], "outputs": ["q"]},
        "net": {"kind": "ann", "inputs": ["q"], "outputs": ["y"], "scale_as": ["u"]}}}
    with pytest.raises(ModelSpecError, match="cannot be estimated; give observe"):
        ComposedModel(parse_model_spec(unobserved), {}, ["u"], ["y"], {"u": (0.0, 1.0)}, {"y": (0.0, 1.0)}, DT)
    assert MassSpringDamper().output_names == ("position",)


def test_training_refuses_a_past_too_short_to_estimate_the_state() -> None:
    from hypa.data import DataSignature, Normalization
    from hypa.training import HybridModule

    config = {"name": "oscillator", "outputs": ["y"], "parameters": MSD, "blocks": {
        "oscillator": {"kind": "physics", "system": "mass_spring_damper", "inputs": ["u"], "outputs": ["y"]}}}
    data = lambda past: DataSignature(["u"], ["y"], Normalization(["u", "y"], [0.0, 0.0], [1.0, 1.0]), DT,  # noqa: E731
                                      window=100, past=past)
    with pytest.raises(ValueError, match=r"estimates its 2 states from 1 measured value.*at least 1"):
        HybridModule.from_data(data(0), config)
    HybridModule.from_data(data(1), config)  # two samples of the position: enough


def test_a_state_an_output_reads_alone_takes_that_outputs_scale() -> None:
    """The position (read by y = position) gets y's operating point and spread, wherever that is;
    the velocity, read by no output, keeps the data-free scale of the nominal physics around 0."""
    spec = msd_model().spec
    blocks = [ComposedModel(spec, {}, ["u"], ["y"], {"u": (0.01, 0.05)}, {"y": (mean, 0.06)}, dt=DT,
                            horizon=100).blocks["oscillator"] for mean in (-0.004, 5.0)]
    for block, mean in zip(blocks, (-0.004, 5.0)):
        assert block.state_mean.tolist() == pytest.approx([mean, 0.0])
        assert float(block.state_std[0]) == pytest.approx(0.06)
    assert float(blocks[0].state_std[1]) == float(blocks[1].state_std[1]) > 0
