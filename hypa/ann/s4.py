"""S4D block: diagonal state-space layers (Gu et al., 2022, "On the parameterization and
initialization of diagonal state space models") with GLU mixing, residuals and a linear head.

Per forward the SSM kernel is computed and the sequence convolved with it (FFT for long
sequences, a Toeplitz product for short ones); the SSM state after the last step is returned in
closed form and a given initial state adds its free response, so chunked calls equal one whole
call without any recursion over time.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from hypa.ann.base import SequenceBlock

S4State = list[Tensor]  # per layer: complex SSM state (B, d_model, d_state // 2)


class S4DKernel(nn.Module):
    """H independent diagonal SSMs with N/2 complex modes each (conjugate pairs implied).

    Continuous x' = A x + B u, y = 2 Re(C x) + D u with B = 1 (absorbed into C), step
    Δ = exp(log_dt) and A = diag(-exp(a_re_log) - 1/(τ_max Δ) + i a_im). Zero-order hold gives

        Ā = exp(Δ A),   B̄ = (Ā - 1) / A,   x_k = Ā x_{k-1} + B̄ u_k,   y_k = 2 Re(C x_k) + D u_k,

    i.e. the causal convolution y = K * u + D u with kernel K_l = 2 Re(C Ā^l B̄), l = 0..L-1.

    The decay per step is r = -Δ Re A = Δ exp(a_re_log) + 1/τ_max, so every mode has
    |Ā| = exp(-r) <= exp(-1/τ_max) < 1 whatever the parameters: each forgets its past within
    ``max_decay`` = τ_max samples. Without that floor (``max_decay=None``, plain S4D) training
    on short windows keeps modes much slower than the window (|Ā| -> 1 in float32 as
    Δ exp(a_re_log) -> 0); within a window they act as ramps from its zero start, and a free run
    far longer than the window drives them to levels training never saw.

    Init: S4D-Lin  A_n = -1/2 + i π n,  or  S4D-Inv  A_n = -1/2 + i (N/π)(N/(2n+1) - 1) (before
    the floor); log Δ uniform in [log dt_min, log dt_max]; C ~ CN(0, 1).
    """

    def __init__(self, d_model: int, d_state: int, init: str, dt_min: float, dt_max: float,
                 max_decay: float | None = None) -> None:
        super().__init__()
        if max_decay is not None and not max_decay > 0:
            raise ValueError(f"max_decay must be a positive number of samples or None, got {max_decay}")
        self.min_rate = 0.0 if max_decay is None else 1.0 / float(max_decay)
        h, n = d_model, d_state // 2
        log_dt = math.log(dt_min) + torch.rand(h) * (math.log(dt_max) - math.log(dt_min))  # (H,)
        modes = torch.arange(n, dtype=torch.float32)
        if init == "lin":
            a_im = math.pi * modes
        elif init == "inv":
            a_im = (d_state / math.pi) * (d_state / (2 * modes + 1) - 1)
        else:
            raise ValueError(f"unknown S4D init {init!r}; choose 'lin' or 'inv'")
        self.log_dt = nn.Parameter(log_dt)
        self.a_re_log = nn.Parameter(torch.full((h, n), math.log(0.5)))
        self.a_im = nn.Parameter(a_im.repeat(h, 1))  # (H, N/2)
        # C stored as real pairs (H, N/2, 2): optimizers and .double() handle real tensors only.
        self.c = nn.Parameter(torch.view_as_real(torch.randn(h, n, dtype=torch.cfloat)))
        self.d = nn.Parameter(torch.randn(h))
        for p in (self.log_dt, self.a_re_log, self.a_im):
            p._optim = {"weight_decay": 0.0}  # hint (s4 convention): do not shrink the dynamics

    def forward(self, u: Tensor, x0: Tensor | None) -> tuple[Tensor, Tensor]:
        """u (B, H, L) and state x0 (B, H, N/2), complex or None (zero) -> y (B, H, L), x_L.

        With the initial state the output gains its free response 2 Re(C Ā^{k+1} x0), and the
        state after the last step is x_L = Ā^L x0 + Σ_l Ā^l B̄ u_{L-1-l}: both from the same
        powers Ā^l as the kernel, so a chunked call costs no recursion over time.
        """
        length, n = u.shape[-1], self.a_im.shape[-1]
        rate, angle = self.decay_rate(), self.log_dt.exp()[:, None] * self.a_im  # (H, N/2) each
        a_bar, b_bar = self.discrete()  # (H, N/2) each
        c = torch.view_as_complex(self.c)  # (H, N/2)
        # Ā^l = exp(-l r) (cos + i sin)(l Δ Im A) in real arithmetic: a complex exp over
        # (H, N/2, L) is two orders of magnitude slower on the CPU than real exp, cos and sin.
        steps = torch.arange(length, device=u.device, dtype=u.dtype)
        magnitude = torch.exp(-rate[..., None] * steps)  # (H, N/2, L)
        phase = angle[..., None] * steps  # (H, N/2, L)
        # Re and Im stacked along the mode axis, (H, N, L), so every product below is real.
        powers = torch.cat([magnitude * torch.cos(phase), magnitude * torch.sin(phase)], dim=1)
        cb = c * b_bar  # (H, N/2)
        cb_ri = torch.cat([cb.real, -cb.imag], dim=-1)  # (H, N): Re(cb Ā^l) = cb_ri · powers_l
        kernel = 2 * torch.einsum("hn,hnl->hl", cb_ri, powers)  # (H, L)
        y = causal_convolution(u, kernel) + self.d[:, None] * u  # (B, H, L)
        a_pow_len = torch.complex(powers[:, :n, -1], powers[:, n:, -1]) * a_bar  # (H, N/2): Ā^L
        forced = torch.einsum("bhl,hnl->bhn", u.flip(-1), powers)  # (B, H, N): Σ_l Ā^l u_{L-1-l}
        x_last = torch.complex(forced[..., :n], forced[..., n:]) * b_bar  # (B, H, N/2)
        if x0 is not None:
            w = x0 * (c * a_bar)  # (B, H, N/2)
            y = y + 2 * torch.einsum("bhn,hnl->bhl", torch.cat([w.real, -w.imag], dim=-1), powers)
            x_last = x_last + a_pow_len * x0
        return y, x_last

    def step(self, u: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
        """One sample of ``forward`` in real arithmetic: u (B, H), state x (B, H, N/2, 2) as (Re, Im) pairs.

            y = 2 Re(C B̄) u + D u + 2 Re(C Ā x),        x' = Ā x + B̄ u

        (``forward`` with L = 1: the kernel's first tap and the free response's first sample),
        for an exported one-step model (``hypa.export``): ONNX has no complex numbers.
        """
        dt, rate, angle = self.log_dt.exp()[:, None], self.decay_rate(), self.log_dt.exp()[:, None] * self.a_im
        magnitude = torch.exp(-rate)
        a_re, a_im = magnitude * torch.cos(angle), magnitude * torch.sin(angle)  # Ā (H, N/2)
        norm = rate * rate + angle * angle  # |Δ A|², Δ A = -r + i Δ Im A
        b_re = dt * ((a_re - 1) * -rate + a_im * angle) / norm  # B̄ = Δ (Ā - 1) / (Δ A)
        b_im = dt * (a_im * -rate - (a_re - 1) * angle) / norm
        c_re, c_im = self.c[..., 0], self.c[..., 1]
        x_re, x_im = x[..., 0], x[..., 1]  # (B, H, N/2)
        ax_re, ax_im = a_re * x_re - a_im * x_im, a_re * x_im + a_im * x_re
        y = 2 * (c_re * b_re - c_im * b_im).sum(-1) * u + self.d * u + 2 * (c_re * ax_re - c_im * ax_im).sum(-1)
        return y, torch.stack([ax_re + b_re * u[..., None], ax_im + b_im * u[..., None]], -1)

    def decay_rate(self) -> Tensor:
        """r = -Δ Re A (H, N/2): each mode's decay per step, at least 1/τ_max; |Ā| = exp(-r)."""
        return self.log_dt.exp()[:, None] * self.a_re_log.exp() + self.min_rate

    def discrete(self) -> tuple[Tensor, Tensor]:
        """Ā = exp(Δ A) and B̄ = (Ā - 1)/A = Δ (Ā - 1)/(Δ A), complex (H, N/2) each.

        Built from Δ A = -r + i Δ Im A, never from A itself: A's real part grows as 1/Δ
        under the floor and would overflow for tiny Δ, Δ A stays finite.
        """
        dt = self.log_dt.exp()[:, None]  # (H, 1)
        dt_a = torch.complex(-self.decay_rate(), dt * self.a_im)  # (H, N/2)
        a_bar = torch.exp(dt_a)
        return a_bar, dt * (a_bar - 1) / dt_a


def causal_convolution(u: Tensor, kernel: Tensor, direct_max_len: int = 128) -> Tensor:
    """y_k = Σ_{l=0..k} K_l u_{k-l} per channel: u (B, H, L), kernel (H, L) -> (B, H, L).

    Long sequences use an FFT, zero-padded to 2L so the circular convolution is the linear one
    (O(L log L)). Up to ``direct_max_len`` steps a Toeplitz matrix product is faster on the CPU
    (measured: half the time at L = 101) and exactly causal, where the FFT leaks round-off.
    """
    length = u.shape[-1]
    if length <= direct_max_len:
        # W[h, s, k] = K[h, k - (L-1-s)] (0 for a negative index), so with the time-reversed
        # input ũ_s = u_{L-1-s}: y_k = Σ_s ũ_s W[s, k] = Σ_j u_j K_{k-j}, a plain batched matmul.
        windows = F.pad(kernel, (length - 1, 0)).unfold(-1, length, 1)  # (H, L, L)
        reversed_u = u.flip(-1).transpose(0, 1).contiguous()  # (H, B, L)
        return torch.bmm(reversed_u, windows).transpose(0, 1)  # (B, H, L)
    n_fft = 2 * length
    y = torch.fft.irfft(torch.fft.rfft(u, n=n_fft) * torch.fft.rfft(kernel, n=n_fft), n=n_fft)
    return y[..., :length]  # (B, H, L)


class S4Block(SequenceBlock):
    """Encoder, ``n_layers`` residual S4D layers, linear head.

    Each layer (pre-norm): z = LN(h); z = GELU(S4D(z)); z = GLU(W z) (a gated 1x1 mixing of the
    H channels, which the diagonal SSM never mixes); h = h + dropout(z). Every operation but the
    SSM acts per step, so the block is causal and its state is the per-layer SSM state.

    Args:
        d_in, d_out: input and output features.
        d_model: number of independent SSM channels H (width of the residual stream).
        d_state: SSM order N per channel (even: N/2 complex conjugate pairs).
        n_layers: S4D layers.
        dropout: dropout on the residual branch.
        init: ``"lin"`` (S4D-Lin) or ``"inv"`` (S4D-Inv) initialisation of Im A.
        dt_min, dt_max: range of the initial step sizes Δ (log-uniform) in the time unit of A,
            whose real part starts at -1/2 (before the floor): decay times of 2/dt_max to
            2/dt_min steps.
        max_decay: the slowest decay time τ_max allowed, in samples: every mode forgets its
            past within it (|Ā| <= exp(-1/τ_max)). Keep it well inside the training window
            (a quarter of it: e^-4 of a window's zero start is left at its end), so that a free
            run of any length meets only states that training windows reach. None: no floor,
            plain S4D, whose slow modes drift in runs much longer than the window.
        zero_init: start with an all-zero head (output exactly 0).
    """

    def __init__(
        self,
        d_in: int,
        d_out: int,
        *,
        d_model: int = 32,
        d_state: int = 32,
        n_layers: int = 2,
        dropout: float = 0.0,
        init: str = "lin",
        dt_min: float = 1e-3,
        dt_max: float = 1e-1,
        max_decay: float | None = 25.0,
        zero_init: bool = False,
    ) -> None:
        super().__init__(d_in, d_out, zero_init=zero_init)
        if min(d_model, n_layers) < 1 or d_state < 2 or d_state % 2:
            raise ValueError("need d_model, n_layers >= 1 and an even d_state >= 2, got "
                             f"{d_model}, {n_layers}, {d_state}")
        if not 0 < dt_min <= dt_max:
            raise ValueError(f"need 0 < dt_min <= dt_max, got {dt_min}, {dt_max}")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        self.d_model, self.d_state = d_model, d_state
        self.embed = nn.Linear(d_in, d_model)
        self.norms = nn.ModuleList(nn.LayerNorm(d_model) for _ in range(n_layers))
        self.ssms = nn.ModuleList(
            S4DKernel(d_model, d_state, init, dt_min, dt_max, max_decay) for _ in range(n_layers)
        )
        self.mixers = nn.ModuleList(nn.Linear(d_model, 2 * d_model) for _ in range(n_layers))
        self.drop = nn.Dropout(dropout)
        # No final norm before the head: it would normalize away the amplitude that the head
        # regresses (measured: a lower error on the first-order-lag test without it).
        self.head = self._make_head(d_model)

    def forward(self, x: Tensor, state: S4State | None = None) -> tuple[Tensor, S4State]:
        self._check_input(x)
        if state is not None and len(state) != len(self.ssms):
            raise ValueError(f"state holds {len(state)} layers, the block has {len(self.ssms)}")
        # No state means zero initial SSM states, whose free response need not be computed.
        initial = state if state is not None else [None] * len(self.ssms)
        h = self.embed(x)  # (B, L, H)
        new_state = []
        for norm, ssm, mixer, x0 in zip(self.norms, self.ssms, self.mixers, initial):
            z, x_last = ssm(norm(h).transpose(1, 2), x0)  # (B, H, L), (B, H, N/2)
            z = F.glu(mixer(F.gelu(z).transpose(1, 2)), dim=-1)  # (B, L, H)
            h = h + self.drop(z)  # (B, L, H)
            new_state.append(x_last)
        return self.head(h), new_state  # (B, L, d_out)

    def step_state(self, state: S4State) -> list[Tensor]:
        """The layers' states as ``step`` holds them: (Re, Im) pairs (B, H, N/2, 2)."""
        return [torch.view_as_real(s) for s in state]

    def step(self, x: Tensor, state: list[Tensor]) -> tuple[Tensor, list[Tensor]]:
        """``forward`` of one sample in real arithmetic: x (B, d_in), the layers' states as (B, H, N/2, 2)
        (Re, Im) pairs (``torch.view_as_real`` of ``forward``'s) -> y (B, d_out) and the next states."""
        h, new_state = self.embed(x), []  # (B, H)
        for norm, ssm, mixer, x0 in zip(self.norms, self.ssms, self.mixers, state):
            z, x_next = ssm.step(norm(h), x0)  # (B, H), (B, H, N/2, 2)
            h = h + self.drop(F.glu(mixer(F.gelu(z)), dim=-1))
            new_state.append(x_next)
        return self.head(h), new_state

    def default_state(self, batch: int, device: torch.device | str | None, dtype: torch.dtype
                      ) -> S4State:
        cdtype = torch.complex128 if dtype == torch.float64 else torch.complex64
        shape = (batch, self.d_model, self.d_state // 2)
        return [torch.zeros(shape, device=device, dtype=cdtype) for _ in self.ssms]
