"""LTIBlock: named parameters -> normalized lifted simulation, for the vehicle and a non-vehicle system."""

import dataclasses

import numpy as np
import pytest
import torch
from scipy.signal import cont2discrete, dlsim

from hypa.physics import (
    LTIBlock,
    MassSpringDamper,
    ParameterSpec,
    PhysicalParameters,
    Scaling,
    UnstablePhysicsError,
    discretize,
    normalize,
    simulate_recursive,
)
from hypa.physics.normalized import NormalizingMaps
from hypa.vehicle import SingleTrack, SteeringGain, VehicleParameters, vehicle_parameters

DT = 1 / 32
VP = VehicleParameters()


def vehicle_scaling() -> Scaling:
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    return Scaling(t(0.002, -0.0004), t(0.09, 0.012), t(0.001, 0.0), t(0.02, 0.003), t(0.002, -0.0004), t(0.09, 0.012))


def test_single_track_matrices_as_printed() -> None:
    ss = SingleTrack().matrices({k: torch.tensor(v, dtype=torch.float64) for k, v in VP.as_dict().items()})
    m, izz, lf, lr, cf, cr, v = VP.mass, VP.izz, VP.lf, VP.lr, VP.cf, VP.cr, VP.velocity
    a = [[-(cf * lf**2 + cr * lr**2) / (v * izz), -(cf * lf - cr * lr) / izz],
         [-1 - (cf * lf - cr * lr) / (v**2 * m), -(cf + cr) / (v * m)]]
    b = [[cf * lf / izz, -cr * lr / izz], [cf / (v * m), cr / (v * m)]]
    np.testing.assert_allclose(ss.a.numpy(), a, rtol=1e-14)
    np.testing.assert_allclose(ss.b.numpy(), b, rtol=1e-14)
    fws = SingleTrack(rear_steering=False).matrices({k: torch.tensor(v, dtype=torch.float64)
                                                     for k, v in VP.as_dict().items()})
    np.testing.assert_allclose(fws.b.numpy(), np.array(b)[:, :1], rtol=1e-14)


def test_steady_state_yaw_gain_is_physical() -> None:
    """ψ̇/δf = v / (L (1 + K v²)) with the understeer gradient K of the linear model."""
    block = LTIBlock(SingleTrack(rear_steering=False), vehicle_parameters(VP), DT, horizon=100)
    steps = torch.full((1, 400, 1), 0.01, dtype=torch.float64)  # 0.01 rad front wheel angle
    yaw = block(torch.zeros(1, 2, dtype=torch.float64), steps)[0, -1, 0].item()
    k = VP.mass / VP.wheelbase**2 * (VP.lr / VP.cf - VP.lf / VP.cr)
    expected = VP.velocity / (VP.wheelbase * (1 + k * VP.velocity**2)) * 0.01
    assert yaw == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("hold", ["zoh", "foh", "cubic"])
@pytest.mark.parametrize("length", [100, 37, 257])
def test_normalized_simulation_denormalized_equals_physical(hold: str, length: int) -> None:
    """Eq. 5-8: simulating in the ANN's scale and scaling back is the physical simulation."""
    params = vehicle_parameters(VP)
    block = LTIBlock(SingleTrack(), params, DT, horizon=100, hold=hold, scaling=vehicle_scaling())
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(3, 2, generator=g, dtype=torch.float64) * torch.tensor([0.1, 0.01], dtype=torch.float64)
    u = torch.randn(3, length + block.extra_inputs, 2, generator=g, dtype=torch.float64) * 0.02
    physical = block.simulate_physical(x0, u)
    d = block.discrete()  # the step-by-step recursion over what the taps read (a cubic hold's ends extrapolated)
    reference = simulate_recursive(d.phi, d.taps, torch.zeros(2, dtype=torch.float64), x0, block.tap_inputs(u, length))
    torch.testing.assert_close(physical, reference, rtol=1e-12, atol=1e-14)
    assert physical.shape == (3, length, 2)


def test_steering_gains() -> None:
    params = vehicle_parameters(dataclasses.replace(VP, rws_ratio=-0.2))
    swa = torch.linspace(-0.5, 0.5, 100, dtype=torch.float64).reshape(1, 100, 1)
    front = LTIBlock(SteeringGain("front"), params, DT).simulate_physical(None, swa)
    rear = LTIBlock(SteeringGain("rear"), params, DT).simulate_physical(None, swa)
    torch.testing.assert_close(front, swa / VP.steering_ratio)
    torch.testing.assert_close(rear, -0.2 * swa / VP.steering_ratio)


def test_mass_spring_damper_against_scipy() -> None:
    params = PhysicalParameters(MassSpringDamper().parameter_specs({"mass": 2.0, "stiffness": 50.0, "damping": 1.5}))
    block = LTIBlock(MassSpringDamper(), params, dt=0.01, horizon=50)
    a = np.array([[0, 1], [-25.0, -0.75]])
    b = np.array([[0], [0.5]])
    ad, bd, *_ = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), 0.01)
    force = np.random.default_rng(1).normal(size=(333, 1))
    _, expected, _ = dlsim((ad, bd, np.eye(2), np.zeros((2, 1)), 0.01), force, x0=[0.1, 0.0])
    ours = block.simulate_physical(torch.tensor([[0.1, 0.0]], dtype=torch.float64),
                                   torch.tensor(force)[None])[0].numpy()
    np.testing.assert_allclose(ours[:-1, 0], expected[1:, 0], atol=1e-12)  # the output is the position


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_drift_e_against_scipy(hold: str) -> None:
    """dx/dt = A x + B u + e: the drift is a constant input, exact under either hold (folded into Ĥ)."""
    from scipy.linalg import expm

    model = MassSpringDamper()
    params = PhysicalParameters(model.parameter_specs({"mass": 2.0, "stiffness": 50.0, "damping": 1.5,
                                                       "offset_force": 3.0}))
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    scaling = Scaling(t(0.05, 0.0), t(0.1, 0.5), t(0.5), t(2.0), t(0.05), t(0.1))
    block = LTIBlock(model, params, dt=0.01, horizon=50, hold=hold, scaling=scaling)
    a, b, e = np.array([[0, 1], [-25.0, -0.75]]), np.array([[0], [0.5]]), np.array([0.0, 1.5])
    force = np.random.default_rng(1).normal(size=(121, 1))
    if hold == "zoh":  # scipy: e as a second input held at 1
        ad, bd, *_ = cont2discrete((a, np.hstack([b, e[:, None]]), np.eye(2), np.zeros((2, 2))), 0.01)
        x, steps = np.array([0.1, 0.0]), []
        for f in force:
            x = ad @ x + bd @ np.r_[f, 1.0]
            steps.append(x[0])
    else:  # FOH: expm([[A, B, e, 0], [0, 0, 0, I], 0] dt): x+ = Φ x + (E1 - E2) u_k + E2 u_{k+1} + γ
        gen = np.zeros((5, 5))
        gen[:2, :2], gen[:2, 2:3], gen[:2, 3], gen[2, 4] = a * 0.01, b * 0.01, e * 0.01, 1.0
        big = expm(gen)
        e1, e2 = big[:2, 2:3], big[:2, 4:5]
        x, steps = np.array([0.1, 0.0]), []
        for k in range(len(force) - 1):
            x = big[:2, :2] @ x + (e1 - e2) @ force[k] + e2 @ force[k + 1] + big[:2, 3]
            steps.append(x[0])
    ours = block.simulate_physical(t(0.1, 0.0)[None], torch.tensor(force)[None])[0, :, 0].numpy()
    np.testing.assert_allclose(ours, steps, rtol=1e-11, atol=1e-12)
    d = block.discrete()  # the drift of ``discretize`` too
    np.testing.assert_allclose(d.drift.numpy(), expm(np.block([[a, e[:, None]], [np.zeros((1, 3))]]) * 0.01)[:2, 2],
                               rtol=1e-12)


def test_gradcheck_block_with_respect_to_physical_parameters() -> None:
    params = vehicle_parameters(VP, trainable=["cf", "cr", "izz"])
    block = LTIBlock(SingleTrack(), params, DT, horizon=12, hold="foh", scaling=vehicle_scaling())
    x0, u = torch.randn(2, 2, dtype=torch.float64), torch.randn(2, 13, 2, dtype=torch.float64)
    names = [f"parameters_.raw.{n}" for n in ("cf", "cr", "izz")]

    def fn(*raw_values):
        return torch.func.functional_call(block, dict(zip(names, raw_values)), (x0, u))

    inputs = tuple(params.raw[n.rsplit(".", 1)[1]].detach().clone().requires_grad_() for n in names)
    grads = torch.autograd.grad(fn(*inputs).sum(), inputs)
    assert all(g.abs() > 0 for g in grads)  # the output really depends on every parameter
    assert torch.autograd.gradcheck(fn, inputs)


def test_trainable_parameters_get_gradients_frozen_do_not() -> None:
    params = vehicle_parameters(VP, trainable=["cf"])
    block = LTIBlock(SingleTrack(), params, DT, horizon=100, scaling=vehicle_scaling())
    loss = block(torch.zeros(4, 2, dtype=torch.float64), torch.randn(4, 100, 2, dtype=torch.float64)).square().mean()
    loss.backward()
    assert params.raw["cf"].grad is not None and params.raw["cf"].grad.abs() > 0
    assert params.raw["cr"].grad is None
    assert params.trainable_names == ("cf",)


def test_frozen_lifted_matrices_are_cached_and_refreshed_on_change() -> None:
    params = vehicle_parameters(VP)
    block = LTIBlock(SingleTrack(), params, DT, horizon=100, scaling=vehicle_scaling())
    first, _ = block.lifted(torch.float32)
    assert block.lifted(torch.float32)[0] is first
    params.set_values({"cf": 120000.0})
    second, _ = block.lifted(torch.float32)
    assert second is not first and not torch.equal(second.b, first.b)
    block.set_scaling(dataclasses.replace(vehicle_scaling(),
                                          input_std=torch.tensor([0.05, 0.003], dtype=torch.float64)))
    assert block.lifted(torch.float32)[0] is not second


def test_positive_parameters_stay_positive_and_bad_values_are_refused() -> None:
    params = vehicle_parameters(VP, trainable=["mass"])
    with torch.no_grad():
        params.raw["mass"].sub_(50.0)  # a huge optimizer step
    assert params.value("mass").item() > 0
    with pytest.raises(ValueError, match="positive"):
        ParameterSpec("cf", -1.0, "N/rad")
    with pytest.raises(ValueError, match="positive"):
        VehicleParameters(mass=0.0)
    with pytest.raises(KeyError, match="known"):
        vehicle_parameters(VP, trainable=["cornering"])


def test_unstable_parameters_are_named() -> None:
    # strong oversteer (cr lr << cf lf) above the critical speed
    bad = dataclasses.replace(VP, cr=20000.0, velocity=60.0)
    block = LTIBlock(SingleTrack(), vehicle_parameters(bad), DT)
    with pytest.raises(UnstablePhysicsError, match="unstable"):
        block.check_stable()
    LTIBlock(SingleTrack(), vehicle_parameters(VP), DT).check_stable()


def test_float32_block_matches_float64() -> None:
    block = LTIBlock(SingleTrack(), vehicle_parameters(VP), DT, horizon=100, scaling=vehicle_scaling())
    x0, u = torch.randn(8, 2, dtype=torch.float64), torch.randn(8, 100, 2, dtype=torch.float64)
    ref = block(x0, u)
    out = block(x0.float(), u.float())
    assert out.dtype == torch.float32
    assert ((out.double() - ref).norm() / ref.norm()).item() < 1e-5


@pytest.mark.parametrize("hold", ["zoh", "foh", "cubic"])
def test_normalizing_before_the_hold_equals_eq_5_to_8(hold: str) -> None:
    """One exponential of the rescaled generator (``NormalizingMaps``) = discretize, then eq. 6-8."""
    g = torch.Generator().manual_seed(4)
    r = lambda *s: torch.randn(*s, generator=g, dtype=torch.float64)  # noqa: E731
    a, b, c, d = r(3, 3) - 2 * torch.eye(3, dtype=torch.float64), r(3, 2), r(4, 3), r(4, 2)
    scaling = Scaling(r(3), r(3).abs() + 0.1, r(2), r(2).abs() + 0.1, r(4), r(4).abs() + 0.1)
    e = r(3)
    expected = normalize(discretize(a, b, 0.05, hold, e), c, d, scaling)
    maps = NormalizingMaps.build(scaling, 0.05, hold, torch.float64)
    rows, out = maps.state_rows(a, b, e), maps.output_rows(c, d)
    batched = maps.state_rows(torch.stack([a, a]), torch.stack([b, b]), torch.stack([e, e]))  # one matrix_exp
    torch.testing.assert_close(batched, torch.stack([rows, rows]), rtol=1e-13, atol=1e-14)
    taps = torch.cat(expected.b_taps, dim=-1)
    got = (rows[:, :3], rows[:, 3:-1], rows[:, -1], out[:, :3], out[:, 3:-1], out[:, -1])
    for ours, ref in zip(got, (expected.a, taps, expected.h, expected.c, expected.d, expected.g)):
        torch.testing.assert_close(ours, ref, rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("hold", ["zoh", "foh", "cubic"])
def test_trainable_one_node_window_equals_cached_frozen_path(hold: str) -> None:
    """The trainable window (``simulate_from_rows``) and the frozen cached product agree, gradients too."""
    trained = LTIBlock(SingleTrack(), vehicle_parameters(VP, trainable=["cf"]), DT, horizon=20, hold=hold,
                       scaling=vehicle_scaling())
    frozen = LTIBlock(SingleTrack(), vehicle_parameters(VP), DT, horizon=20, hold=hold, scaling=vehicle_scaling())
    x0 = torch.randn(3, 2, dtype=torch.float64, requires_grad=True)
    u = torch.randn(3, 20 + trained.extra_inputs, 2, dtype=torch.float64, requires_grad=True)
    weights = torch.randn(3, 20, 2, dtype=torch.float64)
    ours, ref = trained(x0, u), frozen(x0, u)
    torch.testing.assert_close(ours, ref, rtol=1e-12, atol=1e-12)
    grads = torch.autograd.grad((ours * weights).sum(), (x0, u))
    expected = torch.autograd.grad((ref * weights).sum(), (x0, u))
    for got, want in zip(grads, expected):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)


def test_frozen_values_carry_no_graph() -> None:
    params = vehicle_parameters(VP, trainable=["cf"])
    values = params.values(("mass", "cf", "rws_ratio"), torch.float32)
    assert values["cf"].requires_grad and not values["mass"].requires_grad
    assert values["rws_ratio"].item() == pytest.approx(VP.rws_ratio)
    assert values["mass"].item() == pytest.approx(VP.mass)


def test_signed_parameters_step_relative_to_their_nominal_size() -> None:
    """rws_ratio (signed, ~0.1) is stored divided by |nominal|: an optimizer step of 0.01 on the
    raw value moves it by 1 %, as for the log-stored positive parameters."""
    params = vehicle_parameters(dataclasses.replace(VP, rws_ratio=0.1), trainable=["rws_ratio", "cf"])
    with torch.no_grad():
        params.raw["rws_ratio"].add_(0.01)
        params.raw["cf"].add_(0.01)
    values = params.as_floats()
    assert values["rws_ratio"] == pytest.approx(0.101, rel=1e-12)
    assert values["cf"] == pytest.approx(VP.cf * np.exp(0.01), rel=1e-12)
    params.set_values({"rws_ratio": -0.05})
    assert params.value("rws_ratio").item() == pytest.approx(-0.05)
    assert params.values(("rws_ratio", "cf"))["rws_ratio"].item() == pytest.approx(-0.05)
