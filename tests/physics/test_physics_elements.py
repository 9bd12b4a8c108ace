"""The input-path elements the diagnosis adds: a first-order lag (LTI) and a dead time (a shift).

References are exact: the lag's step and ramp responses in closed form and scipy's lsim, the
dead time against numpy's linear interpolation (exact for the first-order hold's piecewise-
linear input). Gradients reach both parameters.
"""

import math

import numpy as np
import pytest
import torch
from scipy.signal import lsim

from hypa.physics import LTIBlock, ParameterSpec, PhysicalParameters, Scaling
from hypa.physics.elements import DeadTime, FirstOrderLag, LeadLag, SecondOrder, StaticGain

DT = 1 / 32


def lag_block(tau: float, hold: str, scaling: Scaling | None = None, trainable: bool = False) -> LTIBlock:
    model = FirstOrderLag("lag")
    params = PhysicalParameters([ParameterSpec("lag/tau_s", tau, "s", trainable=trainable)])
    return LTIBlock(model, params, DT, horizon=50, hold=hold, scaling=scaling)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("length", [50, 173])
def test_lag_matches_scipy_for_piecewise_inputs(hold: str, length: int) -> None:
    """lsim's linear interpolation is the FOH's input; a staircase input makes it the ZOH's."""
    tau = 0.08
    rng = np.random.default_rng(1)
    u = np.cumsum(rng.normal(size=length + 1)) * 0.1
    block = lag_block(tau, hold).double()
    x0 = torch.tensor([[0.3]], dtype=torch.float64)
    inputs = torch.tensor(u[None, : length + block.n_taps - 1, None])
    y = block(x0, inputs)[0, :, 0].numpy()
    if hold == "foh":
        t = np.arange(length + 1) * DT
        _, ref, _ = lsim(([-1 / tau], [[1 / tau]], [[1.0]], [[0.0]]), u, t, X0=[0.3], interp=True)
    else:  # exact ZOH recursion
        a = math.exp(-DT / tau)
        ref, x = [0.3], 0.3
        for k in range(length):
            x = a * x + (1 - a) * u[k]
            ref.append(x)
    np.testing.assert_allclose(y, np.asarray(ref)[1 : length + 1], rtol=1e-9, atol=1e-10)


def test_lag_steady_state_and_step_response() -> None:
    """Started in equilibrium with its first input, a constant input keeps it there; a step
    then rises as 1 - exp(-t / τ). Holds in the normalized coordinates of any scaling."""
    tau = 0.05
    scaling = Scaling(*(torch.tensor([v], dtype=torch.float64) for v in (0.2, 0.5, 0.1, 2.0, 0.2, 0.5)))
    block = lag_block(tau, "foh", scaling).double()
    u_phys = np.concatenate([np.full(10, 0.7), np.full(40, 1.7)])
    u_hat = torch.tensor(((u_phys - 0.1) / 2.0)[None, :, None])
    x0 = block.steady_state(u_hat[:, 0])
    assert float(x0) * 0.5 + 0.2 == pytest.approx(0.7, abs=1e-12)
    y = (block(x0, u_hat)[0, :, 0].numpy() * 0.5 + 0.2)  # x_1 .. x_49
    np.testing.assert_allclose(y[:9], 0.7, atol=1e-12)
    # FOH: the input ramps from 0.7 to 1.7 over sample 9 -> 10, then holds: exact ramp-step response
    t = (np.arange(10, 50) - 9) * DT
    ramp = 1.0 - tau / DT * (1 - np.exp(-np.minimum(t, DT) / tau)) * np.exp(-np.maximum(t - DT, 0) / tau)
    np.testing.assert_allclose(y[9:], 0.7 + ramp, rtol=1e-10)


def test_lag_time_constant_gets_a_gradient() -> None:
    block = lag_block(0.08, "foh", trainable=True).double()
    u = torch.linspace(0, 1, 51, dtype=torch.float64)[None, :, None]
    block(block.steady_state(u[:, 0]), u).sum().backward()
    grad = block.parameters_.raw["lag/tau_s"].grad
    assert grad is not None and float(grad) < 0  # a slower lag lags more: a smaller sum


@pytest.mark.parametrize("delay", [0.0 + 1e-9, 0.01, DT, 0.07, 0.2])
def test_dead_time_is_linear_interpolation_held_before_the_start(delay: float) -> None:
    rng = np.random.default_rng(2)
    u = rng.normal(size=(2, 90, 3))
    params = PhysicalParameters([ParameterSpec("d/delay_s", delay, "s")])
    y = DeadTime(params, "d/delay_s", DT)(torch.tensor(u)).numpy()
    t = np.arange(90) * DT
    for b in range(2):
        for c in range(3):
            ref = np.interp(t - delay, t, u[b, :, c], left=u[b, 0, c])
            np.testing.assert_allclose(y[b, :, c], ref, rtol=1e-9, atol=1e-9)


def test_dead_time_gradient_is_the_input_slope() -> None:
    """d y_n / d delay = -(u_{n-k} - u_{n-k-1}) / dt between the samples it interpolates."""
    params = PhysicalParameters([ParameterSpec("d/delay_s", 0.05, "s", trainable=True)])
    u = torch.arange(40, dtype=torch.float64)[None, :, None] ** 2 * 0.01
    dead_time = DeadTime(params, "d/delay_s", DT)
    y = dead_time(u)
    (dy,) = torch.autograd.grad(y[0, 20, 0], params.raw["d/delay_s"])
    k = int(0.05 / DT)
    slope = float(u[0, 20 - k, 0] - u[0, 19 - k, 0]) / DT
    assert float(dy) == pytest.approx(-slope * 0.05, rel=1e-9)  # raw is log(delay): chain rule × delay


def test_elements_refuse_bad_settings() -> None:
    with pytest.raises(ValueError, match="positive"):
        PhysicalParameters([ParameterSpec("lag/tau_s", 0.0, "s")])
    with pytest.raises(ValueError, match="needs the parameter"):
        DeadTime(PhysicalParameters([]), "d/delay_s", DT)


@pytest.mark.parametrize(("gain", "transient"), [(0.12, 0.3), (0.2, 0.0), (-0.1, 0.05)])
def test_lead_lag_matches_its_transfer_function(gain: float, transient: float) -> None:
    """LeadLag against scipy's lsim of (k + (k - k_t) τ_t s) / ((1 + τ_t s)(1 + τ s)) from rest,
    its steady start, and the phase reversal: with k_t > k a step first moves the other way."""
    tau_t, tau = 0.3, 0.07
    model = LeadLag("rws")
    values = {"rws/gain": gain, "rws/transient": transient, "rws/transient_tau_s": tau_t, "rws/tau_s": tau}
    params = PhysicalParameters([ParameterSpec(n, v, "-", positive=v > 0) for n, v in values.items()])
    block = LTIBlock(model, params, DT, horizon=64, hold="foh").double()
    rng = np.random.default_rng(2)
    u = np.cumsum(rng.normal(size=201)) * 0.05
    y = block(torch.zeros(1, 2, dtype=torch.float64), torch.tensor(u[None, : 200 + block.n_taps - 1, None]))
    num = [(gain - transient) * tau_t, gain]
    den = np.polymul([tau_t, 1.0], [tau, 1.0])
    _, ref, _ = lsim((num, den), u, np.arange(201) * DT, interp=True)
    np.testing.assert_allclose(y[0, :, 0].numpy(), ref[1:201], rtol=1e-8, atol=1e-10)
    step = torch.ones(1, 80 + block.n_taps - 1, 1, dtype=torch.float64)
    step[:, 0] = 0.0
    x0 = block.steady_state(step[:, 0])
    np.testing.assert_allclose(x0.numpy(), 0.0, atol=1e-15)
    response = block(x0, step)[0, :, 0].numpy()
    assert response[-1] == pytest.approx(gain, abs=1e-3)  # 2.5 s = 8 τ_t: settled at the gain
    if transient > gain > 0:
        assert response[2] < 0  # counter-phase first


@pytest.mark.parametrize(("gain", "zero_s", "frequency_hz", "damping"), [(0.5, 0.1, 2.0, 0.4), (-0.02, -0.3, 0.8, 1.3)])
def test_second_order_matches_its_transfer_function(gain: float, zero_s: float, frequency_hz: float,
                                                    damping: float) -> None:
    """SecondOrder (what hypa.explain writes for a second-order form) against scipy's lsim of
    k (1 + T s) / (1 + 2ζ s/ω + s²/ω²) from rest, and its steady start at the gain."""
    model = SecondOrder("form")
    values = {"form/gain": gain, "form/zero_s": zero_s, "form/natural_frequency_hz": frequency_hz,
              "form/damping": damping}
    params = PhysicalParameters([ParameterSpec(n, v, "-", positive=v > 0) for n, v in values.items()])
    block = LTIBlock(model, params, DT, horizon=64, hold="foh").double()
    u = np.cumsum(np.random.default_rng(3).normal(size=201)) * 0.05
    y = block(torch.zeros(1, 2, dtype=torch.float64), torch.tensor(u[None, : 200 + block.n_taps - 1, None]))
    w = 2 * np.pi * frequency_hz
    _, ref, _ = lsim(([gain * zero_s, gain], [1 / w**2, 2 * damping / w, 1.0]), u, np.arange(201) * DT, interp=True)
    np.testing.assert_allclose(y[0, :, 0].numpy(), ref[1:201], rtol=1e-8, atol=1e-10)
    level = torch.full((1, 1), 2.0, dtype=torch.float64)
    x0 = block.steady_state(level)
    steady = block(x0, level.expand(1, 50 + block.n_taps - 1)[..., None])[0, :, 0].numpy()
    np.testing.assert_allclose(steady, 2.0 * gain, rtol=1e-9)


def test_static_gain_has_no_states() -> None:
    model = StaticGain("form")
    block = LTIBlock(model, PhysicalParameters([ParameterSpec("form/gain", -0.3, "-", positive=False)]), DT,
                     horizon=8, hold="foh").double()
    u = torch.linspace(-1.0, 1.0, 8 + block.n_taps - 1, dtype=torch.float64)[None, :, None]
    assert model.n_states == 0
    y = block(torch.zeros(1, 0, dtype=torch.float64), u)[0, :, 0].numpy()
    np.testing.assert_allclose(y, -0.3 * u[0, -len(y):, 0].numpy(), rtol=1e-12)
