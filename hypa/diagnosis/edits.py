"""Candidate causes as edits of a hypa model.

A cause is not a formula of its own: it is a change to the nominal :class:`~hypa.models.ModelSpec`
(a block inserted, a parameter set free, a scheduling channel connected, a sensor offset),
so the model that names it is the model ``hypa train`` trains, simulated by the one physics
engine (``hypa.physics``). The catalogue of such edits is data (:mod:`hypa.diagnosis.catalogue`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from hypa.models.spec import ModelSpec

# knob kinds: how the engine fits a candidate
GRADIENT = "gradient"  # the knobs are physical parameters, fitted by gradient descent
AFFINE = "affine"  # the output is affine in one offset: least squares from two free runs
NONE = "none"  # nothing to fit (a structural change, e.g. scheduling)


@dataclass(frozen=True)
class Candidate:
    """One candidate cause: the nominal model edited, and what to fit.

    ``cause``: the catalogue id; ``target``: the channel or parameter it acts on; ``spec``:
    the edited model; ``knobs``: parameter names (qualified, ``<block>/<name>`` for a block's
    own) that are fitted, or the offset's channel for ``affine``; ``units``: per knob.
    """

    cause: str
    target: str
    spec: ModelSpec
    fit: str
    knobs: tuple[str, ...] = ()
    units: Mapping[str, str] = field(default_factory=dict)
    learn: tuple[str, ...] = ()  # inserted blocks a network may learn instead (the catalogue's ``learn``)
    # a block's system replaced (a ``for_each: block`` entry's ``where: {system: {old: new}}``): its
    # values start as a guess in another parametrization, so it is fitted whatever its score test
    # promises (:func:`hypa.diagnosis.race.evaluate_round`)
    replaces: bool = False

    @property
    def key(self) -> str:
        return f"{self.cause}:{self.target}"


def frozen(spec: ModelSpec) -> ModelSpec:
    """The model with every parameter frozen (the nominal physics the diagnosis starts from)."""
    return dataclasses.replace(spec, blocks=tuple(dataclasses.replace(b, trainable=()) for b in spec.blocks))


def set_free(spec: ModelSpec, names: Sequence[str]) -> ModelSpec:
    """The model with the parameters ``names`` (qualified: ``<block>/<name>`` for a block's own)
    trainable as well, in the blocks that own or read them."""

    free: dict[str, list[str]] = {b.name: list(b.trainable) for b in spec.blocks}
    for name in names:
        if "/" in name:
            block, local = name.split("/", 1)
            owners = [block] if block in free else []
        else:
            local = name
            owners = [b.name for b in spec.blocks if b.kind in ("physics", "fmu") and name in b.parameter_names]
        for owner in owners:
            if local not in free[owner]:
                free[owner].append(local)
    return dataclasses.replace(spec, blocks=tuple(dataclasses.replace(b, trainable=tuple(free[b.name]))
                                                  for b in spec.blocks))


def home(spec: ModelSpec, name: str) -> tuple[tuple[str, ...], str]:
    """Where a model config holds the value of the parameter ``name``: (the blocks, its local name) for a
    block's own (``<block>/<name>``) and for an FMU's that FMU blocks set in their own ``parameters`` (which
    win over the model's: every such block), else ((), name): the model's shared ``parameters``."""
    if "/" in name:
        block, local = name.split("/", 1)
        return (block,), local
    return tuple(b.name for b in spec.blocks if b.kind == "fmu" and name in b.parameters), name


def applied(candidate: Candidate, values: Mapping[str, float]) -> ModelSpec:
    """The candidate's model with its fitted ``values`` written in and every parameter frozen again:
    the base of the next search round, and what the written model config holds."""
    spec = frozen(candidate.spec)
    if candidate.fit == AFFINE:
        return dataclasses.replace(spec, sensor_offsets={**spec.sensor_offsets, candidate.target:
                                                         float(values[candidate.target])})
    shared, own = dict(spec.parameters), {}
    for name, value in values.items():
        blocks, local = home(spec, name)
        if not blocks:
            shared[name] = float(value)
        for block in blocks:
            own.setdefault(block, {})[local] = float(value)
    blocks = tuple(dataclasses.replace(b, parameters={**b.parameters, **own[b.name]}) if b.name in own else b
                   for b in spec.blocks)
    return dataclasses.replace(spec, blocks=blocks, parameters=shared)


def averaged(specs: Sequence[ModelSpec]) -> ModelSpec:
    """One model fitted on different data (the cross-validation folds: the same structure, other
    values) with each fitted number the mean over them: the parameters (shared and the blocks'
    own) and the sensor offsets."""
    first = specs[0]
    if len(specs) == 1:
        return first

    def mean(values: Sequence[Mapping[str, object]]) -> dict[str, object]:
        out = dict(values[0])
        for name in values[0]:
            numbers = [v.get(name) for v in values]
            if all(isinstance(n, (int, float)) and not isinstance(n, bool) for n in numbers):
                out[name] = sum(float(n) for n in numbers) / len(numbers)
        return out

    blocks = tuple(dataclasses.replace(b, parameters=mean([s.blocks[i].parameters for s in specs]))
                   for i, b in enumerate(first.blocks))
    return dataclasses.replace(first, blocks=blocks, parameters=mean([s.parameters for s in specs]),
                               sensor_offsets=mean([s.sensor_offsets for s in specs]))
