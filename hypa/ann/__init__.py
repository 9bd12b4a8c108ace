"""ANN blocks behind one causal sequence contract: ``(B, L, d_in) -> (B, L, d_out)`` plus a state.

A network is named by its config name (``lstm``, ``transformer``, ``s4``, ``mamba``) or by the
import path of a :class:`SequenceBlock` subclass in any importable module (``mypkg.nets.MyBlock``
or ``mypkg.nets:MyBlock``): a user's own network plugs in the way a user's own system does.
``conf/ann/*.yaml`` are Hydra ``_target_`` configs; ``build_ann(name, d_in, d_out, **hparams)``
builds a block with ``hydra.utils.instantiate``, its hyperparameters the explicit keyword
arguments of the block's class (a misspelt one is named with the accepted ones).
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from hydra.errors import InstantiationException
from hydra.utils import instantiate

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


def network_class(name: str) -> type[SequenceBlock]:
    """The block class of a config name or an import path (``pkg.mod.Class`` / ``pkg.mod:Class``).

    Raises:
        ValueError: an unknown name, a path that does not import, or a class that is not a
            :class:`SequenceBlock` (the message says which, and lists the known names).
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"a network is a name ({', '.join(sorted(ANN_BLOCKS))}) or an import path, got {name!r}")
    if name in ANN_BLOCKS:
        return ANN_BLOCKS[name]
    module_name, _, attribute = name.partition(":") if ":" in name else name.rpartition(".")
    if not module_name or not attribute:
        raise ValueError(f"unknown ANN block {name!r}; known: {', '.join(sorted(ANN_BLOCKS))}, or the import path "
                         "of a hypa.ann.SequenceBlock subclass (package.module.Class)")
    try:
        obj: object = importlib.import_module(module_name)
        for part in attribute.split("."):
            obj = getattr(obj, part)
    except ImportError as error:
        raise ValueError(f"network {name}: cannot import {module_name!r} ({error}); is its folder on the Python "
                         "path?") from error
    except AttributeError:
        raise ValueError(f"network {name}: module {module_name!r} has no {attribute!r}") from None
    if not (isinstance(obj, type) and issubclass(obj, SequenceBlock)) or inspect.isabstract(obj):
        raise ValueError(f"network {name}: not a concrete subclass of hypa.ann.SequenceBlock "
                         "(forward(x, state) and default_state(batch, device, dtype))")
    return obj


def target(name: str) -> str:
    """The ``_target_`` of a network: its class's import path (``hypa.ann.lstm.LSTMBlock`` for ``lstm``)."""
    cls = network_class(name)
    return f"{cls.__module__}.{cls.__qualname__}"


def ann_hyperparameters(name: str) -> dict[str, Any]:
    """The hyperparameters block ``name`` accepts, with their defaults (d_in, d_out excluded)."""
    params = list(inspect.signature(network_class(name).__init__).parameters.values())[1:]  # drop self
    return {p.name: p.default for p in params
            if p.name not in ("d_in", "d_out") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}


def build_ann(name: str, d_in: int, d_out: int, **hparams: Any) -> SequenceBlock:
    """Build the block ``name`` (a config name or an import path) mapping (B, L, d_in) -> (B, L, d_out),
    by ``hydra.utils.instantiate`` of its ``_target_`` with ``hparams``.

    Raises:
        ValueError: ``name`` is not a known block (the message lists the known names).
        TypeError: a hyperparameter the block does not accept (the message lists the accepted).
    """
    accepted = ann_hyperparameters(name)
    unknown = sorted(set(hparams) - set(accepted))
    if unknown:
        raise TypeError(
            f"ANN block {name!r} got unknown hyperparameter(s) {', '.join(unknown)}; "
            f"accepted: {', '.join(accepted)}"
        )
    try:
        return instantiate({"_target_": target(name), "_convert_": "all", **hparams}, d_in, d_out)
    except InstantiationException as error:  # the block's own check (a size < 1), as the block raised it
        if isinstance(error.__cause__, (ValueError, TypeError)):
            raise error.__cause__ from None
        raise


__all__ = [
    "ANN_BLOCKS",
    "LSTMBlock",
    "MambaBlock",
    "S4Block",
    "S4DKernel",
    "SequenceBlock",
    "TransformerBlock",
    "ann_hyperparameters",
    "build_ann",
    "network_class",
    "selective_scan",
    "target",
]
