"""LSTM block: optional input projection -> ``nn.LSTM`` -> linear head (the paper's main ANN)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from hypa.ann.base import SequenceBlock, recurrent_layers

LSTMState = tuple[Tensor, Tensor]  # (h, c), each (num_layers, B, hidden_size)


class LSTMBlock(SequenceBlock):
    """Stacked LSTM with a linear output head.

    Per layer and step k (σ the logistic function, ⊙ the elementwise product):

        i, f, g, o = σ(W_i z_k + U_i h_{k-1} + b_i), σ(..f..), tanh(..g..), σ(..o..)
        c_k = f ⊙ c_{k-1} + i ⊙ g,   h_k = o ⊙ tanh(c_k),   y_k = W_y h_k + b_y

    where z_k is the (optionally projected) input. The recursion is causal by construction and
    the state (h, c) after the last step continues a record exactly.

    Args:
        d_in, d_out: input and output features.
        hidden_size: LSTM hidden units per layer.
        num_layers: stacked LSTM layers.
        dropout: dropout between stacked layers (``nn.LSTM`` semantics; inactive for 1 layer).
        input_proj: width of a linear input projection before the LSTM; None feeds x directly.
        zero_init: start with an all-zero head (output exactly 0).
    """

    def __init__(
        self,
        d_in: int,
        d_out: int,
        *,
        hidden_size: int = 64,
        num_layers: int = 1,
        dropout: float = 0.0,
        input_proj: int | None = None,
        zero_init: bool = False,
    ) -> None:
        super().__init__(d_in, d_out, zero_init=zero_init)
        self.hidden_size, self.num_layers = hidden_size, num_layers
        self.proj, self.lstm = recurrent_layers(nn.LSTM, d_in, hidden_size, num_layers, dropout, input_proj)
        self.head = self._make_head(hidden_size)

    def forward(self, x: Tensor, state: LSTMState | None = None) -> tuple[Tensor, LSTMState]:
        self._check_input(x)
        if state is None:
            state = self.default_state(x.shape[0], x.device, x.dtype)
        z = self.proj(x)  # (B, L, d_proj)
        h, (h_n, c_n) = self.lstm(z, state)  # (B, L, H), 2 x (num_layers, B, H)
        return self.head(h), (h_n, c_n)  # (B, L, d_out)

    def default_state(self, batch: int, device: torch.device | str | None, dtype: torch.dtype
                      ) -> LSTMState:
        zeros = torch.zeros(self.num_layers, batch, self.hidden_size, device=device, dtype=dtype)
        return zeros, zeros.clone()
