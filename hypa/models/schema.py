"""The schema of the ``model`` config node (``conf/model/*.yaml``), as Hydra structured configs.

The commands' configurations type their ``model`` node as :class:`ModelConfig`, so Hydra rejects a
misspelt key of a model YAML (a user's own from ``--config-dir`` too) or of an override
(``model.blocks.x.inptus=...``) while composing, naming the key. :func:`hypa.models.spec.parse_model_spec`
checks a plain mapping (a checkpoint's stored model, a YAML read in Python) against the same
dataclasses: they are the one definition of a model's and a block's keys. The values stay open
(``Any``): a signal list may be one name or an interpolation (``${channels:input}``), and
:func:`~hypa.models.spec.parse_model_spec` checks them with messages that name the block.

This module imports only dataclasses and OmegaConf.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from omegaconf import MISSING


@dataclass
class BlockConfig:
    """One block (see :class:`hypa.models.spec.BlockSpec` for what each key means)."""

    kind: str = MISSING  # physics | ann | delay | saturation
    inputs: Any = None  # signal names read
    outputs: Any = None  # signal names written
    system: str | None = None  # physics: a built-in system or package.module:Class
    trainable: Any = None  # parameter names learned from data
    residual_of: Any = None  # ann: signals the output is added to
    scale_as: Any = None  # signals whose scale the outputs share
    initial_state: Any = None  # measured outputs, steady, estimate or encoder
    parameters: Any = None  # name -> value [the parameter's unit], or with a unit: 2.5 Ah, {value: 2.5, unit: Ah}
    scheduling: Any = None  # physics: parameter -> scheduling channel
    observe: Any = None  # physics: block output -> measured output
    table: Any = None  # physics scheduled by one signal: its matrices off a verified table where no gradient needs them
    curved: Any = None  # physics: state -> power (2, 3, root), couplings from the state bent (hypa.physics.curved)
    limited: Any = None  # physics: state -> upper | lower, the state held at a limit (hypa.physics.limited)
    depends: Any = None  # physics: parameter -> {by, kind}, varying with a direction or a state
    modes: Any = None  # physics: inputs each driving a first-order mode added into the outputs (hypa.physics.modes)
    driven: Any = None  # physics: signals read after its inputs, entering every state derivative


@dataclass
class StageConfig:
    """One stage of a staged training: blocks trained, blocks bypassed."""

    name: str = MISSING
    train: Any = None
    bypass: Any = None


@dataclass
class ModelConfig:
    """The ``model`` node (see :class:`hypa.models.spec.ModelSpec`)."""

    name: str = "model"
    blocks: dict[str, BlockConfig] = field(default_factory=dict)
    outputs: Any = None
    stages: list[StageConfig] = field(default_factory=list)
    hold: str | None = None  # zoh | foh | cubic, overriding physics.hold of the run
    parameters: Any = None  # shared physical parameters (as a block's), overriding the vehicle config
    sensor_offsets: Any = None  # measured - true [SI]


def keys(schema: type) -> tuple[str, ...]:
    """The keys a node of ``schema`` may have, in declared order."""
    return tuple(f.name for f in fields(schema))


def unknown_keys(node: Mapping[str, Any], schema: type) -> list[str]:
    """The keys of ``node`` that ``schema`` does not have, sorted."""
    return sorted(set(map(str, node)) - set(keys(schema)))


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
