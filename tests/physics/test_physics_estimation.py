"""Estimating unmeasured states from a past window (least squares) and the data-free state scale."""

import numpy as np
import pytest
import scipy.linalg
import torch
from scipy.signal import cont2discrete

from hypa.physics import (
    LTIBlock,
    MassSpringDamper,
    PhysicalParameters,
    Scaling,
    StateSpace,
    default_state_std,
)
from hypa.vehicle import SingleTrack, VehicleParameters, vehicle_parameters

DT = 1 / 610.35  # Silverbox's sample rate: the nominal oscillator turns ~0.72 rad per sample
VALUES = {"mass": 5.1e-6, "stiffness": 0.98, "damping": 2.2e-4, "offset_force": 0.02}


def t(*v: float) -> torch.Tensor:
    return torch.tensor(v, dtype=torch.float64)


def oscillator(hold: str = "zoh") -> LTIBlock:
    """Force -> position only (C = [1, 0]): the velocity is never measured."""
    model = MassSpringDamper()
    scaling = Scaling(t(0.01, 0.0), t(0.1, 40.0), t(0.0), t(0.1), t(0.01), t(0.1))
    return LTIBlock(model, PhysicalParameters(model.parameter_specs(VALUES)), DT, horizon=50, hold=hold,
                    scaling=scaling)


def physical_matrices() -> tuple[np.ndarray, ...]:
    m, k, d, f0 = (VALUES[n] for n in ("mass", "stiffness", "damping", "offset_force"))
    a, b, e = np.array([[0.0, 1.0], [-k / m, -d / m]]), np.array([[0.0], [1 / m]]), np.array([0.0, f0 / m])
    phi, gamma, *_ = cont2discrete((a, np.hstack([b, e[:, None]]), np.eye(2), np.zeros((2, 2))), DT)
    return phi, gamma[:, :1], gamma[:, 1]  # x+ = Φ x + Γ u + γ (ZOH)


def simulate(x0: np.ndarray, force: np.ndarray) -> np.ndarray:
    """States x_0..x_L (L+1, 2) from scipy's ZOH matrices."""
    phi, gamma, drift = physical_matrices()
    xs = [x0]
    for f in force:
        xs.append(phi @ xs[-1] + gamma @ f + drift)
    return np.array(xs)


def normalized(block: LTIBlock, force: np.ndarray, position: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    u = (torch.tensor(force) - block.input_mean) / block.input_std
    y = (torch.tensor(position) - block.output_mean) / block.output_std
    return u, y


def test_noise_free_position_recovers_the_whole_state() -> None:
    block, rng, past = oscillator(), np.random.default_rng(0), 10
    force = rng.normal(size=(4, past + 1, 1)) * 0.05
    x0 = rng.normal(size=(4, 2)) * np.array([0.05, 20.0])
    states = np.stack([simulate(x0[i], force[i]) for i in range(4)])  # (B, P+2, 2)
    u, y = normalized(block, force, states[:, : past + 1, :1])
    estimate = block.estimate_state(u, y, [True])
    truth = (torch.tensor(states[:, past]) - block.state_mean) / block.state_std
    assert (estimate - truth).abs().max() < 1e-8
    # and the prediction from it continues the measured trajectory
    prediction = block(estimate, u[:, past:])  # one step: x̂_{P+1}
    expected = (torch.tensor(states[:, past + 1, :1]) - block.output_mean) / block.output_std
    assert (prediction[:, 0] - expected).abs().max() < 1e-8


def test_with_noise_it_is_the_least_squares_optimum() -> None:
    block, rng, past = oscillator(), np.random.default_rng(1), 10
    force = rng.normal(size=(3, past + 1, 1)) * 0.05
    x0 = rng.normal(size=(3, 2)) * np.array([0.05, 20.0])
    positions = np.stack([simulate(x0[i], force[i])[: past + 1, :1] for i in range(3)])
    positions += rng.normal(size=positions.shape) * 1e-3
    u, y = normalized(block, force, positions)
    exact, default = block.estimate_state(u, y, [True], ridge=0.0), block.estimate_state(u, y, [True])
    phi, _gamma, _drift = physical_matrices()
    powers = [np.linalg.matrix_power(phi, j) for j in range(past + 1)]
    observability = np.stack([p[0] for p in powers])  # rows C Φ^j, C = [1, 0]
    for i in range(3):
        free = simulate(np.zeros(2), force[i])[: past + 1]  # the response to the inputs from x_0 = 0
        x0_ls = np.linalg.lstsq(observability, positions[i, :, 0] - free[:, 0], rcond=None)[0]
        x_p = powers[past] @ x0_ls + free[past]
        truth = (torch.tensor(x_p) - block.state_mean) / block.state_std
        torch.testing.assert_close(exact[i], truth, rtol=1e-9, atol=1e-9)
        torch.testing.assert_close(default[i], truth, rtol=1e-6, atol=1e-6)  # the ridge is negligible


def test_past_zero_with_measured_states_returns_the_measurement() -> None:
    block = LTIBlock(SingleTrack(), vehicle_parameters(VehicleParameters()), 1 / 32, horizon=10, hold="foh",
                     scaling=Scaling(t(0.0, 0.0), t(0.09, 0.012), t(0.0, 0.0), t(0.02, 0.003), t(0.0, 0.0),
                                     t(0.09, 0.012)))
    y = torch.randn(5, 1, 2, dtype=torch.float64)
    estimate = block.estimate_state(torch.randn(5, 1, 2, dtype=torch.float64), y, [True, True])
    torch.testing.assert_close(estimate, y[:, 0], rtol=1e-7, atol=1e-12)


@pytest.mark.parametrize("scheduled", [False, True])
def test_only_samples_up_to_p_are_read(scheduled: bool) -> None:
    params = vehicle_parameters(VehicleParameters())
    block = LTIBlock(SingleTrack(), params, 1 / 32, horizon=10, hold="foh",
                     scheduled=["velocity"] if scheduled else ())
    past, g = 6, torch.Generator().manual_seed(0)
    u = torch.randn(2, 20, 2, generator=g, dtype=torch.float64, requires_grad=True)
    y = torch.randn(2, 20, 2, generator=g, dtype=torch.float64)
    y[..., 1] = float("nan")  # the side slip is not measured: never read
    v = torch.linspace(10, 20, 20, dtype=torch.float64).expand(2, 20)[..., None] if scheduled else None
    estimate = block.estimate_state(u, y[:, : past + 1], [True, False], scheduling=v)
    assert torch.isfinite(estimate).all()
    (grad,) = torch.autograd.grad(estimate.sum(), u)
    assert grad[:, past + 1 :].abs().max() == 0 and grad[:, : past + 1].abs().max() > 0
    later = u.detach().clone()
    later[:, past + 1 :] += 1.0
    v_later = None if v is None else torch.cat([v[:, : past + 1], v[:, past + 1 :] + 5.0], 1)
    torch.testing.assert_close(block.estimate_state(later, y[:, : past + 1], [True, False], scheduling=v_later),
                               estimate.detach(), rtol=0, atol=0)


@pytest.mark.parametrize("hold", ["zoh", "foh", "cubic"])
def test_scheduled_estimate_recovers_the_side_slip_from_the_yaw_rate(hold: str) -> None:
    """A velocity-scheduled single track seen through its yaw rate only: the state at P, exactly."""
    block = LTIBlock(SingleTrack(), vehicle_parameters(VehicleParameters()), 1 / 32, horizon=10, hold=hold,
                     scaling=Scaling(t(0.0, 0.0), t(0.09, 0.012), t(0.0, 0.0), t(0.02, 0.003), t(0.0, 0.0),
                                     t(0.09, 0.012)), scheduled=["velocity"])
    g, past = torch.Generator().manual_seed(5), 10
    x0 = torch.randn(3, 2, generator=g, dtype=torch.float64)
    u = torch.randn(3, past + 1, 2, generator=g, dtype=torch.float64)
    v = torch.linspace(8, 25, past + 1, dtype=torch.float64).expand(3, past + 1)[..., None].contiguous()
    states = block.states(x0, u, v)  # x̂_1..x̂_S
    truth = states[:, past - 1]
    y = torch.cat([x0[:, None], states], 1)[:, : past + 1].clone()  # ŷ = x̂ (C = I), samples 0..P
    y[..., 1] = 0.0  # unobserved
    estimate = block.estimate_state(u, y, torch.tensor([True, False]), scheduling=v, ridge=0.0)
    assert (estimate - truth).abs().max() < 1e-10
    ridged = block.estimate_state(u, y, torch.tensor([True, False]), scheduling=v)  # biased by ~λ / σ_min(O)²
    assert (ridged - truth).abs().max() < 1e-6


class Estimator(torch.nn.Module):
    """``estimate_state`` as a module's forward, so that ``functional_call`` can swap the parameters."""

    def __init__(self, block: LTIBlock, observed: list[bool], scheduling: torch.Tensor) -> None:
        super().__init__()
        self.block, self.observed, self.scheduling = block, observed, scheduling

    def forward(self, u: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return self.block.estimate_state(u, y, self.observed, scheduling=self.scheduling)


def test_gradcheck_estimate() -> None:
    params = vehicle_parameters(VehicleParameters(), trainable=["cf"])
    block = LTIBlock(SingleTrack(), params, 1 / 32, horizon=10, scheduled=["velocity"])
    g = torch.Generator().manual_seed(2)
    u = torch.randn(2, 4, 2, generator=g, dtype=torch.float64, requires_grad=True)
    y = torch.randn(2, 4, 2, generator=g, dtype=torch.float64, requires_grad=True)
    v = torch.linspace(10, 20, 4, dtype=torch.float64).expand(2, 4)[..., None].contiguous()
    estimator = Estimator(block, [True, False], v)

    def fn(cf, u, y):
        return torch.func.functional_call(estimator, {"block.parameters_.raw.cf": cf}, (u, y))

    cf = params.raw["cf"].detach().clone().requires_grad_()
    assert torch.autograd.grad(fn(cf, u, y).sum(), cf)[0].abs() > 0
    assert torch.autograd.gradcheck(fn, (cf, u, y))


def test_default_state_std_of_a_double_integrator() -> None:
    """x = [position, velocity], u = force / mass: no Lyapunov solution exists, the N-step Gramian does."""
    a, b = t(0.0, 1.0, 0.0, 0.0).reshape(2, 2), t(0.0, 0.5).reshape(2, 1)
    system = StateSpace(a, b, t(1.0, 0.0).reshape(1, 2), t(0.0).reshape(1, 1))
    dt, sigma, horizon = 0.01, 3.0, 100
    std = default_state_std(system, dt, t(sigma), horizon)
    phi = np.array([[1.0, dt], [0.0, 1.0]])
    gamma = scipy.linalg.expm(np.block([[a.numpy(), b.numpy()], [np.zeros((1, 3))]]) * dt)[:2, 2:]
    gramian = sum(np.linalg.matrix_power(phi, j) @ gamma @ gamma.T @ np.linalg.matrix_power(phi, j).T
                  for j in range(horizon)) * sigma**2
    np.testing.assert_allclose(std.numpy(), np.sqrt(np.diag(gramian)), rtol=1e-12)
    # the velocity is a random walk (σ √N dt / m); the position grows ~N^{3/2}
    assert std[1].item() == pytest.approx(sigma * 0.5 * dt * np.sqrt(horizon), rel=1e-12)
    assert default_state_std(system, dt, t(sigma), 4 * horizon)[0] / std[0] == pytest.approx(8.0, rel=0.05)


def test_default_state_std_is_never_zero() -> None:
    a = -torch.eye(2, dtype=torch.float64)
    driven = StateSpace(a, t(1.0, 0.0).reshape(2, 1), torch.eye(2, dtype=torch.float64), torch.zeros(2, 1))
    std = default_state_std(driven, 0.1, t(2.0), 50)
    assert std[1] == pytest.approx(1e-3 * std[0].item()) and std[0] > 0  # the undriven state: floored
    none = StateSpace(a, torch.zeros(2, 1, dtype=torch.float64), torch.eye(2, dtype=torch.float64), torch.zeros(2, 1))
    assert torch.equal(default_state_std(none, 0.1, t(2.0), 50), torch.ones(2, dtype=torch.float64))
