"""The lifted N-step form (eq. 9-11) against the step-by-step recursion (eq. 5)."""

import numpy as np
import pytest
import torch

from hypa.physics import lifted_matrices, matrix_powers, simulate_lifted, simulate_recursive
from hypa.physics.lifted import simulate_from_rows


def random_normalized(n: int, m: int, taps: int, seed: int, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(n, n, generator=g, dtype=torch.float64)
    a = 0.97 * a / torch.linalg.eigvals(a).abs().max()  # spectral radius 0.97: stable, slow decay
    b = tuple(torch.randn(n, m, generator=g, dtype=torch.float64) for _ in range(taps))
    h = torch.randn(n, generator=g, dtype=torch.float64)
    return a.to(dtype), tuple(t.to(dtype) for t in b), h.to(dtype)


def test_matrix_powers() -> None:
    a = torch.randn(3, 3, dtype=torch.float64) * 0.5
    powers = matrix_powers(a, 13)
    assert powers.shape == (13, 3, 3)
    for k in range(13):
        torch.testing.assert_close(powers[k], torch.linalg.matrix_power(a, k), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("horizon", [1, 2, 7, 100, 200])
@pytest.mark.parametrize("taps", [1, 2])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lifted_equals_recursion_float64(horizon: int, taps: int, seed: int) -> None:
    n, m = 2 + seed, 1 + seed % 2
    a, b, h = random_normalized(n, m, taps, seed)
    lifted = lifted_matrices(a, b, h, horizon)
    assert lifted.a.shape == (horizon * n, n)
    assert lifted.b.shape == (horizon * n, (horizon + taps - 1) * m)
    g = torch.Generator().manual_seed(seed + 10)
    x0 = torch.randn(5, n, generator=g, dtype=torch.float64)
    u = torch.randn(5, horizon + taps - 1, m, generator=g, dtype=torch.float64)
    ref = simulate_recursive(a, b, h, x0, u)
    out = simulate_lifted(lifted, x0, u)
    scale = ref.abs().max()
    assert (out - ref).abs().max() / scale < 1e-12


def test_lifted_zoh_structure_is_block_toeplitz() -> None:
    """Row i of ℬ is [Â^i B̂, ..., B̂, 0, ...]: the last input of eq. 10 is u_{k+N-1}."""
    a, (b,), h = random_normalized(2, 1, 1, 3)
    lifted = lifted_matrices(a, (b,), h, 4)
    blocks = lifted.b.reshape(4, 2, 4, 1)
    for i in range(4):
        for j in range(4):
            expected = torch.linalg.matrix_power(a, i - j) @ b if j <= i else torch.zeros(2, 1, dtype=a.dtype)
            torch.testing.assert_close(blocks[i, :, j], expected)
    h_sum = sum(torch.linalg.matrix_power(a, d) @ h for d in range(4))
    torch.testing.assert_close(lifted.h[-2:], h_sum)


@pytest.mark.parametrize("horizon", [100, 200])
def test_lifted_float32_relative(horizon: int) -> None:
    a, b, h = random_normalized(2, 2, 1, 5)
    x0, u = torch.randn(8, 2, dtype=torch.float64), torch.randn(8, horizon, 2, dtype=torch.float64)
    ref = simulate_recursive(a, b, h, x0, u)
    lifted32 = lifted_matrices(a.float(), tuple(t.float() for t in b), h.float(), horizon)
    out = simulate_lifted(lifted32, x0.float(), u.float()).double()
    assert ((out - ref).norm() / ref.norm()).item() < 1e-5


def test_gradcheck_lifting() -> None:
    a, b, h = random_normalized(2, 1, 2, 9)
    a, h = a.clone().requires_grad_(), h.clone().requires_grad_()
    b0 = b[0].clone().requires_grad_()
    x0, u = torch.randn(2, 2, dtype=torch.float64), torch.randn(2, 9, 1, dtype=torch.float64)

    def fn(a, b0, h, x0, u):
        return simulate_lifted(lifted_matrices(a, (b0, b[1]), h, 8), x0, u)

    assert torch.autograd.gradcheck(fn, (a, b0, h, x0.requires_grad_(), u.requires_grad_()))


def test_wrong_input_length_is_explained() -> None:
    a, b, h = random_normalized(2, 1, 2, 0)
    lifted = lifted_matrices(a, b, h, 10)
    with pytest.raises(ValueError, match="expected 11 input samples"):
        simulate_lifted(lifted, torch.zeros(1, 2, dtype=torch.float64), torch.zeros(1, 10, 1, dtype=torch.float64))
    with pytest.raises(ValueError, match="horizon"):
        lifted_matrices(a, b, h, 0)
    assert np.isfinite(lifted.b.numpy()).all()


def test_matrix_powers_gradient_matches_taped_recursion() -> None:
    a = (0.6 * torch.randn(3, 3, dtype=torch.float64)).requires_grad_()
    weights = torch.randn(40, 3, 3, dtype=torch.float64)
    (grad,) = torch.autograd.grad((matrix_powers(a, 40) * weights).sum(), a)
    taped, p = [torch.eye(3, dtype=torch.float64)], torch.eye(3, dtype=torch.float64)
    for _ in range(39):
        p = p @ a
        taped.append(p)
    (expected,) = torch.autograd.grad((torch.stack(taped) * weights).sum(), a)
    torch.testing.assert_close(grad, expected, rtol=1e-10, atol=1e-12)
    assert torch.autograd.gradcheck(lambda a: matrix_powers(a, 9), (a,))


def _taped_lifted(a, b_taps, h, horizon):
    """The lifted matrices assembled from plain taped ops (reference for ``_Lifting``)."""
    n, m, taps = a.shape[-1], b_taps[0].shape[-1], len(b_taps)
    powers = [torch.eye(n, dtype=a.dtype)]
    for _ in range(horizon):
        powers.append(powers[-1] @ a)
    zero = torch.zeros(n, m, dtype=a.dtype)
    rows = [torch.cat([sum((powers[i - j + t] @ b_taps[t] for t in range(taps) if t <= j <= i + t), zero)
                       for j in range(horizon + taps - 1)], dim=1) for i in range(horizon)]
    h_rows = torch.cumsum(torch.stack([p @ h for p in powers[:horizon]]), 0)
    return torch.cat(powers[1:]), torch.cat(rows), h_rows.reshape(-1)


@pytest.mark.parametrize("taps", [1, 2])
def test_lifting_gradient_matches_taped_assembly(taps: int) -> None:
    a, b, h = random_normalized(3, 2, taps, 4)
    leaves = [a.clone().requires_grad_(), *(t.clone().requires_grad_() for t in b), h.clone().requires_grad_()]
    lifted = lifted_matrices(leaves[0], tuple(leaves[1:-1]), leaves[-1], 9)
    ref = _taped_lifted(leaves[0], tuple(leaves[1:-1]), leaves[-1], 9)
    g = torch.Generator().manual_seed(1)
    weights = [torch.randn(r.shape, generator=g, dtype=torch.float64) for r in ref]
    for ours, expected in zip((lifted.a, lifted.b, lifted.h), ref):
        torch.testing.assert_close(ours, expected, rtol=1e-12, atol=1e-12)
    grads = torch.autograd.grad(sum((o * w).sum() for o, w in zip((lifted.a, lifted.b, lifted.h), weights)), leaves)
    expected = torch.autograd.grad(sum((r * w).sum() for r, w in zip(ref, weights)), leaves)
    for got, want in zip(grads, expected):
        torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)

    def fn(*x):
        out = lifted_matrices(x[0], tuple(x[1:-1]), x[-1], 5)
        return out.a, out.b, out.h

    assert torch.autograd.gradcheck(fn, tuple(leaves))


@pytest.mark.parametrize("taps", [1, 2])
def test_one_node_simulation_matches_lifted_product(taps: int) -> None:
    """``simulate_from_rows`` (one custom node) against the lifted product and the recursion."""
    a, b, h = random_normalized(3, 2, taps, 6)
    rows = torch.cat([a, *b, h[:, None]], dim=-1).requires_grad_()
    g = torch.Generator().manual_seed(2)
    x0 = torch.randn(4, 3, generator=g, dtype=torch.float64).requires_grad_()
    u = torch.randn(4, 9 + taps - 1, 2, generator=g, dtype=torch.float64).requires_grad_()
    weights = torch.randn(4, 9, 3, generator=g, dtype=torch.float64)
    parts = (rows[:, :3], tuple(rows[:, 3 + 2 * t : 5 + 2 * t] for t in range(taps)), rows[:, -1])
    ours = simulate_from_rows(rows, taps, x0, u)
    ref = simulate_lifted(lifted_matrices(*parts, 9), x0, u)
    torch.testing.assert_close(ours, ref, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(ours, simulate_recursive(*parts, x0, u), rtol=1e-12, atol=1e-12)
    grads = torch.autograd.grad((ours * weights).sum(), (rows, x0, u))
    expected = torch.autograd.grad((ref * weights).sum(), (rows, x0, u))
    for got, want in zip(grads, expected):
        torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-12)
    assert torch.autograd.gradcheck(lambda r, x, v: simulate_from_rows(r, taps, x, v), (rows, x0, u))
