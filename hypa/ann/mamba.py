"""Mamba block in pure PyTorch: selective (input-dependent) diagonal state-space layers
(Gu & Dao, 2023, "Mamba: linear-time sequence modeling with selective state spaces").

No CUDA kernels and no extra dependency: the selective scan (``hypa.ann.mamba_scan``) is a
blocked loop over time with a hand-written backward, fast enough on a CPU for the windows hypa
trains on (L ≈ 100) and exact in its state hand-off between chunks.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from hypa.ann.base import SequenceBlock
from hypa.ann.mamba_scan import selective_scan

# Per layer: convolution buffer (B, d_conv-1, D_in) and SSM state (B, D_in, N).
MambaState = list[tuple[Tensor, Tensor]]


class _MambaLayer(nn.Module):
    """Pre-norm residual Mamba layer, with x = RMSNorm(h):

        h + W_out( SSM(SiLU(conv(W_u x))) ⊙ SiLU(W_z x) )
    """

    def __init__(self, d_model: int, d_state: int, d_conv: int, expand: int, dt_rank: int,
                 dt_min: float, dt_max: float, min_rate: float = 0.0) -> None:
        super().__init__()
        self.min_rate = min_rate
        d_inner = expand * d_model
        self.d_inner, self.d_state, self.d_conv, self.dt_rank = d_inner, d_state, d_conv, dt_rank
        self.norm = nn.RMSNorm(d_model)
        self.in_proj = nn.Linear(d_model, 2 * d_inner, bias=False)
        # Causal depthwise convolution written out as d_conv shifted products in the (B, L, D_in)
        # layout: the buffer hand-off is explicit and no transposes are needed (as fast as
        # nn.Conv1d on the CPU, measured). Initialised as nn.Conv1d would be (fan-in d_conv).
        bound = d_conv**-0.5
        self.conv_weight = nn.Parameter(torch.empty(d_conv, d_inner).uniform_(-bound, bound))
        self.conv_bias = nn.Parameter(torch.empty(d_inner).uniform_(-bound, bound))
        self.x_proj = nn.Linear(d_inner, dt_rank + 2 * d_state, bias=False)
        self.dt_proj = nn.Linear(dt_rank, d_inner)
        self.out_proj = nn.Linear(d_inner, d_model, bias=False)
        # Initial Δ = softplus(bias) log-uniform in [dt_min, dt_max], as in the reference init.
        nn.init.uniform_(self.dt_proj.weight, -dt_rank**-0.5, dt_rank**-0.5)
        log_dt = math.log(dt_min) + torch.rand(d_inner) * (math.log(dt_max) - math.log(dt_min))
        dt = log_dt.exp()  # (D_in,)
        with torch.no_grad():
            self.dt_proj.bias.copy_(dt + torch.log(-torch.expm1(-dt)))  # inverse softplus
        # S4D-real: A_n = -(n + 1), the same for every channel; stored as log(-A) to keep A < 0.
        a_init = torch.arange(1, d_state + 1, dtype=torch.float32).repeat(d_inner, 1)  # (D_in, N)
        self.a_log = nn.Parameter(torch.log(a_init))
        self.d = nn.Parameter(torch.ones(d_inner))
        for p in (self.a_log, self.d):
            p._optim = {"weight_decay": 0.0}  # hint (mamba convention): do not shrink the dynamics

    def forward(self, x: Tensor, conv_buf: Tensor, ssm: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """x (B, L, d_model), conv buffer (B, d_conv-1, D_in), SSM state (B, D_in, N).

        Convolution: v_k = bias + Σ_i w_i ⊙ u_{k-(d_conv-1)+i}, i = 0..d_conv-1, where the steps
        before this chunk come from the buffer (zeros at the start of a record).
        """
        u, gate = self.in_proj(self.norm(x)).chunk(2, dim=-1)  # 2 x (B, L, D_in)
        length = u.shape[1]
        padded = torch.cat([conv_buf, u], dim=1)  # (B, d_conv-1+L, D_in)
        # The last d_conv-1 inputs, copied so the state does not keep the whole chunk alive.
        new_buf = padded[:, length:].clone()  # (B, d_conv-1, D_in)
        v = self.conv_bias + padded[:, :length] * self.conv_weight[0]  # (B, L, D_in)
        for i in range(1, self.d_conv):
            v = torch.addcmul(v, padded[:, i:i + length], self.conv_weight[i])
        u = F.silu(v)  # (B, L, D_in)
        dt_low, b, c = self.x_proj(u).split([self.dt_rank, self.d_state, self.d_state], dim=-1)
        delta = F.softplus(self.dt_proj(dt_low))  # (B, L, D_in)
        a = -self.a_log.exp()  # (D_in, N)
        # y (B, L, D_in), new_ssm (B, D_in, N)
        y, new_ssm = selective_scan(u, delta, a, b, c, self.d, ssm, min_rate=self.min_rate)
        return x + self.out_proj(y * F.silu(gate)), new_buf, new_ssm  # (B, L, d_model)


class MambaBlock(SequenceBlock):
    """Input projection, ``n_layers`` Mamba layers, linear head.

    The selectivity (Δ_k, B_k, C_k computed from the input at step k) lets the layer decide per
    step what to remember, unlike the time-invariant S4D. Causal: the convolution only looks
    back ``d_conv - 1`` steps (through the buffer) and the scan only forward in time.

    Args:
        d_in, d_out: input and output features.
        d_model: width of the residual stream.
        d_state: SSM states N per inner channel.
        d_conv: kernel length of the causal depthwise convolution.
        expand: inner width D_in = expand · d_model.
        n_layers: Mamba layers.
        dt_rank: rank of the Δ projection; None means ceil(d_model / 16).
        dt_min, dt_max: range of the initial step sizes Δ (log-uniform).
        max_decay: the slowest decay time allowed, in samples: the decay per step is Δ_k |A| +
            1 / max_decay, so every state forgets within ``max_decay`` samples whatever is learned
            (as ``S4Block``'s). Plain Mamba (None) keeps states far slower than a training window,
            which a free run much longer than the window drives to levels training never saw.
        zero_init: start with an all-zero head (output exactly 0).
    """

    def __init__(
        self,
        d_in: int,
        d_out: int,
        *,
        d_model: int = 32,
        d_state: int = 16,
        d_conv: int = 4,
        expand: int = 1,
        n_layers: int = 2,
        dt_rank: int | None = None,
        dt_min: float = 1e-3,
        dt_max: float = 1e-1,
        max_decay: float | None = 25.0,
        zero_init: bool = False,
    ) -> None:
        super().__init__(d_in, d_out, zero_init=zero_init)
        if max_decay is not None and not max_decay > 0:
            raise ValueError(f"max_decay must be a positive number of samples or None, got {max_decay}")
        if min(d_model, d_state, d_conv, expand, n_layers) < 1:
            raise ValueError("d_model, d_state, d_conv, expand and n_layers must be >= 1")
        if dt_rank is not None and dt_rank < 1:
            raise ValueError(f"dt_rank must be None or >= 1, got {dt_rank}")
        if not 0 < dt_min <= dt_max:
            raise ValueError(f"need 0 < dt_min <= dt_max, got {dt_min}, {dt_max}")
        rank = dt_rank if dt_rank is not None else math.ceil(d_model / 16)
        self.d_inner, self.d_state, self.d_conv = expand * d_model, d_state, d_conv
        self.embed = nn.Linear(d_in, d_model)
        self.layers = nn.ModuleList(
            _MambaLayer(d_model, d_state, d_conv, expand, rank, dt_min, dt_max,
                        0.0 if max_decay is None else 1.0 / float(max_decay))
            for _ in range(n_layers)
        )
        # No final norm before the head: it would normalize away the amplitude that the head
        # regresses (measured: a lower error on the first-order-lag test without it).
        self.head = self._make_head(d_model)

    def forward(self, x: Tensor, state: MambaState | None = None) -> tuple[Tensor, MambaState]:
        self._check_input(x)
        if state is None:
            state = self.default_state(x.shape[0], x.device, x.dtype)
        if len(state) != len(self.layers):
            raise ValueError(f"state holds {len(state)} layers, the block has {len(self.layers)}")
        h = self.embed(x)  # (B, L, d_model)
        new_state = []
        for layer, (conv_buf, ssm) in zip(self.layers, state):
            h, conv_buf, ssm = layer(h, conv_buf, ssm)  # (B, L, d_model)
            new_state.append((conv_buf, ssm))
        return self.head(h), new_state  # (B, L, d_out)

    def default_state(self, batch: int, device: torch.device | str | None, dtype: torch.dtype
                      ) -> MambaState:
        # Zero past input: the same as zero left padding of the convolution, and h = 0.
        return [
            (torch.zeros(batch, self.d_conv - 1, self.d_inner, device=device, dtype=dtype),
             torch.zeros(batch, self.d_inner, self.d_state, device=device, dtype=dtype))
            for _ in self.layers
        ]
