"""Causal, decoder-only Transformer with a banded attention window and a relative position bias.

Absolute positions would make step k's output depend on where a chunk starts, so chunked
simulation would not equal whole simulation. Instead every head adds a learned bias that depends
only on the distance k - j between query and key, initialised as ALiBi (Press et al., 2022).
The window (``context`` steps) bounds both the memory and what the state must carry: the keys
and values of the last ``context - 1`` steps of every layer.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from hypa.ann.base import SequenceBlock

# Per layer: keys and values of the last S <= context-1 steps, each (B, n_heads, S, d_head).
KVCache = list[tuple[Tensor, Tensor]]


def alibi_slopes(n_heads: int) -> Tensor:
    """Geometric ALiBi slopes m_h = 2^(-8h/n) for h = 1..n (interleaved when n is no power of 2)."""
    def powers(n: int) -> list[float]:
        return [2.0 ** (-8.0 * (h + 1) / n) for h in range(n)]

    if math.log2(n_heads).is_integer():
        return torch.tensor(powers(n_heads))
    closest = 2 ** math.floor(math.log2(n_heads))
    return torch.tensor(powers(closest) + powers(2 * closest)[0::2][: n_heads - closest])


class _Layer(nn.Module):
    """Pre-norm layer: h = x + Attn(LN(x)); out = h + FFN(LN(h)), with a key/value cache.

    Attention per head: w_kj = exp(s_kj) / (exp(σ) + Σ_j' exp(s_kj')), Attn_k = Σ_j w_kj v_j,
    with scores s_kj = q_k·k_j / sqrt(d_head) + bias and a learned sink logit σ.
    """

    def __init__(self, d_model: int, n_heads: int, dim_feedforward: int, dropout: float) -> None:
        super().__init__()
        self.n_heads, self.d_head, self.dropout = n_heads, d_model // n_heads, dropout
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.qkv = nn.Linear(d_model, 3 * d_model)
        # Attention sink: a learned logit σ per head for attending to "nothing" (a zero value).
        # Without it the attention weights always sum to 1, so a head cannot tell 3 past steps
        # from 30, e.g. the growing response at the start of a record (measured: a first-order
        # lag is learned to a 3-6x lower error with the sink).
        self.sink = nn.Parameter(torch.zeros(n_heads))
        self.out = nn.Linear(d_model, d_model)
        self.ffn = nn.Sequential(
            nn.Linear(d_model, dim_feedforward), nn.GELU(), nn.Dropout(dropout),
            nn.Linear(dim_feedforward, d_model),
        )
        self.drop = nn.Dropout(dropout)

    def forward(self, x: Tensor, k_past: Tensor, v_past: Tensor, bias: Tensor
                ) -> tuple[Tensor, Tensor, Tensor]:
        """x (B, Lq, D), past keys/values (B, nh, S, dh), bias (nh, Lq, S+Lq).

        Returns the layer output (B, Lq, D) and the keys and values of all S+Lq steps.
        """
        b, lq, d = x.shape
        qkv = self.qkv(self.norm1(x)).view(b, lq, 3, self.n_heads, self.d_head)
        q, k, v = qkv.permute(2, 0, 3, 1, 4)  # 3 x (B, nh, Lq, dh)
        # Slot 0 is the sink: a zero key (so its score is just the bias σ) and a zero value.
        zero = k.new_zeros(b, self.n_heads, 1, self.d_head)
        k = torch.cat([zero, k_past, k], dim=2)  # (B, nh, 1+S+Lq, dh)
        v = torch.cat([zero, v_past, v], dim=2)  # (B, nh, 1+S+Lq, dh)
        sink = self.sink.view(-1, 1, 1).expand(-1, lq, 1)  # (nh, Lq, 1)
        bias = torch.cat([sink, bias], dim=-1)  # (nh, Lq, 1+S+Lq)
        # Written out rather than F.scaled_dot_product_attention: with an additive mask its CPU
        # path scans the mask for fully masked rows, ~30 % slower here; no row is ever empty.
        scores = torch.matmul(q * self.d_head**-0.5, k.transpose(-1, -2))  # (B, nh, Lq, 1+S+Lq)
        weights = F.dropout(torch.softmax(scores.add_(bias), dim=-1), self.dropout, self.training)
        a = torch.matmul(weights, v)  # (B, nh, Lq, dh)
        h = x + self.drop(self.out(a.transpose(1, 2).reshape(b, lq, d)))  # (B, Lq, D)
        return h + self.drop(self.ffn(self.norm2(h))), k[:, :, 1:], v[:, :, 1:]


class TransformerBlock(SequenceBlock):
    """Causal Transformer: input projection, ``n_layers`` pre-norm layers, linear head.

    Head h of every layer attends from query step k to key steps j with 0 <= k - j < ``context``:

        s_kj = q_k·k_j / sqrt(d_head) + b_h[k - j],   b_h[d] initialised to -m_h d

    with ALiBi slopes m_h (``alibi_slopes``) and b learned, shared by all layers; the weights
    include a learned sink (see ``_Layer``). Steps j > k are never seen (causal) and neither are
    steps more than ``context - 1`` back (banded).

    Internally the sequence is processed in query blocks of ``max(context, 128)`` steps, each
    attending to the cached keys/values of the previous ``context - 1`` steps, so memory is
    O(L · context) and never an L×L mask, and chunked calls with the returned cache are exact.

    Args:
        d_in, d_out: input and output features.
        d_model: width of the residual stream (divisible by ``n_heads``).
        n_heads: attention heads per layer.
        n_layers: Transformer layers.
        dim_feedforward: hidden width of the position-wise feed-forward network.
        dropout: on attention weights, residual branches and the feed-forward hidden layer.
        context: steps attended per query, the current one included.
        zero_init: start with an all-zero head (output exactly 0).
    """

    def __init__(
        self,
        d_in: int,
        d_out: int,
        *,
        d_model: int = 32,
        n_heads: int = 4,
        n_layers: int = 2,
        dim_feedforward: int = 64,
        dropout: float = 0.0,
        context: int = 101,
        zero_init: bool = False,
    ) -> None:
        super().__init__(d_in, d_out, zero_init=zero_init)
        if min(d_model, n_heads, n_layers, dim_feedforward, context) < 1:
            raise ValueError("d_model, n_heads, n_layers, dim_feedforward and context must be >= 1")
        if d_model % n_heads:
            raise ValueError(f"d_model ({d_model}) must be divisible by n_heads ({n_heads})")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        self.d_model, self.n_heads, self.context = d_model, n_heads, context
        self.embed = nn.Linear(d_in, d_model)
        self.layers = nn.ModuleList(
            _Layer(d_model, n_heads, dim_feedforward, dropout) for _ in range(n_layers)
        )
        # No final norm before the head: it would normalize away the amplitude that the head
        # regresses (measured: a lower error on the first-order-lag test without it).
        self.head = self._make_head(d_model)
        distance = torch.arange(context, dtype=torch.float32)
        self.rel_bias = nn.Parameter(-alibi_slopes(n_heads)[:, None] * distance)  # (nh, context)

    def _bias(self, n_past: int, n_query: int) -> Tensor:
        """Additive attention bias (nh, Lq, S+Lq): b_h[k - j] inside the band, -inf outside."""
        device = self.rel_bias.device
        k = torch.arange(n_query, device=device)[:, None] + n_past  # (Lq, 1), from cache start
        j = torch.arange(n_past + n_query, device=device)[None, :]  # (1, S+Lq)
        distance = k - j  # (Lq, S+Lq)
        inside = (distance >= 0) & (distance < self.context)
        bias = self.rel_bias[:, distance.clamp(0, self.context - 1)]  # (nh, Lq, S+Lq)
        return bias.masked_fill(~inside, float("-inf"))

    def forward(self, x: Tensor, state: KVCache | None = None) -> tuple[Tensor, KVCache]:
        self._check_input(x)
        cache = state if state is not None else self.default_state(x.shape[0], x.device, x.dtype)
        if len(cache) != len(self.layers):
            raise ValueError(f"state holds {len(cache)} layers, the block has {len(self.layers)}")
        keep = self.context - 1
        block = max(self.context, 128)
        outputs = []
        for start in range(0, x.shape[1], block):
            h = self.embed(x[:, start:start + block])  # (B, Lq, D)
            bias = self._bias(cache[0][0].shape[2], h.shape[1]).to(h.dtype)  # (nh, Lq, S+Lq)
            new_cache = []
            for layer, (k_past, v_past) in zip(self.layers, cache):
                h, k, v = layer(h, k_past, v_past, bias)  # (B, Lq, D), 2 x (B, nh, S+Lq, dh)
                cut = max(k.shape[2] - keep, 0)
                new_cache.append((k[:, :, cut:], v[:, :, cut:]))  # 2 x (B, nh, <=context-1, dh)
            cache = new_cache
            outputs.append(self.head(h))  # (B, Lq, d_out)
        return torch.cat(outputs, dim=1), cache  # (B, L, d_out)

    def step_state(self, cache: KVCache) -> list[Tensor]:
        """A cache as ``step`` holds it, of a fixed size: per layer the keys and values of the last
        ``context - 1`` steps (B, nh, context - 1, dh), zeros before a record's first step, then the
        number of steps they hold (B, 1)."""
        keep, (k0, _) = self.context - 1, cache[0]
        pad = lambda t: torch.cat([t.new_zeros(*t.shape[:2], keep - t.shape[2], t.shape[3]), t], 2)  # noqa: E731
        return [*(pad(t) for kv in cache for t in kv), k0.new_full((k0.shape[0], 1), float(k0.shape[2]))]

    def step(self, x: Tensor, state: list[Tensor]) -> tuple[Tensor, list[Tensor]]:
        """``forward`` of one sample, batch of one, on the fixed-size cache of ``step_state``: x (1, d_in)
        -> y (1, d_out) and the next cache. Slots before the record's first step are masked out of
        the attention (-inf), so the step equals ``forward`` from the first sample on."""
        keep, (*kv, held) = self.context - 1, state
        distance = torch.arange(keep, -1, -1, device=x.device)  # the cache's steps, oldest first, then this one
        valid = torch.cat([distance[:-1] <= held.reshape(-1)[0], distance.new_ones(1, dtype=torch.bool)])
        bias = self.rel_bias[:, distance].masked_fill(~valid, float("-inf"))[:, None].to(x.dtype)  # (nh, 1, context)
        h, new = self.embed(x)[:, None], []  # (1, 1, D)
        for layer, k_past, v_past in zip(self.layers, kv[0::2], kv[1::2]):
            h, k, v = layer(h, k_past, v_past, bias)  # (1, 1, D), 2 x (1, nh, context, dh)
            new += [k[:, :, 1:], v[:, :, 1:]]
        return self.head(h)[:, 0], [*new, torch.clamp(held + 1, max=keep)]

    def default_state(self, batch: int, device: torch.device | str | None, dtype: torch.dtype
                      ) -> KVCache:
        # No past at the start of a record: an empty cache, not zeros (zeros would be attended).
        d_head = self.d_model // self.n_heads
        empty = torch.zeros(batch, self.n_heads, 0, d_head, device=device, dtype=dtype)
        return [(empty, empty) for _ in self.layers]
