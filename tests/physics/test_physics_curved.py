"""Curved couplings (``curved: {state: power}``, ``hypa.physics.curved``): zero weights are the
system itself, a cubic on a mass-spring-damper's position is Duffing's spring exactly, a square
on a velocity about an operating point follows scipy's ODE solver, and a bad mapping is one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from hypa.models.spec import ModelSpecError, parse_model_spec, spec_config
from hypa.physics import (
    LTIBlock,
    LTIModel,
    MassSpringDamper,
    ParameterSpec,
    PhysicalParameters,
    StateSpace,
    SystemContractError,
    check_system,
)
from hypa.physics.curved import Curved
from hypa.physics.mass_spring_damper import DuffingOscillator
from hypa.physics.systems import build_system

VALUES = {"mass": 1.0, "stiffness": 400.0, "damping": 4.0, "offset_force": 0.0}
DT = 1 / 200


def run(model: LTIModel, u: torch.Tensor, **values: float) -> np.ndarray:
    sim = LTIBlock(model, PhysicalParameters(model.parameter_specs({**VALUES, **values})), dt=DT, horizon=100,
                   hold="foh")
    with torch.no_grad():
        x = sim.states(torch.zeros(1, 2, dtype=torch.float64), u)[0].numpy()
    return np.concatenate([np.zeros((1, 2)), x])


def force(t: np.ndarray) -> np.ndarray:
    return 300 * np.sin(2 * np.pi * 2 * t) + 80 * np.sin(2 * np.pi * 5.3 * t + 1.0)


@pytest.fixture(scope="module")
def u() -> torch.Tensor:
    return torch.tensor(force(np.arange(0, 3, DT)), dtype=torch.float64)[None, :, None]


def test_zero_weights_are_the_system_and_a_cubic_position_is_duffing(u: torch.Tensor) -> None:
    curved = Curved(MassSpringDamper(), {"position": 3}, "spring")
    check_system(curved)
    assert curved.is_nonlinear and curved.state_names == MassSpringDamper.state_names
    names = set(curved.parameter_names) - set(MassSpringDamper().parameter_names)
    assert names == {"spring/position_level", "spring/position_spread", "spring/curve_position_on_position",
                     "spring/curve_position_on_velocity"}
    linear = run(MassSpringDamper(), u)
    assert np.allclose(run(curved, u, **{"spring/position_spread": 0.4}), linear, atol=1e-12, rtol=0)
    # k q (1 + w (q / s)^2) is Duffing's k q (1 + h q^2) with h = w / s^2 (row velocity: A = -k / m)
    w, s = 0.8, 0.4
    bent = run(curved, u, **{"spring/position_spread": s, "spring/curve_position_on_velocity": w,
                             "spring/curve_position_on_position": 5.0})  # A[position, position] = 0: no effect
    duffing = run(DuffingOscillator(), u, hardening=w / s**2)
    assert np.abs(bent - duffing).max() < 1e-10 * np.abs(duffing).max()
    assert np.abs(bent - linear).max() > 0.1 * np.abs(linear).max()  # the curvature matters here


def test_a_square_about_an_operating_point_against_scipy(u: torch.Tensor) -> None:
    """Power 2 on the velocity, about a level of 0.3 m/s: both couplings from the velocity bend
    (into the position, A = 1, and into itself, A = -d / m), as the module docstring writes."""
    level, spread, w_q, w_v = 0.3, 1.0, -0.05, 0.3
    u = u / 5  # a square grows without bound: keep the speed near its operating point
    model = Curved(MassSpringDamper(), {"velocity": 2}, "b")
    x = run(model, u, **{"b/velocity_level": level, "b/velocity_spread": spread, "b/curve_velocity_on_position": w_q,
                         "b/curve_velocity_on_velocity": w_v})
    t = np.arange(0, 3, DT)
    m, k, d = VALUES["mass"], VALUES["stiffness"], VALUES["damping"]

    def rhs(time: float, state: np.ndarray) -> np.ndarray:
        q, v = state
        bend = (v - level) * (v - level) / spread
        return np.array([v + w_q * bend, (np.interp(time, t, force(t) / 5) - k * q - d * (v + w_v * bend)) / m])

    ref = solve_ivp(rhs, (0, t[-1]), np.zeros(2), t_eval=t, rtol=1e-10, atol=1e-12, max_step=DT).y.T
    error = np.abs(x - ref).max(axis=0) / np.abs(ref).max(axis=0)
    assert error.max() < 1e-3, error  # Heun's step for the feedback: second order in dt
    assert np.abs(x - run(MassSpringDamper(), u)).max(axis=0)[0] > 0.02 * np.abs(ref[:, 0]).max()


def test_the_model_key_round_trips_and_bad_mappings_are_one_line() -> None:
    config = {"name": "m", "outputs": ["position"], "blocks": {"spring": {
        "kind": "physics", "system": "mass_spring_damper", "inputs": ["force"], "outputs": ["position"],
        "curved": {"position": 3}, "trainable": ["curve_position_on_velocity"]}}}
    spec = parse_model_spec(config)
    assert spec.block("spring").curved == {"position": 3}
    assert spec_config(spec)["blocks"]["spring"]["curved"] == {"position": 3}
    built = build_system("mass_spring_damper", "spring", {"position": 3})
    assert isinstance(built, Curved) and built.display_name == "MassSpringDamper (curved on position)"
    with pytest.raises(ValueError, match=r"^MassSpringDamper \(curved on position\) needs parameters"):
        LTIBlock(built, PhysicalParameters(MassSpringDamper().parameter_specs({})), dt=0.01)  # named, not "Curved"
    with pytest.raises(ModelSpecError, match="power, 2, 3 or root"):
        parse_model_spec({**config, "blocks": {"spring": {**config["blocks"]["spring"], "curved": {"position": 4}}}})
    with pytest.raises(ModelSpecError, match="only physics blocks"):
        parse_model_spec({"name": "m", "outputs": ["y"], "blocks": {"d": {
            "kind": "delay", "inputs": ["u"], "outputs": ["y"], "parameters": {"delay_s": 0.1},
            "curved": {"y": 3}}}})
    with pytest.raises(SystemContractError, match="has no state 'speed'"):
        build_system("mass_spring_damper", "spring", {"speed": 3})


def test_a_nonlinear_system_keeps_its_own_feedback_beside_the_curved_one(u: torch.Tensor) -> None:
    """Curving Duffing's velocity: zero weights are Duffing itself (its cubic spring kept), and
    the feedback holds both columns, Duffing's first."""
    model = Curved(DuffingOscillator(), {"velocity": 3}, "b")
    check_system(model)
    p = {s.name: torch.tensor(s.value, dtype=torch.float64) for s in model.parameter_specs(VALUES)}
    assert model.feedback(p).shape == (2, 2)
    duffing = run(DuffingOscillator(), u, hardening=5.0)
    assert np.abs(run(model, u, hardening=5.0) - duffing).max() < 1e-12 * np.abs(duffing).max()
    damped = run(model, u, hardening=5.0, **{"b/curve_velocity_on_velocity": 0.5})
    assert np.abs(damped - duffing).max() > 0.01 * np.abs(duffing).max()


class Drain(LTIModel):
    """dh/dt = -h / tau + g u: a tank linearised, its level h positive."""

    state_names, input_names, output_names = ("level",), ("inflow",), ("level",)
    parameters = (ParameterSpec("tau", 50.0, "s"), ParameterSpec("gain", 0.02, "m/(s V)"))

    def matrices(self, p):
        t = p["tau"]
        return StateSpace((-1 / t).reshape(1, 1), p["gain"].reshape(1, 1), torch.ones(1, 1, dtype=t.dtype),
                          t.new_zeros(1, 1))


@pytest.mark.parametrize("w", [1.0, 0.4])
def test_a_root_is_torricellis_outflow_against_scipy(w: float) -> None:
    """``curved: {level: root}``: -h / tau becomes -(h + w (√(μ h) - h)) / tau; at w = 1 the flow
    through an orifice, -√(μ h) / tau (the same flow as the linear one at the level μ), against
    scipy's ODE solver over a fill and a drain; w = 0 is the linear tank."""
    dt, level = 1.0, 2.0
    t = np.arange(0, 600, dt)
    inflow = np.where((t // 150) % 2 == 0, 8.0, 1.0)  # held per sample: a zero-order hold
    model = Curved(Drain(), {"level": "root"}, "tank")
    check_system(model)
    values = {"tank/level_level": level, "tank/level_spread": 1.0, "tank/curve_level": w}
    sim = LTIBlock(model, PhysicalParameters(model.parameter_specs(values)), dt=dt, horizon=100, hold="zoh")
    start = torch.tensor([[0.5]], dtype=torch.float64)
    with torch.no_grad():
        x = sim.states(start, torch.tensor(inflow, dtype=torch.float64)[None, :, None])[0, :, 0].numpy()

    def rhs(time: float, h: np.ndarray) -> list[float]:
        outflow = h[0] + w * (np.sqrt(level * max(h[0], 0.0)) - h[0])
        return [-outflow / 50.0 + 0.02 * inflow[min(int(time // dt), len(t) - 1)]]

    ref = solve_ivp(rhs, (0, t[-1] + dt), [0.5], t_eval=t + dt, rtol=1e-10, atol=1e-12, max_step=dt / 4).y[0]
    assert np.abs(x - ref).max() < 1e-3 * np.abs(ref).max(), np.abs(x - ref).max()
    linear = LTIBlock(Drain(), PhysicalParameters(Drain().parameter_specs({})), dt=dt, horizon=100, hold="zoh")
    with torch.no_grad():
        flat = linear.states(start, torch.tensor(inflow, dtype=torch.float64)[None, :, None])[0, :, 0].numpy()
    assert np.abs(x - flat).max() > 0.05 * np.abs(flat).max()  # the root matters here
