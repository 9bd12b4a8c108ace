"""Dependent parameters (``depends: {p: {by: s, kind: direction | state | cubic}}``, ``hypa.physics.dependent``):
the outputs follow the parameter too where it enters C or D (an accelerometer reads -c v / m), against
scipy's ODE solver; a parameter of the state equation alone leaves the outputs linear."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from hypa.physics import LTIBlock, LTIModel, ParameterSpec, PhysicalParameters, StateSpace, check_system
from hypa.physics.dependent import Dependent

M, K, C, D, WIDTH = 2.0, 800.0, 12.0, 0.4, 0.02  # [kg], [N/m], [N s/m], [-], [m/s]
DT = 1e-3


class Mount(LTIModel):
    """m q'' = F - k q - c q': position and acceleration measured."""

    state_names, input_names, output_names = ("position", "velocity"), ("force",), ("position", "acceleration")
    parameters = (ParameterSpec("mass", M, "kg"), ParameterSpec("stiffness", K, "N/m"),
                  ParameterSpec("damping", C, "N s/m"))

    def matrices(self, p):
        m, k, c = p["mass"], p["stiffness"], p["damping"]
        zero, one = torch.zeros_like(m), torch.ones_like(m)
        a = torch.stack([torch.stack([zero, one]), torch.stack([-k / m, -c / m])])
        b = torch.stack([zero, 1 / m]).reshape(2, 1)
        return StateSpace(a, b, torch.stack([torch.stack([one, zero]), a[1]]), torch.stack([zero, 1 / m]).reshape(2, 1))


def force(t):
    return 40 * np.sin(2 * np.pi * 3 * t) + 15 * np.sin(2 * np.pi * 7.7 * t + 0.5)


def run(model: Dependent, values: dict) -> tuple[np.ndarray, np.ndarray]:
    """The mount at rest, driven by ``force`` for 2 s (first-order hold): the time and its outputs (T-1, 2)."""
    block = LTIBlock(model, PhysicalParameters(model.parameter_specs(values)), dt=DT, horizon=100, hold="foh")
    t = np.arange(0, 2, DT)
    u = torch.tensor(force(t), dtype=torch.float64)[None, :, None]
    with torch.no_grad():
        states = block.states(torch.zeros(1, 2, dtype=torch.float64), u)[0]
        return t, block.output(states[None], u[:, 1:])[0].numpy()


def test_a_damping_by_direction_moves_the_accelerometer_too() -> None:
    model = Dependent(Mount(), {"damping": {"by": "velocity", "kind": "direction"}}, "mount")
    check_system(model)
    assert model.has_nonlinear_output  # c enters C: the acceleration reads it
    values = {"mount/damping_direction_velocity": D, "mount/damping_direction_velocity_width": WIDTH}
    t, y = run(model, values)

    def damping(v):
        return C * (1 + D * np.tanh(v / WIDTH))

    def rhs(time, x):
        return [x[1], (force(time) - K * x[0] - damping(x[1]) * x[1]) / M]

    ref = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t[1:], rtol=1e-10, atol=1e-12, max_step=DT).y
    acceleration = (force(t[1:]) - K * ref[0] - damping(ref[1]) * ref[1]) / M
    for got, want in ((y[:, 0], ref[0]), (y[:, 1], acceleration)):
        assert np.abs(got - want).max() < 2e-3 * np.abs(want).max(), np.abs(got - want).max() / np.abs(want).max()
    # the nominal damping in C (what Dependent did before): the acceleration misses the direction's part
    linear_c = (force(t[1:]) - K * ref[0] - C * ref[1]) / M
    assert np.abs(linear_c - acceleration).max() > 0.05 * np.abs(acceleration).max()


def test_a_parameter_of_the_state_equation_alone_leaves_the_outputs_linear() -> None:
    class PositionOnly(Mount):
        output_names = ("position",)

        def matrices(self, p):
            ss = super().matrices(p)
            return StateSpace(ss.a, ss.b, ss.c[:1], ss.d[:1])

    model = Dependent(PositionOnly(), {"damping": {"by": "velocity", "kind": "direction"}}, "mount")
    assert not model.has_nonlinear_output


def test_a_stiffness_cubic_in_the_position_against_scipy() -> None:
    """k(q) = K (1 + a z + b z² + c z³), z = (q - μ) / σ: a spring that stiffens at both ends of its stroke and
    more at one; k enters A and C affinely, so the three evaluations are exact at any deflection."""
    model = Dependent(Mount(), {"stiffness": {"by": "position", "kind": "cubic"}}, "mount")
    check_system(model)
    a, b, c, level, spread = 0.3, 0.8, -0.4, 0.01, 0.05
    values = {"mount/stiffness_slope_position": a, "mount/stiffness_square_position": b,
              "mount/stiffness_cube_position": c, "mount/stiffness_slope_position_level": level,
              "mount/stiffness_slope_position_spread": spread}
    t, y = run(model, values)

    def stiffness(q):
        z = (q - level) / spread
        return K * (1 + a * z + b * z**2 + c * z**3)

    def rhs(time, x):
        return [x[1], (force(time) - stiffness(x[0]) * x[0] - C * x[1]) / M]

    ref = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t[1:], rtol=1e-10, atol=1e-12, max_step=DT).y
    z = (ref[0] - level) / spread
    assert np.abs(z).max() > 1.0  # the cubic's terms at full size: past one spread
    acceleration = (force(t[1:]) - stiffness(ref[0]) * ref[0] - C * ref[1]) / M
    for got, want in ((y[:, 0], ref[0]), (y[:, 1], acceleration)):
        assert np.abs(got - want).max() < 2e-3 * np.abs(want).max(), np.abs(got - want).max() / np.abs(want).max()
    # its linear part alone (the state kind's a) is another spring: the square and the cube are in the result
    linear = K * (1 + a * z)
    assert np.abs((stiffness(ref[0]) - linear) * ref[0]).max() > 0.2 * np.abs(stiffness(ref[0]) * ref[0]).max()


def test_a_cubic_with_no_square_or_cube_is_the_state_kind() -> None:
    cubic = Dependent(Mount(), {"stiffness": {"by": "position", "kind": "cubic"}}, "mount")
    state = Dependent(Mount(), {"stiffness": {"by": "position", "kind": "state"}}, "mount")
    values = {"mount/stiffness_slope_position": 0.3, "mount/stiffness_slope_position_level": 0.01,
              "mount/stiffness_slope_position_spread": 0.05}
    p_cubic = {s.name: torch.tensor(s.value, dtype=torch.float64) for s in cubic.parameter_specs(values)}
    p_state = {s.name: torch.tensor(s.value, dtype=torch.float64) for s in state.parameter_specs(values)}
    x, u = torch.randn(7, 2, dtype=torch.float64) * 0.1, torch.randn(7, 1, dtype=torch.float64)
    torch.testing.assert_close(cubic.nonlinearity(x, u, cubic.prepare(p_cubic)),
                               state.nonlinearity(x, u, state.prepare(p_state)), rtol=1e-12, atol=0)
    torch.testing.assert_close(cubic.output_nonlinearity(x, u, p_cubic), state.output_nonlinearity(x, u, p_state),
                               rtol=1e-12, atol=0)


@pytest.mark.parametrize("kind", ["direction", "state", "cubic"])
def test_zero_weight_is_the_system_itself(kind: str) -> None:
    model = Dependent(Mount(), {"damping": {"by": "velocity", "kind": kind}}, "mount")
    p = {s.name: torch.tensor(s.value, dtype=torch.float64) for s in model.parameter_specs({})}
    x, u = torch.randn(5, 2, dtype=torch.float64), torch.randn(5, 1, dtype=torch.float64)
    assert torch.equal(model.output_nonlinearity(x, u, p), torch.zeros(5, 2, dtype=torch.float64))


def test_levels_spreads_and_widths_the_model_leaves_open_come_from_the_data() -> None:
    """A block's ``depends`` and ``curved`` without their level, spread or width: the block's scaling
    of the signal sets them (the measured position's mean and standard deviation in the data, the
    force's; a direction's width a tenth of the spread); one the model gives is kept."""
    from hypa.data import DataSignature, Normalization
    from hypa.models import ComposedModel

    norm = Normalization(["force", "position"], [0.3, 0.021], [2.5, 0.0047])
    data = DataSignature(("force",), ("position",), norm, dt=1e-3, window=50, past=4)
    blocks = {"spring": {"kind": "physics", "system": "mass_spring_damper", "inputs": ["force"],
                         "outputs": ["position"], "initial_state": "estimate",
                         "depends": {"stiffness": {"by": "position", "kind": "cubic"},
                                     "damping": {"by": "force", "kind": "direction"},
                                     "mass": {"by": "force", "kind": "state"}},
                         "curved": {"position": 3},
                         "parameters": {"mass_slope_force_spread": 7.0}}}
    spec = {"name": "springs", "outputs": ["position"], "blocks": blocks}
    values = ComposedModel.from_data(data, spec).parameters_.as_floats()
    assert values["spring/stiffness_slope_position_level"] == pytest.approx(0.021)
    assert values["spring/stiffness_slope_position_spread"] == pytest.approx(0.0047)
    assert values["spring/damping_direction_force_width"] == pytest.approx(0.25)
    assert values["spring/mass_slope_force_level"] == pytest.approx(0.3)
    assert values["spring/mass_slope_force_spread"] == pytest.approx(7.0)  # given: kept
    assert values["spring/position_level"] == pytest.approx(0.021)  # curved
    assert values["spring/position_spread"] == pytest.approx(0.0047)
    spec["parameters"] = {"spring/stiffness_slope_position_level": 0.0}  # the model's parameters too
    values = ComposedModel.from_data(data, spec).parameters_.as_floats()
    assert values["spring/stiffness_slope_position_level"] == pytest.approx(0.0, abs=1e-12)
    assert values["spring/stiffness_slope_position_spread"] == pytest.approx(0.0047)
