"""Nonlinear physics in Lur'e form (``LTIModel.feedback`` / ``nonlinearity``): the saturating
single track against scipy's ODE solver, its linear limit, gradients, and the contract."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from hypa.physics import LTIBlock, LTIModel, ParameterSpec, PhysicalParameters, StateSpace
from hypa.physics.contract import SystemContractError, check_system
from hypa.vehicle import SingleTrack, SingleTrackRelaxationSaturation, SingleTrackSaturation

VALUES = SingleTrack().nominal_values()


def block(model: LTIModel, dt: float, hold: str = "foh", **values: float) -> LTIBlock:
    return LTIBlock(model, PhysicalParameters(model.parameter_specs({**VALUES, **values})), dt=dt, horizon=100,
                    hold=hold)


def steering(t: np.ndarray) -> np.ndarray:
    """A front-wheel angle [rad] that drives the axles well into saturation at μ = 0.6."""
    return 0.03 * np.sin(2 * np.pi * 0.7 * t) + 0.02 * np.sin(2 * np.pi * 1.9 * t + 1.0)


def reference(mu: float, t: np.ndarray) -> np.ndarray:
    """The continuous nonlinear single track integrated by scipy (RK45, tight tolerances)."""
    model = SingleTrackSaturation(rear_steering=False)
    p = {k: torch.tensor(v, dtype=torch.float64) for k, v in {**VALUES, "mu": mu}.items()}
    ss, f, q = model.matrices(p), model.feedback(p), model.prepare(p)
    a, b, f = ss.a.numpy(), ss.b.numpy(), f.numpy()

    def rhs(time: float, x: np.ndarray) -> np.ndarray:
        u = np.array([steering(np.array(time))])
        w = model.nonlinearity(torch.tensor(x), torch.tensor(u), q).numpy()
        return a @ x + b @ u + f @ w

    return solve_ivp(rhs, (t[0], t[-1]), np.zeros(2), t_eval=t, rtol=1e-10, atol=1e-12).y.T


def simulated(mu: float, dt: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, seconds + dt / 2, dt)
    u = torch.tensor(steering(t), dtype=torch.float64)[None, :, None]
    sim = block(SingleTrackSaturation(rear_steering=False), dt, mu=mu)
    with torch.no_grad():
        x = sim.states(torch.zeros(1, 2, dtype=torch.float64), u)[0].numpy()
    return t, np.concatenate([np.zeros((1, 2)), x])


def test_with_unbounded_friction_it_is_the_linear_single_track_exactly() -> None:
    t = np.arange(0, 5, 1 / 32)
    u = torch.tensor(steering(t), dtype=torch.float64)[None, :, None]
    for hold in ("zoh", "foh"):
        linear = block(SingleTrack(rear_steering=False), 1 / 32, hold)
        saturating = block(SingleTrackSaturation(rear_steering=False), 1 / 32, hold, mu=1e9)
        x0 = torch.tensor([[0.05, -0.01]], dtype=torch.float64)
        with torch.no_grad():
            assert torch.allclose(saturating.states(x0, u), linear.states(x0, u), atol=1e-12, rtol=0)


def test_against_scipy_and_second_order_in_the_sample_time() -> None:
    """Heun's predictor-corrector on the nonlinearity: the error against the ODE solution is O(dt²)."""
    errors = []
    for dt in (1 / 32, 1 / 256, 1 / 512, 1 / 1024):
        t, x = simulated(0.6, dt, 6.0)
        ref = reference(0.6, t)
        errors.append(float(np.abs(x - ref).max() / np.abs(ref).max()))
    assert errors[0] < 0.025  # a model's rate, deep in saturation
    assert errors[-1] < 3e-5
    assert 3.2 < errors[1] / errors[2] < 4.8 and 3.2 < errors[2] / errors[3] < 4.8, errors
    t, x = simulated(0.6, 1 / 1024, 6.0)
    linear = block(SingleTrack(rear_steering=False), 1 / 1024)
    with torch.no_grad():
        lin = linear.states(torch.zeros(1, 2, dtype=torch.float64),
                            torch.tensor(steering(t), dtype=torch.float64)[None, :, None])[0].numpy()
    assert np.abs(lin - x[1:]).max() > 0.1 * np.abs(x).max()  # it does saturate here


def test_gradients_reach_the_friction_coefficient() -> None:
    model = SingleTrackSaturation(rear_steering=False)
    specs = [ParameterSpec(s.name, s.value, s.unit, s.positive, s.bounds, trainable=s.name == "mu")
             for s in model.parameter_specs({**VALUES, "mu": 0.8})]
    sim = LTIBlock(model, PhysicalParameters(specs), dt=1 / 32, horizon=100, hold="foh")
    u = torch.tensor(steering(np.arange(0, 4, 1 / 32)), dtype=torch.float64)[None, :, None]
    sim.states(torch.zeros(1, 2, dtype=torch.float64), u).square().sum().backward()
    grads = [p.grad for p in sim.parameters() if p.requires_grad]
    assert len(grads) == 1 and torch.isfinite(grads[0]).all() and float(grads[0].abs()) > 0


def test_relaxation_and_saturation_together_follow_the_contract() -> None:
    for rear in (False, True):
        check_system(SingleTrackRelaxationSaturation(rear_steering=rear))
        check_system(SingleTrackSaturation(rear_steering=rear))


class WrongFeedback(SingleTrackSaturation):
    def feedback(self, p):
        return super().feedback(p).T[:1]


def test_a_feedback_of_the_wrong_shape_is_a_contract_error() -> None:
    with pytest.raises(SystemContractError, match=r"feedback must return F of shape \(2, r\)"):
        check_system(WrongFeedback(rear_steering=False))


def test_a_linear_system_has_no_nonlinearity() -> None:
    class Lag(LTIModel):
        state_names, input_names, output_names = ("y",), ("u",), ("y",)
        parameters = (ParameterSpec("tau", 0.1, "s"),)

        def matrices(self, p):
            tau = p["tau"]
            return StateSpace((-1 / tau).reshape(1, 1), (1 / tau).reshape(1, 1), torch.ones(1, 1, dtype=tau.dtype),
                              tau.new_zeros(1, 1))

    assert not Lag().is_nonlinear and SingleTrackSaturation().is_nonlinear


def test_duffing_without_hardening_is_the_mass_spring_damper_and_with_it_stiffer() -> None:
    from hypa.physics import MassSpringDamper
    from hypa.physics.mass_spring_damper import DuffingOscillator

    values = {"mass": 1.0, "stiffness": 400.0, "damping": 4.0, "offset_force": 0.0}
    t = np.arange(0, 3, 1 / 200)
    u = torch.tensor(300 * np.sin(2 * np.pi * 2 * t), dtype=torch.float64)[None, :, None]

    def run(model: LTIModel, **extra: float) -> torch.Tensor:
        sim = LTIBlock(model, PhysicalParameters(model.parameter_specs({**values, **extra})), dt=1 / 200,
                       horizon=100, hold="foh")
        with torch.no_grad():
            return sim.states(torch.zeros(1, 2, dtype=torch.float64), u)[..., 0]

    linear = run(MassSpringDamper())
    assert torch.allclose(run(DuffingOscillator(), hardening=0.0), linear, atol=1e-12, rtol=0)
    hard = run(DuffingOscillator(), hardening=5.0)  # amplitude ~0.75 m: the spring is ~3x stiffer there
    assert float(hard.abs().max()) < 0.8 * float(linear.abs().max())
    check_system(DuffingOscillator())


def test_coulomb_friction_against_scipy_and_zero_friction_is_the_linear_axis() -> None:
    """The EMPS axis with Coulomb friction (smoothed sign) at 1 kHz, against solve_ivp."""
    from hypa.physics import MassWithFriction
    from hypa.physics.friction import MassWithCoulombFriction

    dt, model = 1e-3, MassWithCoulombFriction()
    t = np.arange(0, 2, dt)
    force = 60 * np.sin(2 * np.pi * 1.0 * t) + 25 * np.sin(2 * np.pi * 3.1 * t)  # [N], reverses often
    u = torch.tensor(force, dtype=torch.float64)[None, :, None]

    def run(system: LTIModel, **extra: float) -> np.ndarray:
        sim = LTIBlock(system, PhysicalParameters(system.parameter_specs(extra)), dt=dt, horizon=100, hold="foh")
        with torch.no_grad():
            return np.concatenate([np.zeros((1, 2)), sim.states(torch.zeros(1, 2, dtype=torch.float64), u)[0].numpy()])

    linear = run(MassWithFriction())
    assert np.allclose(run(model, coulomb_friction=1e-12), linear, atol=1e-12, rtol=0)  # positive: not 0 itself
    x = run(model, coulomb_friction=20.0)
    p = {k: torch.tensor(v, dtype=torch.float64)
         for k, v in {**model.nominal_values(), "coulomb_friction": 20.0}.items()}
    ss, f = model.matrices(p), model.feedback(p)
    a, b, e, f = ss.a.numpy(), ss.b.numpy(), ss.e.numpy(), f.numpy()

    def rhs(time: float, state: np.ndarray) -> np.ndarray:
        w = model.nonlinearity(torch.tensor(state), torch.zeros(1, dtype=torch.float64), model.prepare(p)).numpy()
        return a @ state + b @ [np.interp(time, t, force)] + e + f @ w

    ref = solve_ivp(rhs, (0, t[-1]), np.zeros(2), t_eval=t, rtol=1e-9, atol=1e-12, max_step=dt).y.T
    assert np.abs(x - ref).max(axis=0)[1] < 1e-3 * np.abs(ref[:, 1]).max()  # velocity
    assert np.abs(x - ref).max(axis=0)[0] < 1e-3 * np.abs(ref[:, 0]).max()  # position
    assert np.abs(linear - x).max(axis=0)[0] > 0.05 * np.abs(x[:, 0]).max()  # the friction matters here


def test_cubic_friction_against_scipy_its_pivot_and_zero_share_is_the_coulomb_axis() -> None:
    """The partly cubic viscous friction, against solve_ivp on the friction law written out (not
    through the class), at a share where it doubles the friction at twice the pivot speed."""
    from hypa.physics.friction import MassWithCoulombFriction, MassWithCubicFriction

    dt, model = 1e-3, MassWithCubicFriction()
    check_system(model)
    t = np.arange(0, 2, dt)
    force = 160 * np.sin(2 * np.pi * 0.7 * t) + 25 * np.sin(2 * np.pi * 3.1 * t)  # [N]: beyond 1.5 v_c
    u = torch.tensor(force, dtype=torch.float64)[None, :, None]

    def run(system: LTIModel, **extra: float) -> np.ndarray:
        sim = LTIBlock(system, PhysicalParameters(system.parameter_specs(extra)), dt=dt, horizon=100, hold="foh")
        with torch.no_grad():
            return np.concatenate([np.zeros((1, 2)), sim.states(torch.zeros(1, 2, dtype=torch.float64), u)[0].numpy()])

    assert np.allclose(run(model), run(MassWithCoulombFriction()), atol=1e-12, rtol=0)  # nominal share 0
    share = 0.6
    x = run(model, cubic_share=share)
    v = model.nominal_values()
    m, fv, fc, f0, vc = v["mass"], v["viscous_friction"], v["coulomb_friction"], v["offset_force"], v["cubic_speed"]
    assert vc == pytest.approx(fc / fv)  # the pivot: where the viscous friction equals the Coulomb one

    def rhs(time: float, state: np.ndarray) -> np.ndarray:
        speed = state[1]
        friction = fv * (1 - share) * speed + fv * share * speed**3 / vc**2 + fc * np.tanh(speed / model.SMOOTHING_MPS)
        return np.array([speed, (np.interp(time, t, force) - friction + f0) / m])

    ref = solve_ivp(rhs, (0, t[-1]), np.zeros(2), t_eval=t, rtol=1e-9, atol=1e-12, max_step=dt).y.T
    assert np.abs(ref[:, 1]).max() > 1.5 * vc  # the cubic part dominates at the fastest
    assert np.abs(x - ref).max(axis=0)[1] < 1e-3 * np.abs(ref[:, 1]).max()  # velocity
    assert np.abs(x - ref).max(axis=0)[0] < 1e-3 * np.abs(ref[:, 0]).max()  # position
    p = {k: torch.tensor(val, dtype=torch.float64) for k, val in {**v, "cubic_share": share}.items()}
    at_pivot = model.nonlinearity(torch.tensor([0.0, vc], dtype=torch.float64), torch.zeros(1), model.prepare(p))
    coulomb = MassWithCoulombFriction()
    at_pivot_coulomb = coulomb.nonlinearity(torch.tensor([0.0, vc], dtype=torch.float64), torch.zeros(1),
                                            coulomb.prepare(p))
    assert torch.allclose(at_pivot, at_pivot_coulomb, atol=1e-12, rtol=0)  # the share pivots the law about v_c


class _Tanks(LTIModel):
    """Two tanks draining through orifices: no linear part at all, dx/dt = B u + F sqrt(x)."""
    state_names, input_names, output_names = ("upper", "lower"), ("pump",), ("lower",)
    parameters = (ParameterSpec("k1", 0.05, "V^0.5/s"), ParameterSpec("k2", 0.04, "V^0.5/s"),
                  ParameterSpec("k3", 0.06, "V^0.5/s"), ParameterSpec("k4", 0.03, "1/s"))

    def matrices(self, p):
        z, one = torch.zeros_like(p["k4"]), torch.ones_like(p["k4"])
        return StateSpace(torch.stack([torch.stack([z, z]), torch.stack([z, z])]),
                          torch.stack([p["k4"], z]).reshape(2, 1), torch.stack([z, one]).reshape(1, 2),
                          z.reshape(1, 1))

    def feedback(self, p):
        z = torch.zeros_like(p["k1"])
        return torch.stack([torch.stack([-p["k1"], z]), torch.stack([p["k2"], -p["k3"]])])

    def nonlinearity(self, x, u, p):
        return torch.sqrt(x.clamp_min(1e-6))


def test_nonlinear_physics_is_linearised_about_its_operating_point() -> None:
    """The modes the diagnosis reads its time scales from (``ComposedModel.eigenvalues``): of A
    + F ∂φ/∂x at the scaling's state means, not of the linear part (here empty: all zeros, an
    "integrator" with no time constant), and A itself for a linear system."""
    from hypa.physics.normalized import Scaling

    tanks = _Tanks()
    sim = LTIBlock(tanks, PhysicalParameters(tanks.parameter_specs({})), dt=4.0, horizon=10)
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    sim.set_scaling(Scaling(t(4.0, 9.0), t(1.0, 1.0), t(5.0), t(1.0), t(9.0), t(1.0)))
    with torch.no_grad():
        a = sim.linearised_a()
    expected = torch.tensor([[-0.05 / (2 * 2.0), 0.0], [0.04 / (2 * 2.0), -0.06 / (2 * 3.0)]], dtype=torch.float64)
    assert torch.allclose(a, expected, rtol=1e-12, atol=0)
    assert torch.count_nonzero(sim.state_space().a) == 0
    linear = block(SingleTrack(rear_steering=False), 1 / 32)
    assert torch.equal(linear.linearised_a(), linear.state_space().a)


def test_a_state_no_output_reads_takes_the_level_it_settles_to() -> None:
    """``settled_state_scales``: the upper tank settles to (k4 ū / k1)² under the mean pump voltage,
    the measured lower one keeps the data's operating point, spreads are kept; a system that does
    not settle (a frictionless mass pushed by a mean force: its speed grows) keeps 0."""
    from hypa.physics.operating_point import settled_state_scales

    tanks = _Tanks()
    params = PhysicalParameters(tanks.parameter_specs({}))
    settled = settled_state_scales(tanks, params, 4.0, [(5.0, 1.0)], [(0.0, 2.0), (6.0, 0.5)], [0])
    assert settled[0][0] == pytest.approx((0.03 * 5.0 / 0.05) ** 2, rel=1e-4) and settled[0][1] == 2.0
    assert settled[1] == (6.0, 0.5)

    class Pushed(_Tanks):
        def feedback(self, p):
            return torch.zeros(2, 2, dtype=p["k1"].dtype)

    pushed = Pushed()
    assert settled_state_scales(pushed, params, 4.0, [(5.0, 1.0)], [(0.0, 2.0), (6.0, 0.5)], [0])[0] == (0.0, 2.0)


def test_the_estimate_of_a_state_the_outputs_barely_see_is_the_same_on_every_call() -> None:
    """The tanks' upper level, seen through 5 samples of the lower one in single precision: its
    Gauss-Newton refinement is ill-conditioned, and single-precision LAPACK differs run to run in
    its round-off (with the buffers' alignment); those differences once reached 7e-5 of the state's
    spread, so one record's free run started elsewhere on every call (and an export's check failed
    one time in three). The solve is in double precision: every call gives the same bits."""
    from hypa.physics.normalized import Scaling

    tanks = _Tanks()
    sim = LTIBlock(tanks, PhysicalParameters(tanks.parameter_specs({})), dt=4.0, horizon=10).float()
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    sim.set_scaling(Scaling(t(9.0, 6.0), t(2.0, 0.4), t(5.0), t(1.0), t(6.0), t(0.4)))
    rng = np.random.default_rng(5)
    u = torch.tensor(rng.standard_normal((1, 6, 1)), dtype=torch.float32)
    y = torch.tensor(rng.standard_normal((1, 6, 1)), dtype=torch.float32) * 0.3
    observed = torch.tensor([True])
    with torch.no_grad():
        first = sim.estimate_state(u, y, observed)
        for size in range(1, 60):  # other work between the calls moves the buffers
            padding = torch.ones(size * 7)
            assert torch.equal(sim.estimate_state(u, y, observed), first), size
            del padding
