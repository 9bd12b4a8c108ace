"""Discretization against scipy's exact references, and gradients through it."""

import numpy as np
import pytest
import torch
from scipy.signal import cont2discrete, dlsim, lsim

from hypa.physics import discretize, simulate_recursive
from hypa.physics.exponential import expm


def random_stable(n: int, m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n))
    a -= (np.max(np.linalg.eigvals(a).real) + rng.uniform(0.2, 2.0)) * np.eye(n)
    return a, rng.normal(size=(n, m))


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_matches_scipy_cont2discrete(seed: int, hold: str) -> None:
    n, m, dt = 2 + seed % 3, 1 + seed % 2, 0.03125
    a, b = random_stable(n, m, seed)
    ours = discretize(torch.tensor(a), torch.tensor(b), dt, hold)
    ad, bd, cd, dd, _ = cont2discrete((a, b, np.eye(n), np.zeros((n, m))), dt, method=hold)
    np.testing.assert_allclose(ours.phi.numpy(), ad, rtol=0, atol=1e-10)
    if hold == "zoh":
        np.testing.assert_allclose(ours.taps[0].numpy(), bd, rtol=0, atol=1e-10)
        return
    # scipy's FOH realization uses the state ξ = x - D u; compare the simulated x instead.
    rng = np.random.default_rng(seed + 100)
    u, x0 = rng.normal(size=(60, m)), rng.normal(size=n)
    _, x_scipy, _ = dlsim((ad, bd, cd, dd, dt), u, x0=x0 - dd @ u[0])
    x_ours = simulate_recursive(ours.phi, ours.taps, torch.zeros(n, dtype=torch.float64),
                                torch.tensor(x0)[None], torch.tensor(u)[None])[0].numpy()
    np.testing.assert_allclose(x_ours, x_scipy[1:], rtol=0, atol=1e-10)


def _hold_errors(u_fine: np.ndarray, t_fine: np.ndarray, every: int) -> dict[str, float]:
    """Max error of each hold at 32 Hz against the continuous response (relative to its peak)."""
    a, b = np.array([[-7.0, 28.0], [-1.0, -5.5]]), np.array([[64.5], [2.4]])
    _, _, x_fine = lsim((a, b, np.eye(2), np.zeros((2, 1))), u_fine, t_fine)
    x_true, u = x_fine[::every], u_fine[::every, None]
    errors = {}
    for hold in ("zoh", "foh"):
        d = discretize(torch.tensor(a), torch.tensor(b), t_fine[every], hold)
        u_hold = u if hold == "foh" else u[:-1]  # FOH also reads the sample after the step
        x = simulate_recursive(d.phi, d.taps, torch.zeros(2, dtype=torch.float64),
                               torch.zeros(1, 2, dtype=torch.float64), torch.tensor(u_hold)[None])[0].numpy()
        errors[hold] = float(np.abs(x - x_true[1:]).max() / np.abs(x_true).max())
    return errors


def test_foh_is_exact_for_piecewise_linear_input() -> None:
    t_fine = np.linspace(0, 4, 4 * 32 * 64 + 1)
    samples = np.random.default_rng(0).normal(size=4 * 32 + 1)
    u_fine = np.interp(t_fine, t_fine[::64], samples)  # linear between the 32 Hz samples
    assert _hold_errors(u_fine, t_fine, 64)["foh"] < 1e-8


def test_zoh_leaves_percent_error_on_smooth_input_foh_does_not() -> None:
    """A 1 Hz sine sampled at 32 Hz is not held: ZOH lags by half a sample (a few %)."""
    t_fine = np.linspace(0, 4, 4 * 32 * 64 + 1)
    errors = _hold_errors(np.sin(2 * np.pi * t_fine), t_fine, 64)
    assert errors["zoh"] > 0.02
    assert errors["foh"] < 0.2 * errors["zoh"]


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_gradcheck_discretization(hold: str) -> None:
    a, b = random_stable(3, 2, 7)
    a, b = torch.tensor(a, requires_grad=True), torch.tensor(b, requires_grad=True)

    def fn(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, ...]:
        d = discretize(a, b, 0.05, hold)
        return (d.phi, *d.taps)

    assert torch.autograd.gradcheck(fn, (a, b))


def test_bad_arguments_raise() -> None:
    a, b = torch.eye(2), torch.ones(2, 1)
    with pytest.raises(ValueError, match="hold"):
        discretize(a, b, 0.1, "tustin")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="positive"):
        discretize(a, b, 0.0)
    with pytest.raises(ValueError, match="A must be"):
        discretize(torch.eye(3), b, 0.1)


@pytest.mark.parametrize("scale", [0.0, 1e-3, 1.0, 30.0])
def test_expm_matches_torch_values_and_gradients(scale: float) -> None:
    """The custom exponential (and its block-matrix adjoint) against torch's taped one."""
    g = torch.Generator().manual_seed(3)
    m = (scale * torch.randn(5, 5, generator=g, dtype=torch.float64)).requires_grad_()
    weights = torch.randn(5, 5, generator=g, dtype=torch.float64)
    ours, ref = expm(m), torch.linalg.matrix_exp(m)
    torch.testing.assert_close(ours, ref, rtol=1e-13, atol=1e-13 * ref.abs().max().item())
    (grad,) = torch.autograd.grad((ours * weights).sum(), m)
    (expected,) = torch.autograd.grad((ref * weights).sum(), m)
    torch.testing.assert_close(grad, expected, rtol=1e-12, atol=1e-12 * expected.abs().max().item())
    assert torch.autograd.gradcheck(expm, (m,))


def test_expm_float32_and_refusals() -> None:
    m = torch.randn(4, 4, dtype=torch.float64)
    torch.testing.assert_close(expm(m.float()).double(), torch.linalg.matrix_exp(m), rtol=1e-5, atol=1e-5)
    assert torch.isnan(expm(torch.full((2, 2), float("inf")))).all()
    with pytest.raises(ValueError, match="square"):
        expm(torch.zeros(2, 3))


def test_expm_of_a_stack_matches_torch_values_and_gradients() -> None:
    """A stack (one matrix per sample of a scheduled block) shares one scaling; the values and adjoint stay exact."""
    g = torch.Generator().manual_seed(5)
    scales = torch.tensor([1e-3, 0.3, 1.0, 30.0], dtype=torch.float64)[:, None, None, None]  # very different norms
    m = (scales * torch.randn(4, 3, 5, 5, generator=g, dtype=torch.float64)).requires_grad_()
    weights = torch.randn(4, 3, 5, 5, generator=g, dtype=torch.float64)
    ours, ref = expm(m), torch.linalg.matrix_exp(m)
    assert ours.shape == (4, 3, 5, 5)
    for i in range(4):  # relative to each matrix's own size, however small
        torch.testing.assert_close(ours[i], ref[i], rtol=1e-12, atol=1e-12 * ref[i].abs().max().item())
    (grad,) = torch.autograd.grad((ours * weights).sum(), m)
    (expected,) = torch.autograd.grad((ref * weights).sum(), m)
    torch.testing.assert_close(grad, expected, rtol=1e-10, atol=1e-10 * expected.abs().max().item())
    assert torch.autograd.gradcheck(expm, (m[:2, :1, :3, :3].detach().clone().requires_grad_(),))
    stack = torch.randn(6, 4, 4, dtype=torch.float64)
    torch.testing.assert_close(expm(stack.float()).double(), torch.linalg.matrix_exp(stack), rtol=1e-5, atol=1e-5)
