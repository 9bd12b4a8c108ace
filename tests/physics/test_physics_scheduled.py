"""Scheduled (per-sample) physics and the output convention: exact against a per-sample recursion."""

from collections.abc import Mapping

import numpy as np
import pytest
import scipy.linalg
import torch
from torch import Tensor

from hypa.physics import (
    LTIBlock,
    LTIModel,
    ParameterSpec,
    PhysicalParameters,
    Scaling,
    SchedulingError,
    StateSpace,
    affine_scan,
)
from hypa.physics.scheduled import simulate_scheduled, simulate_scheduled_recursive
from hypa.vehicle import SingleTrack, vehicle_parameters

from test_physics_block import DT, VP, vehicle_scaling


class AcceleratedMass(LTIModel):
    """A mass-spring-damper measured by position and acceleration: the acceleration has feedthrough.

    y = [q, q̈] with q̈ = (F - k q - d q̇ + F0) / m, so C = [[1, 0], [-k/m, -d/m]], D = [[0], [1/m]] and
    the constant F0/m of the acceleration is a drift e on the state only (not an output offset).
    """

    state_names = ("position", "velocity")
    input_names = ("force",)
    output_names = ("position", "acceleration")
    parameters = (ParameterSpec("mass", 2.0, "kg"), ParameterSpec("stiffness", 50.0, "N/m"),
                  ParameterSpec("damping", 1.5, "N s/m"), ParameterSpec("offset_force", 0.7, "N", positive=False))

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        m, k, d, f0 = p["mass"], p["stiffness"], p["damping"], p["offset_force"]
        zero, one = torch.zeros_like(m), torch.ones_like(m)
        a = torch.stack([torch.stack([zero, one]), torch.stack([-k / m, -d / m])])
        b = torch.stack([zero, 1 / m]).reshape(2, 1)
        c = torch.stack([torch.stack([one, zero]), a[1]])
        return StateSpace(a, b, c, torch.stack([zero, 1 / m]).reshape(2, 1), torch.stack([zero, f0 / m]))


def numpy_matrices(model: LTIModel, values: Mapping[str, float]) -> tuple[np.ndarray, ...]:
    ss = model.matrices({k: torch.tensor(v, dtype=torch.float64) for k, v in values.items()})
    e = np.zeros(ss.a.shape[0]) if ss.e is None else ss.e.numpy()
    return ss.a.numpy(), ss.b.numpy(), ss.c.numpy(), ss.d.numpy(), e


def per_sample_reference(model: LTIModel, values: dict[str, float], scheduled: str | None, rho: np.ndarray,
                         x0: np.ndarray, u: np.ndarray, hold: str, dt: float, steps: int) -> np.ndarray:
    """ŷ_j = C(ρ_j) x_j + D(ρ_j) u_j, j = 1..steps, with x_{j+1} from scipy's expm at ρ_j (physical units)."""
    def at(j: int) -> tuple[np.ndarray, ...]:
        return numpy_matrices(model, values if scheduled is None else {**values, scheduled: rho[j]})

    x, ys = x0.copy(), []
    n, m = x0.shape[0], u.shape[1]
    for j in range(steps):
        a, b, _, _, e = at(j)
        gen = np.zeros((n + 2 * m + 1, n + 2 * m + 1))  # [x, u_j, ramp, 1]: FOH; ZOH ignores the ramp
        gen[:n, :n], gen[:n, n : n + m], gen[:n, -1] = a * dt, b * dt, e * dt
        gen[n : n + m, n + m : n + 2 * m] = np.eye(m)
        big = scipy.linalg.expm(gen)
        if hold == "zoh":
            x = big[:n, :n] @ x + big[:n, n : n + m] @ u[j] + big[:n, -1]
        else:
            e1, e2 = big[:n, n : n + m], big[:n, n + m : n + 2 * m]
            x = big[:n, :n] @ x + (e1 - e2) @ u[j] + e2 @ u[j + 1] + big[:n, -1]
        _, _, c, d, _ = at(min(j + 1, len(rho) - 1))
        ys.append(c @ x + d @ u[j + 1] if j + 1 < len(u) else c @ x)
    return np.array(ys)


def velocity_profile(batch: int, length: int, seed: int) -> Tensor:
    g = torch.Generator().manual_seed(seed)
    ramp = torch.linspace(5.0, 30.0, length, dtype=torch.float64)
    return (ramp + 0.5 * torch.rand(batch, length, generator=g, dtype=torch.float64))[..., None]  # (B, L, 1)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_scheduled_single_track_is_exact_against_the_per_sample_recursion(hold: str) -> None:
    block = LTIBlock(SingleTrack(), vehicle_parameters(VP), DT, horizon=50, hold=hold, scaling=vehicle_scaling(),
                     scheduled=["velocity"])
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(3, 2, generator=g, dtype=torch.float64) * torch.tensor([0.1, 0.01], dtype=torch.float64)
    u = torch.randn(3, 60, 2, generator=g, dtype=torch.float64) * 0.02
    v = velocity_profile(3, 60, 1)
    ours = block.simulate_physical(x0, u, v).numpy()
    assert ours.shape == (3, 60 - block.extra_inputs, 2)
    for i in range(3):
        ref = per_sample_reference(SingleTrack(), VP.as_dict(), "velocity", v[i, :, 0].numpy(), x0[i].numpy(),
                                   u[i].numpy(), hold, DT, ours.shape[1])
        assert np.abs(ours[i] - ref).max() / np.abs(ref).max() < 1e-10


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("scheduled", [None, "stiffness"])
def test_feedthrough_pairs_d_with_the_input_of_the_same_sample(hold: str, scheduled: str | None) -> None:
    """ŷ_j = C x_j + D u_j (+ drift e): constant (lifted) and scheduled blocks against scipy."""
    model = AcceleratedMass()
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    scaling = Scaling(t(0.01, 0.0), t(0.05, 0.4), t(0.2), t(1.5), t(0.01, 0.3), t(0.05, 3.0))
    block = LTIBlock(model, PhysicalParameters(model.parameters), dt=0.01, horizon=20, hold=hold, scaling=scaling,
                     scheduled=(scheduled,) if scheduled else ())
    assert block.feedthrough and block.extra_inputs == 1
    rng = np.random.default_rng(2)
    x0, force = rng.normal(size=(2, 2)) * 0.1, rng.normal(size=(2, 48, 1))
    stiffness = 50.0 + 20.0 * rng.random(size=(2, 48, 1))
    rho = torch.tensor(stiffness) if scheduled else None
    ours = block.simulate_physical(torch.tensor(x0), torch.tensor(force), rho).numpy()
    assert ours.shape == (2, 47, 2)
    values = model.nominal_values()
    for i in range(2):
        ref = per_sample_reference(model, values, scheduled, stiffness[i, :, 0], x0[i], force[i], hold, 0.01, 47)
        np.testing.assert_allclose(ours[i], ref, rtol=1e-10, atol=1e-10)
    # ``output`` of the states and the same samples' inputs is ``forward``
    un = (torch.tensor(force) - block.input_mean) / block.input_std
    x0n = (torch.tensor(x0) - block.state_mean) / block.state_std
    states = block.states(x0n, un, rho)
    again = block.output(states, un[:, 1:], None if rho is None else rho[:, 1:])
    torch.testing.assert_close(again, block(x0n, un, rho), rtol=1e-12, atol=1e-12)


def test_without_feedthrough_the_window_takes_t_minus_1_extra_inputs() -> None:
    for hold, extra in (("zoh", 0), ("foh", 1)):
        block = LTIBlock(SingleTrack(), vehicle_parameters(VP), DT, horizon=10, hold=hold)
        assert not block.feedthrough and block.extra_inputs == extra
        assert block(torch.zeros(2, 2), torch.zeros(2, 10 + extra, 2)).shape == (2, 10, 2)


def test_fused_training_window_is_used_when_s_equals_horizon(monkeypatch: pytest.MonkeyPatch) -> None:
    """With feedthrough, u has S + 1 samples and the one-node path still runs (and matches the frozen one)."""
    from hypa.physics import simulation

    calls = []
    fused = simulation.simulate_from_rows
    monkeypatch.setattr(simulation, "simulate_from_rows", lambda *a: calls.append(1) or fused(*a))
    model = AcceleratedMass()
    trained = LTIBlock(model, PhysicalParameters(model.parameter_specs({})), 0.01, horizon=20)
    trained.parameters_.set_trainable(["stiffness"])
    frozen = LTIBlock(model, PhysicalParameters(model.parameters), 0.01, horizon=20)
    x0, u = torch.randn(3, 2, dtype=torch.float64), torch.randn(3, 21, 1, dtype=torch.float64)
    ours = trained(x0, u)
    assert calls == [1]
    torch.testing.assert_close(ours, frozen(x0, u), rtol=1e-12, atol=1e-12)
    ours.square().sum().backward()
    assert trained.parameters_.raw["stiffness"].grad.abs() > 0


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_scheduled_at_a_constant_value_equals_the_lifted_block(hold: str) -> None:
    params = vehicle_parameters(VP, trainable=["cf"])
    lifted = LTIBlock(SingleTrack(), params, DT, horizon=30, hold=hold, scaling=vehicle_scaling())
    scheduled = LTIBlock(SingleTrack(), params, DT, horizon=30, hold=hold, scaling=vehicle_scaling(),
                         scheduled=["velocity"])
    x0, u = torch.randn(4, 2, dtype=torch.float64), torch.randn(4, 75, 2, dtype=torch.float64)
    v = torch.full((4, 75, 1), VP.velocity, dtype=torch.float64)
    ref, ours = lifted(x0, u), scheduled(x0, u, v)
    torch.testing.assert_close(ours, ref, rtol=1e-11, atol=1e-11)
    g_ref = torch.autograd.grad(ref.square().sum(), params.raw["cf"])
    g_ours = torch.autograd.grad(ours.square().sum(), params.raw["cf"])
    torch.testing.assert_close(g_ours, g_ref, rtol=1e-9, atol=0.0)


def test_gradcheck_scheduled_block() -> None:
    params = vehicle_parameters(VP, trainable=["cf", "izz"])
    block = LTIBlock(SingleTrack(), params, DT, horizon=4, hold="foh", scaling=vehicle_scaling(),
                     scheduled=["velocity"])
    names = [f"parameters_.raw.{n}" for n in ("cf", "izz")]
    g = torch.Generator().manual_seed(3)
    x0 = torch.randn(2, 2, generator=g, dtype=torch.float64, requires_grad=True)
    u = torch.randn(2, 6, 2, generator=g, dtype=torch.float64, requires_grad=True)
    v = velocity_profile(2, 6, 4).requires_grad_()

    def fn(cf, izz, x0, u, v):
        return torch.func.functional_call(block, dict(zip(names, (cf, izz))), (x0, u, v))

    raw = tuple(params.raw[n].detach().clone().requires_grad_() for n in ("cf", "izz"))
    grads = torch.autograd.grad(fn(*raw, x0, u, v).sum(), (*raw, x0, u, v))
    assert all(bool(gr.abs().max() > 0) for gr in grads)  # every input really matters
    assert torch.autograd.gradcheck(fn, (*raw, x0, u, v))


def test_zoh_on_the_scheduling_signal_against_a_fine_step_reference() -> None:
    """The only approximation: matrices frozen at ρ_j over sample j. Reference: 64 substeps per sample,
    each exact at the substep's midpoint velocity (v interpolated linearly), inputs held / ramped.
    Measured (v 5 -> 30 m/s in 4 s, random steering): 0.45 % (ZOH) / 0.49 % (FOH) of the states' RMS."""
    model, length, substeps = SingleTrack(), 129, 64
    v = np.linspace(5.0, 30.0, length)
    u = np.random.default_rng(0).normal(size=(length, 2)) * 0.02
    for hold, measured in (("zoh", 0.0045), ("foh", 0.0049)):
        block = LTIBlock(model, vehicle_parameters(VP), DT, horizon=50, hold=hold, scheduled=["velocity"])
        ours = block.simulate_physical(torch.zeros(1, 2, dtype=torch.float64), torch.tensor(u)[None],
                                       torch.tensor(v)[None, :, None])[0].numpy()
        steps, h = ours.shape[0], DT / substeps
        u_fine = np.repeat(u[:steps], substeps, 0) if hold == "zoh" else np.concatenate(
            [u[j] + (u[j + 1] - u[j]) * np.arange(substeps)[:, None] / substeps for j in range(steps)]
            + [u[steps:steps + 1]])
        v_mid = np.interp((np.arange(steps * substeps) + 0.5) / substeps, np.arange(length), v)
        fixed = {k: torch.tensor(x, dtype=torch.float64) for k, x in VP.as_dict().items() if k != "velocity"}

        def ab(s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            ss = model.matrices({**fixed, "velocity": s})  # noqa: B023 -- vmap calls it in this iteration
            return ss.a, ss.b

        a, b = torch.func.vmap(ab)(torch.tensor(v_mid))
        gen = np.zeros((len(v_mid), 6, 6))  # one exact FOH substep each (a held input is a flat ramp)
        gen[:, :2, :2], gen[:, :2, 2:4], gen[:, 2:4, 4:] = a.numpy() * h, b.numpy() * h, np.eye(2)
        big = scipy.linalg.expm(gen)
        x, ref = np.zeros(2), []
        for s in range(steps * substeps):
            e1, e2 = big[s, :2, 2:4], big[s, :2, 4:]
            end = u_fine[s] if hold == "zoh" else u_fine[s + 1]
            x = big[s, :2, :2] @ x + (e1 - e2) @ u_fine[s] + e2 @ end
            if (s + 1) % substeps == 0:
                ref.append(x)
        error = np.sqrt(((ours - np.array(ref)) ** 2).sum() / (np.array(ref) ** 2).sum())
        assert measured * 0.9 < error < measured * 1.1, (hold, error)


@pytest.mark.parametrize("steps", [1, 2, 7, 64, 100])
def test_affine_scan_equals_the_loop(steps: int) -> None:
    g = torch.Generator().manual_seed(steps)
    phi = 0.5 * torch.randn(3, steps, 4, 4, generator=g, dtype=torch.float64)
    c = torch.randn(3, steps, 4, generator=g, dtype=torch.float64)
    prefix, offset = affine_scan(phi, c)
    p, q = torch.eye(4, dtype=torch.float64).expand(3, 4, 4), torch.zeros(3, 4, dtype=torch.float64)
    for j in range(steps):
        p, q = phi[:, j] @ p, (phi[:, j] @ q[..., None]).squeeze(-1) + c[:, j]
        torch.testing.assert_close(prefix[:, j], p, rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(offset[:, j], q, rtol=1e-12, atol=1e-12)
    rows = torch.cat([phi, torch.randn(3, steps, 4, 3, generator=g, dtype=torch.float64)], -1)
    x0, u = torch.randn(3, 4, dtype=torch.float64), torch.randn(3, steps + 1, 1, dtype=torch.float64)
    torch.testing.assert_close(simulate_scheduled(rows, 2, x0, u), simulate_scheduled_recursive(rows, 2, x0, u),
                               rtol=1e-12, atol=1e-12)


class ScalarOnly(SingleTrack):
    """Reads a parameter as a python float: fine for one sample, impossible per sample under vmap."""

    def matrices(self, p):
        if float(p["velocity"]) < 0:
            raise ValueError("reversing")
        return super().matrices(p)


def test_scheduling_errors_are_one_line() -> None:
    block = LTIBlock(SingleTrack(), vehicle_parameters(VP), DT, horizon=10, scheduled=["velocity"])
    x0, u = torch.zeros(2, 2, dtype=torch.float64), torch.zeros(2, 10, 2, dtype=torch.float64)
    cases = [
        (lambda: block(x0, u), r"schedules \['velocity'\]: give scheduling"),
        (lambda: block(x0, u, torch.ones(2, 9, 1, dtype=torch.float64)), r"must be \(B, >= 10, 1\)"),
        (lambda: block(x0, u, torch.ones(2, 10, 2, dtype=torch.float64)), r"must be \(B, >= 10, 1\)"),
        (lambda: LTIBlock(SingleTrack(), vehicle_parameters(VP), DT)(x0, u, u[..., :1]), "no scheduled parameters"),
        (lambda: LTIBlock(SingleTrack(), vehicle_parameters(VP), DT, scheduled=["speed"]),
         r"cannot schedule \['speed'\]; its parameters are \['mass'"),
        (lambda: LTIBlock(ScalarOnly(), vehicle_parameters(VP), DT, scheduled=["velocity"])(
            x0, u, torch.ones(2, 10, 1, dtype=torch.float64)), "ScalarOnly.matrices cannot be evaluated per sample"),
    ]
    for call, message in cases:
        with pytest.raises(SchedulingError, match=message) as error:
            call()
        assert "\n" not in str(error.value)
