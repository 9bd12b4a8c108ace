"""A model as data: blocks wired by named signals (the ``model`` config group).

A composition is a list of blocks; each reads named signals and writes named signals. The
measured inputs (e.g. ``steering_wheel_angle``) are signals from the start; the model's
``outputs`` are compared with the measured states. V1, V2, V3, the physical baseline and the
pure networks are YAML files in ``conf/model/``, not Python classes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hypa.physics.systems import PHYSICS_SYSTEMS

BLOCK_KINDS = ("physics", "ann")


class ModelSpecError(ValueError):
    """A model configuration that cannot be built; the message lists what exists."""


@dataclass(frozen=True)
class BlockSpec:
    """One block of a composition.

    kind: ``physics`` (an LTI system from ``hypa.physics.systems``) or ``ann`` (a network of
        the ``ann`` config group).
    inputs / outputs: signal names read / written, in the block's own order.
    system: physics only, the registered system name (``single_track``, ``front_steering``, ...).
    trainable: physics only, parameter names learned from data (grey-box).
    residual_of: ann only, signals the network's output is added to (a correction network);
        when the block is bypassed (first stage of a staged training) its output is exactly
        these signals.
    scale_as: signals whose scale σ the outputs share, giving a network's normalized output a
        physical meaning (a learned rear-wheel angle in units of the front angle's σ, with zero
        mean so that an output of 0 is 0 rad); physics blocks take (μ, σ).
    initial_state: physics blocks with states, the measured signals whose first sample
        starts the block (default: the system's state names); ann blocks, measured states
        given to the network as an impulse at sample 0 (a pure network has no other way to
        know where a window starts).
    """

    name: str
    kind: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    system: str | None = None
    trainable: tuple[str, ...] = ()
    residual_of: tuple[str, ...] = ()
    scale_as: tuple[str, ...] = ()
    initial_state: tuple[str, ...] = ()


@dataclass(frozen=True)
class StageSpec:
    """One stage of a staged training: blocks trained, blocks bypassed."""

    name: str
    train: tuple[str, ...]
    bypass: tuple[str, ...] = ()


@dataclass(frozen=True)
class ModelSpec:
    name: str
    blocks: tuple[BlockSpec, ...]
    outputs: tuple[str, ...]
    stages: tuple[StageSpec, ...] = field(default_factory=tuple)

    @property
    def block_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.blocks)

    def block(self, name: str) -> BlockSpec:
        for b in self.blocks:
            if b.name == name:
                return b
        raise ModelSpecError(f"model {self.name!r} has no block {name!r}; blocks: {', '.join(self.block_names)}")


_BLOCK_KEYS = {"kind", "inputs", "outputs", "system", "trainable", "residual_of", "scale_as", "initial_state"}


def _names(value: Any, where: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        return (value,)
    if not isinstance(value, Sequence):
        raise ModelSpecError(f"{where} must be a list of signal names, got {value!r}")
    return tuple(str(v) for v in value)


def parse_model_spec(config: Mapping[str, Any]) -> ModelSpec:
    """Parse and check the ``model`` config (a plain mapping) into a :class:`ModelSpec`."""
    name = str(config.get("name", "model"))
    blocks_cfg = config.get("blocks") or {}
    if not blocks_cfg:
        raise ModelSpecError(f"model {name!r} has no blocks")
    blocks = []
    for block_name, b in blocks_cfg.items():
        unknown = set(b) - _BLOCK_KEYS
        if unknown:
            raise ModelSpecError(f"block {block_name!r}: unknown keys {sorted(unknown)}; known: {sorted(_BLOCK_KEYS)}")
        kind = b.get("kind")
        if kind not in BLOCK_KINDS:
            raise ModelSpecError(f"block {block_name!r}: kind must be one of {BLOCK_KINDS}, got {kind!r}")
        system = b.get("system")
        if kind == "physics" and system not in PHYSICS_SYSTEMS:
            raise ModelSpecError(
                f"block {block_name!r}: unknown physics system {system!r}; known: {', '.join(PHYSICS_SYSTEMS)}"
            )
        blocks.append(BlockSpec(
            name=str(block_name), kind=kind, inputs=_names(b.get("inputs"), f"{block_name}.inputs"),
            outputs=_names(b.get("outputs"), f"{block_name}.outputs"), system=system,
            trainable=_names(b.get("trainable"), f"{block_name}.trainable"),
            residual_of=_names(b.get("residual_of"), f"{block_name}.residual_of"),
            scale_as=_names(b.get("scale_as"), f"{block_name}.scale_as"),
            initial_state=_names(b.get("initial_state"), f"{block_name}.initial_state"),
        ))
    stages = []
    for s in config.get("stages") or []:
        stages.append(StageSpec(name=str(s["name"]), train=_names(s.get("train"), "stage.train"),
                                bypass=_names(s.get("bypass"), "stage.bypass")))
    spec = ModelSpec(name=name, blocks=tuple(blocks), outputs=_names(config.get("outputs"), "outputs"),
                     stages=tuple(stages))
    for stage in spec.stages:
        for block_name in (*stage.train, *stage.bypass):
            spec.block(block_name)  # raises with the list of blocks
        for block_name in stage.bypass:
            if not spec.block(block_name).residual_of:
                raise ModelSpecError(f"stage {stage.name!r} bypasses {block_name!r}, which has no residual_of")
    return spec
