"""The one sequence contract every ANN block in hypa follows.

A block maps a normalized input sequence to an output sequence, ``(B, L, d_in) -> (B, L, d_out)``,
causally: output step k depends on input steps j <= k only. It carries a state so that a long
record can be simulated in chunks,

    y[:, :k], s = block(x[:, :k], s0);  y[:, k:], _ = block(x[:, k:], s)   ==   block(x, s0)

which is how whole records are simulated free-running and how windows could be chained.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import torch
from torch import Tensor, nn


class SequenceBlock(nn.Module, ABC):
    """Base of all ANN blocks: causal ``(B, L, d_in) -> (B, L, d_out)`` with a chunking state.

    Subclasses take their hyperparameters as explicit, typed keyword arguments (no ``**kwargs``),
    so that ``hypa.ann.build_ann`` can name a misspelt one. With ``zero_init=True`` the final
    output projection starts at exactly zero, so the block initially outputs 0: a residual
    correction then starts as "no correction" and a learned rear-wheel angle starts at 0 rad.
    """

    def __init__(self, d_in: int, d_out: int, *, zero_init: bool = False) -> None:
        super().__init__()
        for label, value in (("d_in", d_in), ("d_out", d_out)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{label} must be a positive integer, got {value!r}")
        self.d_in, self.d_out, self.zero_init = d_in, d_out, bool(zero_init)

    @abstractmethod
    def forward(self, x: Tensor, state: Any | None = None) -> tuple[Tensor, Any]:
        """Map x (B, L, d_in) to y (B, L, d_out), starting from ``state`` (None: the default).

        Returns y and the state after the last step, to be passed with the next chunk.
        """

    @abstractmethod
    def default_state(self, batch: int, device: torch.device | str | None, dtype: torch.dtype
                      ) -> Any:
        """The state before the first step of a record (equivalent to zero past input)."""

    # -- helpers for subclasses ----------------------------------------------------------
    def _check_input(self, x: Tensor) -> None:
        if x.dim() != 3 or x.shape[-1] != self.d_in:
            raise ValueError(f"{type(self).__name__} expects input of shape (B, L, {self.d_in}), "
                             f"got {tuple(x.shape)}")

    def _make_head(self, d_hidden: int) -> nn.Linear:
        """The final linear projection to d_out; all zero when ``zero_init`` (exact 0 output).

        Only the head is zeroed: its weight still receives the gradient dLoss/dy * features,
        so training moves it off zero at the first step, after which the rest learns too.
        """
        head = nn.Linear(d_hidden, self.d_out)
        if self.zero_init:
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)
        return head

    def extra_repr(self) -> str:
        return f"d_in={self.d_in}, d_out={self.d_out}, zero_init={self.zero_init}"


def recurrent_layers(rnn: type[nn.RNNBase], d_in: int, hidden_size: int, num_layers: int, dropout: float,
                     input_proj: int | None) -> tuple[nn.Module, nn.RNNBase]:
    """An optional input projection and a stacked ``rnn`` (``nn.LSTM``, ``nn.GRU``), batch first, after
    checking the arguments (one-line ``ValueError``): what the LSTM and GRU blocks share."""
    if hidden_size < 1 or num_layers < 1:
        raise ValueError(f"hidden_size and num_layers must be >= 1, got {hidden_size}, {num_layers}")
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"dropout must be in [0, 1), got {dropout}")
    if input_proj is not None and input_proj < 1:
        raise ValueError(f"input_proj must be None or >= 1, got {input_proj}")
    proj = nn.Linear(d_in, input_proj) if input_proj is not None else nn.Identity()
    # torch warns about dropout with one layer, where it has no effect anyway
    return proj, rnn(input_size=input_proj or d_in, hidden_size=hidden_size, num_layers=num_layers,
                     dropout=dropout if num_layers > 1 else 0.0, batch_first=True)
