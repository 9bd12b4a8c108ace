"""The cubic hold (``hold: cubic``): the Catmull-Rom input between samples, exact in every path.

References are independent of hypa's construction: the interpolant written from its defining
conditions (through u_k and u_{k+1}, slopes (u_{k+1} - u_{k-1}) / 2 and (u_{k+2} - u_k) / 2)
and integrated by scipy's ODE solver; the continuous system driven by the smooth input itself.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from hypa.conf import CONF
from hypa.physics import LTIBlock, PhysicalParameters
from hypa.physics.discretization import discretize
from hypa.physics.lifted import simulate_recursive
from hypa.physics.mass_spring_damper import DuffingOscillator, MassSpringDamper

F64 = {"dtype": torch.float64}
A = np.array([[0.0, 1.0], [-400.0, -3.0]])  # 3.2 Hz, damping ratio 0.075
B = np.array([[0.0], [2.0]])


def catmull_rom(u: np.ndarray, k: int, s: float) -> float:
    """The input at t_k + s dt from its Hermite form: the cubic through u_k, u_{k+1} with the centred slopes."""
    p0, p1, m0, m1 = u[k], u[k + 1], (u[k + 1] - u[k - 1]) / 2, (u[k + 2] - u[k]) / 2
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1


def test_the_taps_integrate_the_catmull_rom_input_exactly() -> None:
    """x_{k+1} = Φ x_k + Γ_0 u_{k-1} + Γ_1 u_k + Γ_2 u_{k+1} + Γ_3 u_{k+2} against the ODE over one sample."""
    dt = 0.02
    d = discretize(torch.tensor(A), torch.tensor(B), dt, "cubic")
    assert d.past == 1 and len(d.taps) == 4
    rng = np.random.default_rng(3)
    for _ in range(3):
        u, x0 = rng.normal(size=4), rng.normal(size=2)
        exact = solve_ivp(lambda t, x, u=u: A @ x + B[:, 0] * catmull_rom(u, 1, t / dt), (0, dt), x0,
                          rtol=1e-12, atol=1e-14, method="DOP853").y[:, -1]
        ours = d.phi.numpy() @ x0 + sum(g.numpy()[:, 0] * u[t] for t, g in enumerate(d.taps))
        np.testing.assert_allclose(ours, exact, rtol=1e-9, atol=1e-12)
    # a constant input: the taps sum to the zero-order hold's Γ
    torch.testing.assert_close(d.input_gain, discretize(torch.tensor(A), torch.tensor(B), dt).input_gain,
                               rtol=1e-13, atol=1e-15)


def _free_run_error(hold: str, rate: float) -> float:
    """RMS error / spread of a block's free run against the ODE driven by 12 sines of 0.2-2 Hz."""
    model = MassSpringDamper()
    params = PhysicalParameters(model.parameter_specs({"mass": 0.5, "stiffness": 200.0, "damping": 1.5}))
    freqs, phases = np.linspace(0.2, 2.0, 12), np.linspace(0.0, 5.0, 12)

    def force(t):
        return np.sin(2 * np.pi * freqs * np.asarray(t)[..., None] + phases).sum(-1)

    t = np.arange(int(20 * rate)) / rate
    truth = solve_ivp(lambda s, x: [x[1], (force(s) - 200.0 * x[0] - 1.5 * x[1]) / 0.5], (0, t[-1]), [0.0, 0.0],
                      t_eval=t, rtol=1e-12, atol=1e-14, method="DOP853").y[0]
    block = LTIBlock(model, params, 1 / rate, horizon=64, hold=hold)
    y = block.simulate_physical(torch.zeros(1, 2, **F64), torch.tensor(force(t), **F64)[None, :, None])[0, :, 0]
    y = y.numpy()[: len(t) - 1]  # samples 1..L-1
    return float(np.sqrt(np.mean((y - truth[1:]) ** 2)) / truth.std())


def test_a_smooth_input_is_followed_to_fourth_order() -> None:
    """Halving dt divides a smooth input's free-run error by about 4 under ``foh`` and by about 16 under
    ``cubic`` (10 here, its extrapolated first tap included), far below ``foh`` at every rate."""
    errors = {hold: [_free_run_error(hold, rate) for rate in (20.0, 40.0)] for hold in ("foh", "cubic")}
    foh, cubic = errors["foh"], errors["cubic"]
    assert 3.0 < foh[0] / foh[1] < 5.0, errors
    assert cubic[0] / cubic[1] > 8.0, errors  # 10.2: the first step's extrapolated tap adds a third-order part
    assert cubic[0] < 0.1 * foh[0], errors


def _block(hold: str = "cubic", horizon: int = 16, trainable: bool = False, duffing: bool = False) -> LTIBlock:
    model = DuffingOscillator() if duffing else MassSpringDamper()
    values = {"mass": 0.5, "stiffness": 200.0, "damping": 1.5, "offset_force": 0.3}
    if duffing:
        values["hardening"] = 0.0
    specs = model.parameter_specs(values)
    params = PhysicalParameters(dataclasses.replace(s, trainable=trainable and s.name == "stiffness") for s in specs)
    return LTIBlock(model, params, 0.01, horizon=horizon, hold=hold)


def test_every_path_of_a_cubic_block_is_the_step_by_step_recursion() -> None:
    """Frozen lifted windows chained, one trainable window, and a nonlinear block whose nonlinearity is
    zero: each the recursion over what the taps read (``tap_inputs``: the ends extrapolated)."""
    g = torch.Generator().manual_seed(5)
    x0, u = torch.randn(3, 2, generator=g, **F64), torch.randn(3, 58, 1, generator=g, **F64)
    block = _block()
    assert block.extra_inputs == 1 and block.n_taps == 4
    steps = u.shape[1] - block.extra_inputs
    taps = block.tap_inputs(u, steps)
    assert taps.shape[1] == steps + 3
    torch.testing.assert_close(taps[:, 0], 2 * u[:, 0] - u[:, 1])  # u_{-1} on the line through u_0, u_1
    torch.testing.assert_close(taps[:, -1], 2 * u[:, -1] - u[:, -2])
    torch.testing.assert_close(taps[:, 1:-1], u)
    d = block.discrete()
    reference = simulate_recursive(d.phi, d.taps, d.drift, x0, taps)
    torch.testing.assert_close(block(x0, u), reference[..., :1], rtol=1e-12, atol=1e-12)  # chained (horizon 16)
    later = block.tap_inputs(u[:, 1:], steps - 1, before=u[:, :1])  # the sample before the window, known
    torch.testing.assert_close(later, taps[:, 1:])
    torch.testing.assert_close(block(x0, u[:, 1:], before=u[:, :1]),
                               simulate_recursive(d.phi, d.taps, d.drift, x0, later)[..., :1], rtol=1e-12, atol=1e-12)
    window = u[:, :17]  # one horizon of a trainable block: the one-node path
    trained = _block(trainable=True)
    torch.testing.assert_close(trained(x0, window), block(x0, window), rtol=1e-12, atol=1e-12)
    duffing = _block(duffing=True)
    assert duffing.model.is_nonlinear
    torch.testing.assert_close(duffing(x0, u), reference[..., :1], rtol=1e-9, atol=1e-10)


def test_the_state_behind_a_window_is_estimated_exactly() -> None:
    """Noise-free outputs of a cubic block over a past of 12 samples give its unmeasured velocity
    exactly, reading û_{P+1} as the run did."""
    g = torch.Generator().manual_seed(2)
    block = _block()
    x0, u = torch.randn(4, 2, generator=g, **F64), torch.randn(4, 20, 1, generator=g, **F64)
    states = torch.cat([x0[:, None], block.states(x0, u)], 1)  # x̂_0..x̂_19
    y = block.output(states[:, :13], u[:, :13])
    estimate = block.estimate_state(u, y, torch.tensor([True]))
    torch.testing.assert_close(estimate, states[:, 12], rtol=1e-5, atol=1e-6)  # the ridge (1e-8) aside


def test_a_cubic_physics_model_is_refused_by_every_export_in_one_line() -> None:
    from omegaconf import OmegaConf

    from hypa.export import ExportError, ModelStep
    from hypa.export.statespace import refusal
    from hypa.models.composed import ComposedModel
    from hypa.models.spec import parse_model_spec

    config = OmegaConf.load(CONF / "model" / "physical.yaml")
    spec = parse_model_spec(OmegaConf.to_container(config))
    scale = dict.fromkeys(("steering_wheel_angle", "yaw_rate", "side_slip"), (0.0, 1.0))
    for hold, refused in (("foh", False), ("cubic", True)):
        model = ComposedModel(spec, None, ["steering_wheel_angle"], ["yaw_rate", "side_slip"], scale, scale, 0.01,
                              horizon=10, hold=hold).to(torch.float32)
        assert (refusal(model) is not None) == refused
        if not refused:
            ModelStep(model)
            continue
        with pytest.raises(ExportError, match="cubic hold, which reads the input a sample ahead") as error:
            ModelStep(model)
        assert "\n" not in str(error.value) and "physics.hold=foh" in str(error.value)
