"""The scheduled block's fast parts, exact against references: the per-sample hold (φ-functions of
the n x n A dt, ``hold_exponential``) and the scan's hand-written adjoint (``_AffineStates``)."""

import numpy as np
import pytest
import scipy.linalg
import torch

from hypa.physics import LTIBlock
from hypa.physics.exponential import hold_exponential, phi_functions
from hypa.physics.scan import _AffineStates
from hypa.physics.scheduled import (
    forced_terms,
    simulate_scheduled,
    simulate_scheduled_recursive,
)
from hypa.vehicle import SingleTrack, vehicle_parameters

from test_physics_block import DT, VP, vehicle_scaling

F64 = {"dtype": torch.float64}


def phi_reference(m: np.ndarray) -> list[np.ndarray]:
    """φ_0, φ_1, φ_2 of m from one scipy exponential: e^[[M, I, 0], [0, 0, I], [0, 0, 0]] = [[φ_0, φ_1, φ_2], ...]."""
    k = m.shape[0]
    big = np.zeros((3 * k, 3 * k))
    big[:k, :k], big[:k, k : 2 * k], big[k : 2 * k, 2 * k :] = m, np.eye(k), np.eye(k)
    e = scipy.linalg.expm(big)
    return [e[:k, :k], e[:k, k : 2 * k], e[:k, 2 * k :]]


SPECIAL = {  # matrices where closed forms of φ_1, φ_2 cancel or divide by zero; the series does not
    "zero": np.zeros((2, 2)),
    "double integrator": np.array([[0.0, 1.0], [0.0, 0.0]]),
    "repeated eigenvalue": np.array([[-0.7, 1.0], [0.0, -0.7]]),
    "near-repeated": np.array([[-0.7, 1.0], [1e-12, -0.7]]),
    "complex pair": np.array([[-0.2, 3.0], [-3.0, -0.2]]),
    "one eigenvalue near 0": np.array([[-1e-9, 1.0], [0.0, -2.5]]),
    "stiff": np.array([[-40.0, 0.0], [1.0, -0.01]]),
}


@pytest.mark.parametrize("name", list(SPECIAL))
def test_phi_functions_match_scipy_on_special_matrices(name: str) -> None:
    m = SPECIAL[name]
    ref = phi_reference(m)
    one = phi_functions(torch.tensor(m), 2)
    stack = phi_functions(torch.tensor(np.stack([m, 0.5 * m, np.zeros((2, 2))])), 2)  # shares one scaling
    for k in range(3):
        scale = max(1.0, np.abs(ref[k]).max())
        np.testing.assert_allclose(one[k].numpy(), ref[k], rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(stack[k][0].numpy(), ref[k], rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(stack[k][1].numpy(), phi_reference(0.5 * m)[k], rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(stack[k][2].numpy(), np.eye(2) / [1, 1, 2][k], rtol=0, atol=1e-15)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_phi_functions_gradcheck(order: int) -> None:
    g = torch.Generator().manual_seed(order)
    one = (1.5 * torch.randn(3, 3, generator=g, **F64)).requires_grad_()  # > θ: squarings taken
    stack = (torch.tensor([0.01, 0.4, 3.0], **F64)[:, None, None] * torch.randn(3, 3, 3, generator=g, **F64))
    assert torch.autograd.gradcheck(lambda m: phi_functions(m, order), (one,))
    assert torch.autograd.gradcheck(lambda m: phi_functions(m, order), (stack.requires_grad_(),))


def test_phi_functions_refuse_and_propagate_nan() -> None:
    with pytest.raises(ValueError, match="φ_0 to φ_2"):
        phi_functions(torch.zeros(2, 2), 3)
    with pytest.raises(ValueError, match="square"):
        phi_functions(torch.zeros(2, 3), 1)
    bad = torch.full((2, 2, 2), float("inf"), requires_grad=True)
    out = phi_functions(bad, 1)
    assert all(bool(torch.isnan(p).all()) for p in out)
    (grad,) = torch.autograd.grad(out[1].sum(), bad)
    assert bool(torch.isnan(grad).all())


def holds(n: int, m: int) -> dict[str, np.ndarray]:
    """Bottom rows [0, N] (r, n + r) of M: ZOH (N = 0), FOH as ``discretize`` writes it (value, slope),
    and FOH in the end-point basis of ``NormalizingMaps`` (N = [[-I, I], [-I, I]]), each with a drift column."""
    r = 2 * m + 1
    zoh, ramp, ends = (np.zeros((r, n + r)) for _ in range(3))
    ramp[:m, n + m : n + 2 * m] = np.eye(m)
    ends[: 2 * m, n : n + 2 * m] = np.block([[-np.eye(m), np.eye(m)], [-np.eye(m), np.eye(m)]])
    return {"zoh": zoh, "foh value-slope": ramp, "foh end points": ends}


@pytest.mark.parametrize("hold", list(holds(2, 1)))
@pytest.mark.parametrize("scale", [1e-3, 0.6, 8.0])
def test_hold_exponential_is_the_top_rows_of_expm(hold: str, scale: float) -> None:
    """Both ways it chooses (e^M for one system, φ-functions for a stack) against scipy's e^M[:n]
    (to 1e-12 of its largest entry: at scale 8, e^M reaches 1e10 and scipy's own round-off shows)."""
    n, m, samples = 3, 2, 4
    bottom = holds(n, m)[hold]
    g = torch.Generator().manual_seed(int(scale * 10))
    top = scale * torch.randn(n, n + 2 * m + 1, samples, generator=g, **F64)
    stacked = hold_exponential(top, torch.tensor(bottom))
    assert stacked.shape == top.shape
    for i in range(samples):
        ref = scipy.linalg.expm(np.concatenate([top[..., i].numpy(), bottom]))[:n]
        one = hold_exponential(top[..., i], torch.tensor(bottom)).numpy()
        np.testing.assert_allclose(one, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
        np.testing.assert_allclose(stacked[..., i].numpy(), ref, rtol=0, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("hold", list(holds(2, 1)))
def test_hold_exponential_gradcheck(hold: str) -> None:
    bottom = torch.tensor(holds(2, 1)[hold])
    g = torch.Generator().manual_seed(7)
    stack = (torch.tensor([0.02, 0.7, 2.5], **F64) * torch.randn(2, 5, 3, generator=g, **F64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda t: hold_exponential(t, bottom), (stack,))
    assert torch.autograd.gradcheck(lambda t: hold_exponential(t, bottom), (stack[..., 2].detach().requires_grad_(),))


def test_hold_exponential_refuses_mismatched_rows() -> None:
    with pytest.raises(ValueError, match="bottom rows"):
        hold_exponential(torch.zeros(2, 5, 3), torch.zeros(2, 5))


@pytest.mark.parametrize("steps", [1, 2, 3, 8, 13])
def test_affine_states_adjoint_gradcheck(steps: int) -> None:
    """The scan's hand-written adjoint (the forward's products reused) against finite differences."""
    g = torch.Generator().manual_seed(steps)
    phi = (0.6 * torch.randn(3, 3, 2, steps, generator=g, **F64)).requires_grad_()
    c = torch.randn(3, 2, steps, generator=g, **F64).requires_grad_()
    assert torch.autograd.gradcheck(_AffineStates.apply, (phi, c))


@pytest.mark.parametrize("n_taps", [1, 2])
def test_simulate_scheduled_values_and_gradients_equal_the_loop(n_taps: int) -> None:
    g = torch.Generator().manual_seed(n_taps)
    n, m, steps = 2, 2, 37
    rows = torch.cat([0.5 * torch.randn(3, steps, n, n, generator=g, **F64),
                      torch.randn(3, steps, n, n_taps * m + 1, generator=g, **F64)], -1).requires_grad_()
    x0 = torch.randn(3, n, generator=g, **F64).requires_grad_()
    u = torch.randn(3, steps + n_taps - 1, m, generator=g, **F64).requires_grad_()
    weights = torch.randn(3, steps, n, generator=g, **F64)
    ours, ref = simulate_scheduled(rows, n_taps, x0, u), simulate_scheduled_recursive(rows, n_taps, x0, u)
    torch.testing.assert_close(ours, ref, rtol=1e-12, atol=1e-12)
    for a, b in zip(torch.autograd.grad((ours * weights).sum(), (rows, x0, u)),
                    torch.autograd.grad((ref * weights).sum(), (rows, x0, u))):
        torch.testing.assert_close(a, b, rtol=1e-11, atol=1e-11)
    small = (rows[:1, :5].detach().clone().requires_grad_(), x0[:1].detach().clone().requires_grad_(),
             u[:1, : 5 + n_taps - 1].detach().clone().requires_grad_())
    assert torch.autograd.gradcheck(lambda r, x, w: simulate_scheduled(r, n_taps, x, w), small)


def test_forced_terms_per_step_equal_the_sum() -> None:
    g = torch.Generator().manual_seed(0)
    v, u = torch.randn(2, 6, 3, 5, generator=g, **F64), torch.randn(2, 7, 2, generator=g, **F64)
    ours = forced_terms(v, 2, u, 6)
    window = torch.cat([u[:, :6], u[:, 1:7], torch.ones(2, 6, 1, **F64)], -1)
    torch.testing.assert_close(ours, torch.einsum("bsij,bsj->bsi", v, window), rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("hold", ["zoh", "foh", "cubic"])
def test_float32_per_sample_rows_are_float64_to_float32_precision(hold: str) -> None:
    """The race car trains in float32: its per-sample rows (degree-7 series) against float64's (degree 14)."""
    block = LTIBlock(SingleTrack(), vehicle_parameters(VP), DT, horizon=10, hold=hold, scaling=vehicle_scaling(),
                     scheduled=["velocity"])
    v = 5.0 + 30.0 * torch.rand(3, 40, 1, generator=torch.Generator().manual_seed(1), **F64)
    exact = block.normalized_rows(v)
    single = block.normalized_rows(v.float()).double()
    tolerance = 5e-6 if hold == "cubic" else 2e-6  # the cubic's taps are differences of larger terms
    assert float((single - exact).abs().max()) < tolerance * float(exact.abs().max())
