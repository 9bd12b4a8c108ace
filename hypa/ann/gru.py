"""GRU block: optional input projection -> ``nn.GRU`` -> linear head (a lighter recurrent network than the LSTM)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from hypa.ann.base import SequenceBlock, recurrent_layers

GRUState = Tensor  # h, (num_layers, B, hidden_size)


class GRUBlock(SequenceBlock):
    """Stacked GRU with a linear output head.

    Per layer and step k (σ the logistic function, ⊙ the elementwise product; ``nn.GRU``'s gates):

        r_k = σ(W_r x_k + b_ir + U_r h_{k-1} + b_hr),   z_k = σ(W_z x_k + b_iz + U_z h_{k-1} + b_hz)
        n_k = tanh(W_n x_k + b_in + r_k ⊙ (U_n h_{k-1} + b_hn))
        h_k = (1 - z_k) ⊙ n_k + z_k ⊙ h_{k-1},   y_k = W_y h_k + b_y

    where x_k is the (optionally projected) input, r_k the reset and z_k the update gate. Three
    gates against the LSTM's four, and one state vector instead of two. The recursion is causal by
    construction and the state h after the last step continues a record exactly.

    Args:
        d_in, d_out: input and output features.
        hidden_size: GRU hidden units per layer.
        num_layers: stacked GRU layers.
        dropout: dropout between stacked layers (``nn.GRU`` semantics; inactive for 1 layer).
        input_proj: width of a linear input projection before the GRU; None feeds x directly.
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
        self.proj, self.gru = recurrent_layers(nn.GRU, d_in, hidden_size, num_layers, dropout, input_proj)
        self.head = self._make_head(hidden_size)

    def forward(self, x: Tensor, state: GRUState | None = None) -> tuple[Tensor, GRUState]:
        self._check_input(x)
        if state is None:
            state = self.default_state(x.shape[0], x.device, x.dtype)
        z = self.proj(x)  # (B, L, d_proj)
        h, h_n = self.gru(z, state)  # (B, L, H), (num_layers, B, H)
        return self.head(h), h_n  # (B, L, d_out)

    def default_state(self, batch: int, device: torch.device | str | None, dtype: torch.dtype
                      ) -> GRUState:
        return torch.zeros(self.num_layers, batch, self.hidden_size, device=device, dtype=dtype)
