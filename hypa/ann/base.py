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
