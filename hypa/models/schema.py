"""The schema of the ``model`` config node (``conf/model/*.yaml``), as Hydra structured configs.

The commands' configurations type their ``model`` node as :class:`ModelConfig`, so Hydra rejects a
misspelt key of a model YAML (a user's own from ``--config-dir`` too) or of an override
(``model.blocks.x.inptus=...``) while composing, naming the key. The classes are made from the
fields of :class:`~hypa.models.spec.ModelSpec`, :class:`~hypa.models.spec.BlockSpec` and
:class:`~hypa.models.spec.StageSpec` (which say what each key means), the one definition of the
keys, which :func:`~hypa.models.spec.parse_model_spec` checks a plain mapping against too (a
checkpoint's stored model, a YAML read in Python). The values stay open (``Any``): a signal list
may be one name or an interpolation (``${channels:input}``), and
:func:`~hypa.models.spec.parse_model_spec` checks them with messages that name the block.

This module imports only dataclasses, OmegaConf and :mod:`hypa.models.spec` (no torch).
"""

from __future__ import annotations

import typing
from collections.abc import Mapping
from dataclasses import MISSING as NO_DEFAULT
from dataclasses import Field, field, fields, make_dataclass
from typing import Any

from omegaconf import MISSING

from hypa.models.spec import BlockSpec, ModelSpec, StageSpec, keys, unknown_keys

__all__ = ["BlockConfig", "ModelConfig", "StageConfig", "config_schema", "keys", "plain_model", "unknown_keys"]


def config_schema(spec: type, class_name: str, doc: str, /, **typed: tuple[Any, Any]) -> type:
    """The Hydra schema (a dataclass named ``class_name``) of the config node of the dataclass ``spec``: its
    keys (:func:`~hypa.models.spec.keys`) in order, each ``Any`` with the default ``None``, but a
    string the spec requires ``MISSING`` (Hydra asks for it) and an optional string ``str | None``.
    ``typed``: key -> (type, default or ``dataclasses.field``), where the schema says more."""
    hints = typing.get_type_hints(spec)

    def entry(f: Field) -> tuple[str, Any, Field]:
        if f.name in typed:
            kind, default = typed[f.name]
        elif hints[f.name] is str and f.default is NO_DEFAULT:
            kind, default = str, MISSING
        elif hints[f.name] == str | None:
            kind, default = str | None, None
        else:
            kind, default = Any, None
        return f.name, kind, default if isinstance(default, Field) else field(default=default)

    schema = make_dataclass(class_name, [entry(f) for f in fields(spec) if f.name in keys(spec)])
    schema.__module__, schema.__doc__ = __name__, doc  # pickled and documented as this module's
    return schema


BlockConfig = config_schema(BlockSpec, "BlockConfig", "One block, ``blocks.<name>`` (see :class:`~hypa.models.spec."
                            "BlockSpec` for what each key means).")
StageConfig = config_schema(StageSpec, "StageConfig", "One stage of a staged training: blocks trained, blocks "
                            "bypassed (:class:`~hypa.models.spec.StageSpec`).")
ModelConfig = config_schema(ModelSpec, "ModelConfig", "The ``model`` node (see :class:`~hypa.models.spec.ModelSpec`).",
                            name=(str, "model"), blocks=(dict[str, BlockConfig], field(default_factory=dict)),
                            stages=(list[StageConfig], field(default_factory=list)))


def plain_model(node: Mapping[str, Any]) -> dict[str, Any]:
    """A resolved model node as the plain mapping a model YAML holds: the keys the schema filled
    with ``null`` left out (what a checkpoint stores, as before the schema)."""
    def drop_nulls(entry: Mapping[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in entry.items() if v is not None}

    out = drop_nulls(node)
    if isinstance(out.get("blocks"), Mapping):
        out["blocks"] = {name: drop_nulls(b) if isinstance(b, Mapping) else b for name, b in out["blocks"].items()}
    if isinstance(out.get("stages"), list):
        out["stages"] = [drop_nulls(s) if isinstance(s, Mapping) else s for s in out["stages"]]
    return out
