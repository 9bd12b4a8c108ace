"""ANN blocks behind one causal sequence contract: ``(B, L, d_in) -> (B, L, d_out)`` plus a state.

A network is named by its config name (``lstm``, ``gru``, ``transformer``, ``s4``, ``mamba``) or by
the import path of a :class:`SequenceBlock` subclass in any importable module (``mypkg.nets.MyBlock``
or ``mypkg.nets:MyBlock``): a user's own network plugs in the way a user's own system does.
``conf/ann/*.yaml`` are Hydra ``_target_`` configs; ``build_ann(name, d_in, d_out, **hparams)``
builds a block by calling its class with its hyperparameters, the explicit keyword arguments of
the block's class (a misspelt one is named with the accepted ones). The hyperparameters are plain
values (numbers, strings, true/false, null, lists of those), checked before the call: they may come
from a checkpoint someone sent, and a nested ``_target_`` node there must never be built.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Mapping
from typing import Any

from hypa.ann.base import SequenceBlock
from hypa.ann.gru import GRUBlock
from hypa.ann.lstm import LSTMBlock
from hypa.ann.mamba import MambaBlock
from hypa.ann.mamba_scan import selective_scan
from hypa.ann.s4 import S4Block, S4DKernel
from hypa.ann.transformer import TransformerBlock

ANN_BLOCKS: dict[str, type[SequenceBlock]] = {
    "lstm": LSTMBlock,
    "gru": GRUBlock,
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
    its class called with ``hparams`` (plain values only: see :func:`check_hyperparameters`).

    Raises:
        ValueError: ``name`` is not a known block (the message lists the known names).
        TypeError: a hyperparameter the block does not accept (the message lists the accepted),
            or one that is not a plain value of its default's type.
    """
    check_hyperparameters(name, hparams)
    return network_class(name)(d_in, d_out, **hparams)


_PLAIN = (bool, int, float, str, type(None))


def check_hyperparameters(name: str, hparams: Mapping[str, Any]) -> None:
    """Check ``hparams`` for the block ``name``: keys it accepts, each value a plain one (a number, a
    string, true/false, null or a list of those) of its default's kind (a number where the default
    is a number). Raises ``TypeError`` naming the first that is not."""
    accepted = ann_hyperparameters(name)
    unknown = sorted(set(map(str, hparams)) - set(accepted))
    if unknown:
        raise TypeError(
            f"ANN block {name!r} got unknown hyperparameter(s) {', '.join(unknown)}; "
            f"accepted: {', '.join(accepted)}"
        )
    for key, value in hparams.items():
        default = accepted[key]
        plain = isinstance(value, _PLAIN) or (isinstance(value, (list, tuple)) and len(value) <= 1024
                                              and all(isinstance(v, _PLAIN) for v in value))
        number = isinstance(default, (int, float)) and not isinstance(default, bool)
        kind_ok = value is None or default is None or default is inspect.Parameter.empty or (
            isinstance(value, (int, float)) and not isinstance(value, bool) if number else
            isinstance(value, type(default)))
        if not plain or not kind_ok:
            expected = "a number" if number else type(default).__name__
            raise TypeError(f"ANN block {name!r}: hyperparameter {key} must be {expected}, got "
                            f"{type(value).__name__} {str(value)[:60]!r}")


__all__ = [
    "ANN_BLOCKS",
    "GRUBlock",
    "LSTMBlock",
    "MambaBlock",
    "S4Block",
    "S4DKernel",
    "SequenceBlock",
    "TransformerBlock",
    "ann_hyperparameters",
    "build_ann",
    "check_hyperparameters",
    "network_class",
    "selective_scan",
    "target",
]
