"""The lifted N-step form of the normalized state equation (eq. 9-11).

Stacking X̂ = [x̂_{k+1}; ...; x̂_{k+N}] and Û = [û_k; ...; û_{k+N-1+T-1}] (T input taps:
1 for a zero-order hold, 2 for a first-order hold, which also needs û_{k+N}) gives

    X̂ = 𝒜 x̂_k + ℬ Û + ℋ                                                  (eq. 11)

    𝒜 = [Â; Â²; ...; Â^N]                                                 (N n, n)
    ℬ[i, j] = Σ_t Â^{i-j+t} B̂_t  for t <= j <= i + t, else 0 (block Toeplitz)   (N n, (N+T-1) m)
    ℋ[i] = Σ_{d=0..i} Â^d Ĥ                                                 (N n,)

so a whole window is one batched matrix product instead of N dependent steps. For a zero-
order hold, row i of ℬ is [Â^i B̂, Â^{i-1} B̂, ..., B̂, 0, ...] and the last input used is
û_{k+N-1} (eq. 10). All powers of Â are built together by repeated doubling (⌈log2 N⌉
batched products), so rebuilding the matrices every step with trainable physics stays cheap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass(frozen=True)
class LiftedMatrices:
    """𝒜, ℬ, ℋ of eq. 11 for a horizon of N steps."""

    a: Tensor  # (N n, n)
    b: Tensor  # (N n, (N+T-1) m)
    h: Tensor  # (N n,)
    horizon: int
    n_taps: int

    @property
    def input_length(self) -> int:
        """Number of input samples a window needs: N for ZOH, N + 1 for FOH."""
        return self.horizon + self.n_taps - 1


def matrix_powers(a: Tensor, count: int) -> Tensor:
    """[I, A, A², ..., A^{count-1}] as a (count, n, n) tensor, all at once (differentiable).

    Binary powering, vectorized over k: A^k = Π_{bits b of k} A^(2^b), so ⌈log2 count⌉ batched
    products build every power. The backward is analytic (see ``_MatrixPowers``) rather than
    taped, so rebuilding the lifted matrices every training step stays cheap.
    """
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    return _MatrixPowers.apply(a, count)


def _doubling_powers(a: Tensor, count: int) -> Tensor:
    """[I, A, ..., A^{count-1}] (count, n, n) by doubling (``_krylov`` of the identity)."""
    eye = torch.eye(a.shape[-1], dtype=a.dtype, device=a.device)
    return _krylov(a, eye, count).transpose(0, 1)


def _krylov(a: Tensor, w: Tensor, count: int) -> Tensor:
    """Y_d = A^d W for d = 0..count-1 as an (n, count, k) tensor, by doubling.

    Laid side by side, [Y_L, ..., Y_{2L-1}] = A^L [Y_0, ..., Y_{L-1}] is one plain (n, n) x
    (n, L k) product, and A^{2L} = (A^L)²: three small ops per doubling, ⌈log2 count⌉ times.
    """
    n, k = w.shape
    krylov, power, length = w, a, 1
    while length < count:
        krylov = torch.cat([krylov, power @ krylov], dim=1)
        length *= 2
        if length < count:
            power = power @ power
    return krylov.view(n, length, k)[:, :count]


def _powers_adjoint(powers: Tensor, q: Tensor) -> Tensor:
    """dL/dA = Σ_k (A^k)ᵀ M_k,  M_k = Σ_l Q_{k+1+l} (A^l)ᵀ, from Q_d = dL/dP_d (d = 0..L).

    Q_0 is unused (P_0 = I). The inner sums are one product with the block Hankel matrix
    [Q_{k+1+l}]_{k,l}, whose block row k is a contiguous window of [Q_1, ..., Q_L, 0, ...].
    """
    steps, n = powers.shape[0] - 1, powers.shape[-1]
    if steps == 0:
        return torch.zeros_like(powers[0])
    sequence = torch.cat([q[1:], q.new_zeros(steps - 1, n, n)]).transpose(0, 1).reshape(n, -1)
    hankel = sequence.unfold(1, steps * n, n).transpose(0, 1).reshape(steps * n, steps * n)
    m = hankel @ powers[:steps].transpose(1, 2).reshape(steps * n, n)  # (L n, n): rows (k, a)
    return powers[:steps].reshape(steps * n, n).T @ m


class _MatrixPowers(torch.autograd.Function):
    """P_d = A^d, d = 0..count-1, with the adjoint

        dL/dA = Σ_d Σ_{k<d} (A^k)ᵀ Q_d (A^{d-1-k})ᵀ = Σ_k (A^k)ᵀ M_k,   M_k = Σ_l Q_{k+1+l} (A^l)ᵀ

    for Q_d = dL/dP_d (``_powers_adjoint``).
    """

    @staticmethod
    def forward(ctx, a: Tensor, count: int) -> Tensor:  # type: ignore[override]
        powers = _doubling_powers(a, count)
        ctx.save_for_backward(powers)
        return powers

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None]:  # type: ignore[override]
        (powers,) = ctx.saved_tensors
        return _powers_adjoint(powers, grad), None


def block_toeplitz(markov: Tensor) -> Tensor:
    """Lower block-triangular Toeplitz T[i, :, j, :] = K[i - j] (j <= i), else 0.

    markov: (N, n, m) Markov parameters K_d = Â^d B̂. Returns (N, n, N, m). Row block i is
    [K_i, ..., K_0, 0, ...]: a contiguous window of the sequence [K_{N-1}, ..., K_0, 0, ...]
    starting at N-1-i, so all rows are one strided view gathered in reverse order (a single
    copy with contiguous rows, much cheaper than permuting a (N, n, m, N) unfold).
    """
    horizon, n, m = markov.shape
    reverse = torch.cat([markov.flip(0), markov.new_zeros(horizon - 1, n, m)])  # (2N-1, n, m)
    sequence = reverse.transpose(0, 1).reshape(n, (2 * horizon - 1) * m)
    windows = sequence.unfold(1, horizon * m, m).transpose(0, 1)  # (N, n, N m): row N-1-i
    rows = torch.arange(horizon - 1, -1, -1, device=markov.device)
    return windows.index_select(0, rows).view(horizon, n, horizon, m)


def block_diagonal_sums(grad: Tensor) -> Tensor:
    """The adjoint of ``block_toeplitz``: S[d] = Σ_{i>=d} G[i, :, i - d, :] for G (N, n, N, m)."""
    horizon, n, _, m = grad.shape
    flat = grad.reshape(horizon, n, horizon * m)
    padded = torch.cat([flat.new_zeros(horizon, n, (horizon - 1) * m), flat], dim=-1)
    row = padded.stride(0)  # padded[i, :, (e + i) m + c] = G[i, :, i - (N-1-e), c]
    diagonals = padded.as_strided((horizon, horizon, n, m), (m, row + m, padded.stride(1), 1))
    return diagonals.sum(1).flip(0)


def _assemble(rows: Tensor, horizon: int, n_taps: int) -> tuple[Tensor, ...]:
    """P = [I, Â, ..., Â^N], V, and the flat 𝒜 (N n, n), ℬ (N n, (N+T-1) m), ℋ (N n,) from [Â, V]."""
    n = rows.shape[0]
    a, v = rows[:, :n], rows[:, n:]
    m = (v.shape[-1] - 1) // n_taps
    krylov = _krylov(a, rows, horizon)  # (n, N, n + T m + 1): Â^d [Â, V] = [Â^{d+1}, K_d]
    eye = torch.eye(n, dtype=a.dtype, device=a.device)
    powers = torch.cat([eye[None], krylov[:, :, :n].transpose(0, 1)])  # (N+1, n, n)
    markov = krylov[:, :, n:].transpose(0, 1)  # (N, n, T m + 1)
    lifted_b = block_toeplitz(markov[..., :m])
    for t in range(1, n_taps):  # tap t reads the input t samples later: t columns further right
        lifted_b = nn.functional.pad(lifted_b, (0, 0, 0, 1))
        lifted_b[:, :, t:] += block_toeplitz(markov[..., t * m : (t + 1) * m])
    lifted_h = markov[..., -1].cumsum(0)
    return (powers, v, powers[1:].reshape(horizon * n, n),
            lifted_b.view(horizon * n, (horizon + n_taps - 1) * m), lifted_h.reshape(horizon * n))


def _assembly_adjoint(powers: Tensor, v: Tensor, n_taps: int, grad_a: Tensor, grad_b: Tensor,
                      grad_h: Tensor) -> Tensor:
    """dL/d[Â, V] from dL/d𝒜, dL/dℬ, dL/dℋ (see ``_Lifting``)."""
    horizon, n = powers.shape[0] - 1, powers.shape[-1]
    m = (v.shape[-1] - 1) // n_taps
    grad_b = grad_b.reshape(horizon, n, horizon + n_taps - 1, m)
    grad_markov = torch.cat([
        *(block_diagonal_sums(grad_b[:, :, t : t + horizon]) for t in range(n_taps)),
        grad_h.reshape(horizon, n, 1).flip(0).cumsum(0).flip(0),
    ], dim=-1)  # (N, n, T m + 1)
    grad_v = powers[:horizon].reshape(-1, n).T @ grad_markov.reshape(horizon * n, -1)  # Σ_d P_dᵀ G_d
    q = torch.cat([grad_markov @ v.T, grad_markov.new_zeros(1, n, n)])  # dL/dP_d from K_d
    q[1:] += grad_a.reshape(horizon, n, n)
    return torch.cat([_powers_adjoint(powers, q), grad_v], dim=-1)


class _Lifting(torch.autograd.Function):
    """[Â, V] = [Â, B̂_0, ..., B̂_{T-1}, Ĥ] -> (𝒜, ℬ, ℋ) of eq. 11 with an analytic adjoint.

    With P_d = Â^d and the Markov parameters K_d = P_d V (Ĥ is the response to a constant
    unit input, so ℋ = cumsum_d of the last column), the adjoint of the assembly is

        dL/dK_t[d] = Σ_i dL/dℬ[i, i-d+t]   (block diagonal sums),   dL/dĤ-column[d] = Σ_{i>=d} dL/dℋ[i]
        dL/dV = Σ_d P_dᵀ dL/dK_d,   dL/dP_d = dL/d𝒜[d-1] + dL/dK_d Vᵀ  ->  dL/dÂ (``_powers_adjoint``)

    one graph node instead of a few dozen taped ones, which matters when the lifted matrices
    are rebuilt every training step.
    """

    @staticmethod
    def forward(ctx, rows: Tensor, horizon: int, n_taps: int):  # type: ignore[override]
        powers, v, lifted_a, lifted_b, lifted_h = _assemble(rows, horizon, n_taps)
        ctx.save_for_backward(powers, v)
        ctx.n_taps = n_taps
        return lifted_a, lifted_b, lifted_h

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_a: Tensor, grad_b: Tensor, grad_h: Tensor):  # type: ignore[override]
        powers, v = ctx.saved_tensors
        return _assembly_adjoint(powers, v, ctx.n_taps, grad_a, grad_b, grad_h), None, None


class _LiftedSimulation(torch.autograd.Function):
    """([Â, V], x̂_k (B, n), Û (B, (N+T-1) m)) -> X̂ = 𝒜 x̂_k + ℬ Û + ℋ (B, N n) in one node.

    For trainable physics, whose 𝒜, ℬ, ℋ are rebuilt every step and used once: with
    G = dL/dX̂, the adjoint dL/d𝒜 = Gᵀ x̂_k, dL/dℬ = Gᵀ Û, dL/dℋ = Σ_b G goes straight into
    the assembly's adjoint (``_Lifting``), and dL/dx̂_k = G 𝒜, dL/dÛ = G ℬ; the lifted
    matrices get no graph nodes of their own.
    """

    @staticmethod
    def forward(ctx, rows: Tensor, x0: Tensor, u: Tensor, horizon: int, n_taps: int):  # type: ignore[override]
        powers, v, lifted_a, lifted_b, lifted_h = _assemble(rows, horizon, n_taps)
        ctx.save_for_backward(powers, v, lifted_a, lifted_b, x0, u)
        ctx.n_taps = n_taps
        return torch.addmm(lifted_h, u, lifted_b.T).addmm_(x0, lifted_a.T)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        powers, v, lifted_a, lifted_b, x0, u = ctx.saved_tensors
        grad_rows = _assembly_adjoint(powers, v, ctx.n_taps, grad.T @ x0, grad.T @ u, grad.sum(0))
        grad_x0 = grad @ lifted_a if ctx.needs_input_grad[1] else None
        grad_u = grad @ lifted_b if ctx.needs_input_grad[2] else None
        return grad_rows, grad_x0, grad_u, None, None


def lifted_matrices(a: Tensor, b_taps: tuple[Tensor, ...], h: Tensor, horizon: int) -> LiftedMatrices:
    """Build 𝒜, ℬ, ℋ (eq. 9-11) from the normalized Â, B̂_t, Ĥ for ``horizon`` steps."""
    return lifted_from_rows(torch.cat([a, *b_taps, h[:, None]], dim=-1), len(b_taps), horizon)


def lifted_from_rows(rows: Tensor, n_taps: int, horizon: int) -> LiftedMatrices:
    """``lifted_matrices`` from [Â, B̂_0, ..., B̂_{T-1}, Ĥ] as one (n, n + T m + 1) tensor."""
    if horizon < 1:
        raise ValueError(f"horizon must be at least 1, got {horizon}")
    lifted_a, lifted_b, lifted_h = _Lifting.apply(rows, horizon, n_taps)
    return LiftedMatrices(a=lifted_a, b=lifted_b, h=lifted_h, horizon=horizon, n_taps=n_taps)


def simulate_lifted(lifted: LiftedMatrices, x0: Tensor, u: Tensor) -> Tensor:
    """X̂ = 𝒜 x̂_k + ℬ Û + ℋ for a batch.

    x0: (B, n) normalized initial states; u: (B, N+T-1, m) normalized inputs.
    Returns (B, N, n): the states x̂_{k+1}..x̂_{k+N}.
    """
    batch, n = x0.shape
    if u.shape[1] != lifted.input_length:
        raise ValueError(
            f"expected {lifted.input_length} input samples for a horizon of {lifted.horizon} "
            f"with {lifted.n_taps} tap(s), got {u.shape[1]}"
        )
    flat = torch.addmm(lifted.h, u.reshape(batch, -1), lifted.b.T)  # (B, N n)
    if n:
        flat = flat.addmm(x0, lifted.a.T)
    return flat.view(batch, lifted.horizon, n)


def simulate_from_rows(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """``simulate_lifted(lifted_from_rows(rows, n_taps, N), x0, u)`` as one graph node, N = L - T + 1.

    rows: [Â, B̂_0, ..., B̂_{T-1}, Ĥ] (n, n + T m + 1), n >= 1; x0: (B, n); u: (B, L, m).
    Returns (B, N, n). For physics rebuilt every step; cached matrices use ``simulate_lifted``.
    """
    batch, n = x0.shape
    horizon = u.shape[1] - n_taps + 1
    if horizon < 1:
        raise ValueError(f"need at least {n_taps} input samples, got {u.shape[1]}")
    flat = _LiftedSimulation.apply(rows, x0, u.reshape(batch, -1), horizon, n_taps)
    return flat.view(batch, horizon, n)


def simulate_recursive(a: Tensor, b_taps: tuple[Tensor, ...], h: Tensor, x0: Tensor, u: Tensor) -> Tensor:
    """The reference: x̂_{k+1} = Â x̂_k + Σ_t B̂_t û_{k+t} + Ĥ, one step after another.

    x0: (B, n); u: (B, L, m). Returns (B, L - T + 1, n).
    """
    steps = u.shape[1] - len(b_taps) + 1
    x, out = x0, []
    for k in range(steps):
        x = x @ a.T + h
        for t, b_t in enumerate(b_taps):
            x = x + u[:, k + t] @ b_t.T
        out.append(x)
    return torch.stack(out, dim=1)


def simulate_chunked(lifted: LiftedMatrices, x0: Tensor, u: Tensor) -> Tensor:
    """States x̂_{k+1..k+S} (B, S, n) for any S = L - T + 1, from x0 (B, n) and u (B, L, m).

    S = N is one ``simulate_lifted``. Otherwise the sequence is cut into horizon-long windows
    (the last padded with zeros): all windows' input responses are one product, and the windows
    are chained through their last states, x̂_{(c+1)N} = Â^N x̂_{cN} + (forced response)_c, which
    is exact: free-running simulation of any length at the cost of ⌈S/N⌉ tiny (n, n) steps.
    """
    batch, n = x0.shape
    horizon, n_taps = lifted.horizon, lifted.n_taps
    steps = u.shape[1] - n_taps + 1
    if steps == horizon:
        return simulate_lifted(lifted, x0, u)
    if steps < 1:
        raise ValueError(f"need at least {n_taps} input samples, got {u.shape[1]}")
    chunks = math.ceil(steps / horizon)
    pad = chunks * horizon + n_taps - 1 - u.shape[1]
    u_pad = torch.cat([u, u.new_zeros(batch, pad, u.shape[2])], dim=1)
    windows = u_pad.unfold(1, lifted.input_length, horizon)  # (B, C, m, N+T-1)
    windows = windows.transpose(2, 3).reshape(batch, chunks, -1)
    forced = (windows @ lifted.b.T + lifted.h).view(batch, chunks, horizon, n)
    a_n = lifted.a[-n:]  # Â^N
    starts, x = [], x0
    for c in range(chunks):
        starts.append(x)
        x = x @ a_n.T + forced[:, c, -1]
    free = (torch.stack(starts, 1) @ lifted.a.T).view(batch, chunks, horizon, n)
    return (forced + free).reshape(batch, chunks * horizon, n)[:, :steps]
