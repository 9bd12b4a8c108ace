"""ANN blocks behind one causal sequence contract: ``(B, L, d_in) -> (B, L, d_out)`` plus a state.

``build_ann(name, d_in, d_out, **hparams)`` builds a block by its config name; the
hyperparameters are the explicit keyword arguments of the block's class (``conf/ann/*.yaml``).
"""

from __future__ import annotations

import inspect
from typing import Any

from hypa.ann.base import SequenceBlock
from hypa.ann.lstm import LSTMBlock
from hypa.ann.mamba import MambaBlock
from hypa.ann.mamba_scan import selective_scan
from hypa.ann.s4 import S4Block, S4DKernel
from hypa.ann.transformer import TransformerBlock

ANN_BLOCKS: dict[str, type[SequenceBlock]] = {
    "lstm": LSTMBlock,
    "transformer": TransformerBlock,
    "s4": S4Block,
    "mamba": MambaBlock,
}


def ann_hyperparameters(name: str) -> dict[str, Any]:
    """The hyperparameters block ``name`` accepts, with their defaults (d_in, d_out excluded)."""
    cls = _block_class(name)
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]  # drop self
    return {p.name: p.default for p in params if p.name not in ("d_in", "d_out")}


def build_ann(name: str, d_in: int, d_out: int, **hparams: Any) -> SequenceBlock:
    """Build the block registered as ``name`` mapping (B, L, d_in) -> (B, L, d_out).

    Raises:
        ValueError: ``name`` is not registered (the message lists the known names).
        TypeError: a hyperparameter the block does not accept (the message lists the accepted).
    """
    cls = _block_class(name)
    accepted = ann_hyperparameters(name)
    unknown = sorted(set(hparams) - set(accepted))
    if unknown:
        raise TypeError(
            f"ANN block {name!r} got unknown hyperparameter(s) {', '.join(unknown)}; "
            f"accepted: {', '.join(accepted)}"
        )
    return cls(d_in, d_out, **hparams)


def _block_class(name: str) -> type[SequenceBlock]:
    try:
        return ANN_BLOCKS[name]
    except KeyError:
        known = ", ".join(sorted(ANN_BLOCKS))
        raise ValueError(f"unknown ANN block {name!r}; known: {known}") from None


__all__ = [
    "ANN_BLOCKS", "SequenceBlock", "LSTMBlock", "TransformerBlock", "S4Block", "S4DKernel",
    "MambaBlock", "selective_scan", "ann_hyperparameters", "build_ann",
]
