"""Candidate causes as edits of a hypa model: the generic catalogue, for any system.

A cause is not a formula of its own: it is a change to the nominal :class:`~hypa.models.ModelSpec`
(a block inserted, a parameter set free, a scheduling channel connected, a sensor offset),
so the model that names it is the model ``hypa.train`` trains, simulated by the one physics
engine (``hypa.physics``). Every system gets these entries:

====================  ==============================================================
id                    edit
====================  ==============================================================
input_delay           a dead time (``kind: delay``) between a measured input and the model
input_lag             a first-order lag (``first_order_lag``) on a measured input
input_offset          a constant bias of a measured input (``sensor_offsets``)
output_offset         a constant bias of a measured output (``sensor_offsets``)
parameter_mismatch    one physical parameter re-fitted (``trainable``)
scheduling            a parameter that the model holds fixed follows a measured channel
====================  ==============================================================
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from hypa.models.spec import STEADY, BlockSpec, ModelSpec
from hypa.physics.systems import build_system

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

    @property
    def key(self) -> str:
        return f"{self.cause}:{self.target}"


def frozen(spec: ModelSpec) -> ModelSpec:
    """The model with every parameter frozen (the nominal physics the diagnosis starts from)."""
    return dataclasses.replace(spec, blocks=tuple(dataclasses.replace(b, trainable=()) for b in spec.blocks))


def _rewire(spec: ModelSpec, signal: str, new: str, inserted: BlockSpec) -> ModelSpec:
    """Insert ``inserted`` (reading ``signal``, writing ``new``) and let every other block read ``new``."""
    blocks = tuple(dataclasses.replace(b, inputs=tuple(new if s == signal else s for s in b.inputs))
                   for b in spec.blocks)
    return dataclasses.replace(spec, blocks=(inserted, *blocks))


def generic_candidates(spec: ModelSpec, input_names: Sequence[str], output_names: Sequence[str],
                       scheduling_names: Sequence[str], physical_values: Mapping[str, float], dt: float,
                       uncertain: Mapping[str, Sequence[str]] | None = None) -> list[Candidate]:
    """The generic catalogue's candidates for ``spec`` and the data's channels.

    ``parameter_mismatch`` re-fits the parameters the model declares uncertain (its blocks'
    ``trainable``: a stiffness, not a measured mass; or ``uncertain``, block -> parameter names),
    or every parameter when it declares none. The edits start from the model with all frozen.
    """
    uncertain = {b.name: set(b.trainable) for b in spec.blocks} if uncertain is None else {
        k: set(v) for k, v in uncertain.items()}
    declared = any(uncertain.values())
    spec = frozen(spec)
    out: list[Candidate] = []
    consumed = {s for b in spec.blocks for s in b.inputs}
    for name in input_names:
        if name not in consumed:
            continue
        block = f"diagnosed_delay_{name}"
        out.append(Candidate("input_delay", name, _rewire(spec, name, f"{name}__delayed", BlockSpec(
            name=block, kind="delay", inputs=(name,), outputs=(f"{name}__delayed",),
            parameters={"delay_s": 2.0 * dt}, trainable=("delay_s",))), GRADIENT, (f"{block}/delay_s",),
            {f"{block}/delay_s": "s"}))
        block = f"diagnosed_lag_{name}"
        out.append(Candidate("input_lag", name, _rewire(spec, name, f"{name}__lagged", BlockSpec(
            name=block, kind="physics", system="first_order_lag", inputs=(name,), outputs=(f"{name}__lagged",),
            parameters={"tau_s": 2.0 * dt}, trainable=("tau_s",), initial_state=(STEADY,))), GRADIENT,
            (f"{block}/tau_s",), {f"{block}/tau_s": "s"}))
        out.append(Candidate("input_offset", name, spec, AFFINE, (name,)))
    for name in output_names:
        out.append(Candidate("output_offset", name, spec, AFFINE, (name,)))
    for b in spec.blocks:
        if b.kind != "physics":
            continue
        for p in build_system(b.system, b.name).parameter_specs({**physical_values, **spec.parameters}):
            local = p.name.split("/", 1)[-1]
            if local in b.scheduling:
                continue
            if local in scheduling_names:
                out.append(Candidate("scheduling", local, _edit_block(spec, b.name, scheduling={
                    **b.scheduling, local: local}), NONE))
                continue
            if declared and local not in uncertain.get(b.name, ()):
                continue
            out.append(Candidate("parameter_mismatch", p.name, _edit_block(spec, b.name, trainable=(local,)),
                                 GRADIENT, (p.name,), {p.name: p.unit}))
    return out


def _edit_block(spec: ModelSpec, name: str, **changes) -> ModelSpec:
    return dataclasses.replace(spec, blocks=tuple(dataclasses.replace(b, **changes) if b.name == name else b
                                                  for b in spec.blocks))


def applied(candidate: Candidate, values: Mapping[str, float]) -> ModelSpec:
    """The candidate's model with its fitted ``values`` written in and every parameter frozen again:
    the base of the next search round, and what the written model config holds."""
    spec = frozen(candidate.spec)
    if candidate.fit == AFFINE:
        return dataclasses.replace(spec, sensor_offsets={**spec.sensor_offsets, candidate.target:
                                                         float(values[candidate.target])})
    shared, own = dict(spec.parameters), {}
    for name, value in values.items():
        if "/" in name:
            block, local = name.split("/", 1)
            own.setdefault(block, {})[local] = float(value)
        else:
            shared[name] = float(value)
    blocks = tuple(dataclasses.replace(b, parameters={**b.parameters, **own[b.name]}) if b.name in own else b
                   for b in spec.blocks)
    return dataclasses.replace(spec, blocks=blocks, parameters=shared)
