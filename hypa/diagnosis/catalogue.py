"""The catalogue of candidate causes as data: YAML entries that edit a hypa model.

An entry (``hypa/diagnosis/catalogue.yaml`` for every system, ``hypa/vehicle/catalogue.yaml`` for
the vehicle's, a user's own file with ``diagnosis.catalogue=[PATH]``)::

    - id: input_delay                  # the cause's id in reports and diagnosis.json
      name: dead time on a measured input
      for_each: input                  # input | output | parameter | scheduling | block | state |
                                       # auxiliary | block_input | fmu_input
      where: {system: [single_track_front]}   # block only: blocks of these systems, or a
                                       # mapping {system: its replacement, ...} read as {system}
      when: {rws_ratio: nonzero}       # only where these nominal parameters are (non)zero
      fit: gradient                    # gradient (its trainable knobs) | offset | none
      offset: "{input}"                # fit: offset, the measured signal whose bias is fitted
      patch:                           # the edit, in the model config's own terms
        rewire: {"{input}": "{input}__delayed"}   # every existing block reads the new signal
        blocks:                        # new blocks, or keys merged into an existing one
          diagnosed_delay_{input}: {kind: delay, inputs: ["{input}"], outputs: ["{input}__delayed"],
                                    parameters: {delay_s: 2 * dt}, trainable: [delay_s]}
        parameters: {}                 # shared parameter values
      learn: [diagnosed_rear_steering]   # inserted blocks that stand in for a subsystem nobody
                                       # modelled: diagnosed_learned.yaml learns each with a network

Placeholders: ``{input}``, ``{output}``, ``{block}``, ``{parameter}`` (the block's own name of
it), ``{channel}`` (scheduling), ``{block_input}`` (the block's first input), ``{block_outputs[i]}``
(its i-th output), ``{block_scheduling}`` (a whole value: the block's scheduling mapping, so that a
new block is scheduled like it), ``{system}`` (the
replacement of the matched block's system, when ``where.system`` is a mapping), ``{state}`` and
``{couplings}`` (``for_each: state``: a state of a physics block, and as a whole value the
names of the ``curve_<state>_on_<row>`` weights of its nonzero couplings, ``hypa.physics.curved``;
``{curve}`` the one ``curve_<state>`` of a root, empty where the state has no coupling;
an entry whose trainable list comes out empty does not apply to that state), ``{spills}`` (the
names of the ``spill_<state>_to_<row>`` shares into the other states, ``hypa.physics.limited``).
A list placeholder among a list's items is spliced in: ``trainable: ["{state}_limit", "{spills}"]``.
A parameter value may be an expression of ``dt`` [s], the sample time, of ``peak`` (the largest
|value| in the training data of the entry's measured channel, or of the matched block's first
input; of a signal between blocks, |mean| + 3 spreads in the model's scaling), of the model's
parameters by name, and for ``for_each: block`` of the block's states'
``<state>_level`` and ``<state>_spread`` (their operating point and spread); ``for_each: state`` adds
``level`` and ``spread``, the state's operating point and spread in the round's model's scaling,
and ``low`` and ``high``, the 10th and 90th percentiles of the state in that model's free runs
over the training data, and ``bottom`` and ``top``, where a limit on it starts: the smallest and
largest value the data show of a state a measured output reads alone, else ``low`` and ``high``.
``for_each: auxiliary`` visits each measured input no block reads (an auxiliary channel the
diagnosis holds as an input, ``HypaDataModule(auxiliary_inputs=True)``) for each physics block with
states: ``{channel}``, ``{block}``, ``{block_inputs}`` and ``{block_driven}`` (its inputs and driven
signals, lists), ``{drives}`` and ``{drive_scales}`` (the names of the channel's weights in each
state derivative, and a mapping of their fixed sizes, ``hypa.physics.dependent.Driven``).
``for_each: fmu_input`` visits each input of an FMU block that no signal feeds, with each measured input
channel as its source: ``{block}``, ``{fmu_input}`` (the FMU's variable; ``{fmu_input_id}`` as an
identifier), ``{channel}``, ``{block_inputs}``.
``for_each: block_input`` visits each input of each physics block with states that writes a model
output: ``{block}``, ``{mode}`` (the system's name of the input), ``{block_input}`` (its signal),
``{block_modes}``, ``{mode_weights}`` and ``{mode_parameters}`` (a mapping: the mode's time constant,
``tau``, and its weights' sizes, ``hypa.physics.modes``). A ``for_each: parameter`` entry with
``by: [input, state]`` is repeated for each input and state of the parameter's block (``{on}``; its
expressions read ``on_level`` and ``on_spread``), for parameters that act on the state equation, of
systems no ``for_each: block`` entry names. ``scan: {variable: {name: start, ...}}`` makes a candidate per
start value (expressions, e.g. of ``slowest``: the model's slowest decay time at this round's values),
the target naming the start (``current, slow start``; a list of starts: ``start 1 of 3``).
``for_each: state`` visits the states of the physics blocks whose system no ``for_each: block``
entry names (the catalogue's own physics of a system comes first), other than a cause's own
``diagnosed_`` blocks and scheduled ones. Which
parameters ``for_each: parameter`` visits: those the nominal model declares uncertain (its
blocks' ``trainable``), or all.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hypa.core.errors import UserError
from hypa.core.plugins import plugins
from hypa.diagnosis.edits import AFFINE, GRADIENT, NONE, Candidate, frozen
from hypa.models.spec import ELEMENT_PARAMETER, ModelSpec, ModelSpecError, parse_model_spec

GENERIC = Path(__file__).with_name("catalogue.yaml")
FOR_EACH = ("input", "output", "parameter", "scheduling", "block", "state", "auxiliary", "block_input", "fmu_input")
FITS = {"gradient": GRADIENT, "offset": AFFINE, "none": NONE}
_KEYS = {"id", "name", "for_each", "where", "when", "fit", "offset", "patch", "learn", "by", "scan"}
ON = ("input", "state")  # what a for_each: parameter entry's ``by`` visits: the block's inputs, its states
_WHEN = ("zero", "nonzero")
_PATCH_KEYS = {"rewire", "blocks", "parameters"}


class CatalogueError(UserError):
    """A catalogue entry that cannot be used; the message names the file and the entry."""


@dataclass(frozen=True)
class Entry:
    """One catalogue entry (see the module docstring)."""

    id: str
    name: str
    for_each: str
    fit: str
    patch: Mapping[str, Any] = field(default_factory=dict)
    where: Mapping[str, Any] = field(default_factory=dict)
    when: Mapping[str, str] = field(default_factory=dict)  # parameter -> zero | nonzero
    offset: str = ""
    source: str = ""
    learn: tuple[str, ...] = ()  # blocks of the patch a network may learn instead (placeholders allowed)
    on: tuple[str, ...] = ()  # ``by``: for_each: parameter, also each of the block's inputs / states (ON)
    # variable -> its starts, (name, expression) each, a candidate each
    scan: Mapping[str, tuple[tuple[str, Any], ...]] = field(default_factory=dict)

    def applies(self, values: Mapping[str, float]) -> bool:
        """Whether the nominal parameter values allow the entry (``when``; a missing one: no)."""
        return all(name in values and (values[name] != 0) == (want == "nonzero") for name, want in self.when.items())


def builtin_catalogues() -> list[Path]:
    """The generic catalogue and each domain package's (the entry points ``hypa.catalogues``,
    :mod:`hypa.core.plugins`: the vehicle's)."""
    return [GENERIC, *(Path(path) for path in plugins("catalogues").values())]


def load_catalogue(paths: Sequence[Path | str] = ()) -> list[Entry]:
    """The built-in entries and those of ``paths`` (a user's YAML files), checked."""
    entries: list[Entry] = []
    for path in [*builtin_catalogues(), *(Path(p).expanduser() for p in paths)]:
        if not path.is_file():
            raise CatalogueError(f"catalogue {path} does not exist")
        try:
            raw = yaml.safe_load(path.read_text())
        except yaml.YAMLError as error:
            raise CatalogueError(f"catalogue {path} is not valid YAML: {str(error).splitlines()[0]}") from None
        if not isinstance(raw, list):
            raise CatalogueError(f"catalogue {path} must be a list of entries (- id: ...)")
        entries += [_entry(item, path) for item in raw]
    return entries


def _entry(item: Any, path: Path) -> Entry:
    where = f"catalogue {path}, entry {item.get('id', '?') if isinstance(item, dict) else item!r}"
    if not isinstance(item, dict):
        raise CatalogueError(f"{where}: an entry is a mapping with id, for_each, fit and patch or offset")
    unknown = set(item) - _KEYS
    if unknown:
        raise CatalogueError(f"{where}: unknown keys {sorted(unknown)}; known: {sorted(_KEYS)}")
    if not item.get("id"):
        raise CatalogueError(f"{where}: missing id")
    if item.get("for_each") not in FOR_EACH:
        raise CatalogueError(f"{where}: for_each must be one of {', '.join(FOR_EACH)}, got {item.get('for_each')!r}")
    if item.get("fit", "gradient") not in FITS:
        raise CatalogueError(f"{where}: fit must be one of {', '.join(FITS)}, got {item.get('fit')!r}")
    patch = item.get("patch") or {}
    if not isinstance(patch, dict) or set(patch) - _PATCH_KEYS:
        raise CatalogueError(f"{where}: patch takes {', '.join(sorted(_PATCH_KEYS))}")
    fit = FITS[item.get("fit", "gradient")]
    if fit == AFFINE and not item.get("offset"):
        raise CatalogueError(f"{where}: fit: offset needs offset: <the signal>, e.g. offset: \"{{input}}\"")
    if fit != AFFINE and not patch:
        raise CatalogueError(f"{where}: needs a patch (the edit of the model)")
    when = item.get("when") or {}
    if not isinstance(when, dict) or any(v not in _WHEN for v in when.values()):
        raise CatalogueError(f"{where}: when maps parameters to zero or nonzero, got {when!r}")
    if item["for_each"] == "block" and not (item.get("where") or {}).get("system"):
        raise CatalogueError(f"{where}: for_each: block needs where: {{system: [...]}}")
    if item["for_each"] == "state" and (item.get("where") or {}) not in ({}, {"state": "positive"}):
        raise CatalogueError(f"{where}: for_each: state takes where: {{state: positive}} (a state whose free runs "
                             f"stay above 0) or none, got {item.get('where')!r}")
    learn = item.get("learn") or []
    learn = [learn] if isinstance(learn, str) else learn
    unknown = [b for b in learn if b not in (patch.get("blocks") or {})]
    if not isinstance(learn, list) or unknown:
        raise CatalogueError(f"{where}: learn lists blocks of the patch (a network learns each instead), "
                             f"got {item.get('learn')!r}")
    on = item.get("by") or []
    on = [on] if isinstance(on, str) else on
    if not isinstance(on, list) or any(o not in ON for o in on) or (on and item["for_each"] != "parameter"):
        raise CatalogueError(f"{where}: by lists {' and/or '.join(ON)} (for_each: parameter only), "
                             f"got {item.get('by')!r}")
    scan = item.get("scan") or {}
    if not isinstance(scan, dict) or len(scan) > 1 or not all(
            str(k).isidentifier() and v and (isinstance(v, list) or (
                isinstance(v, dict) and all(isinstance(n, str) and n.strip() for n in v))) for k, v in scan.items()):
        raise CatalogueError(f"{where}: scan maps one variable to its start values (expressions), a list or named "
                             f"starts ({{fast: 3 * dt, slow: 3 * slowest}}), got {scan!r}")
    return Entry(id=str(item["id"]), name=str(item.get("name", item["id"])), for_each=item["for_each"], fit=fit,
                 patch=patch, where=item.get("where") or {}, when=when, offset=str(item.get("offset", "")),
                 source=str(path), learn=tuple(str(b) for b in learn), on=tuple(on),
                 scan={str(k): tuple(v.items()) if isinstance(v, dict) else tuple((f"start {i + 1} of {len(v)}", e)
                                                                                   for i, e in enumerate(v))
                       for k, v in scan.items()})


def _format(value: Any, context: Mapping[str, Any]) -> Any:
    """Fill the placeholders in every string of a nested value (keys too)."""
    if isinstance(value, str):
        whole = value[1:-1] if value.startswith("{") and value.endswith("}") else None
        if whole in context and not isinstance(context[whole], str):  # a mapping or list placeholder, itself
            return copy.deepcopy(context[whole])
        return value.format(**context)
    if isinstance(value, list):  # a list placeholder among other items is spliced in: [a, "{couplings}"]
        out: list[Any] = []
        for v in value:
            formatted = _format(v, context)
            out += formatted if isinstance(formatted, list) and not isinstance(v, list) else [formatted]
        return out
    if isinstance(value, dict):
        return {_format(k, context): _format(v, context) for k, v in value.items()}
    return value


def _number(value: Any, variables: Mapping[str, float], where: str) -> float:
    if isinstance(value, (int, float)):
        return float(value)
    from hypa.data.expressions import Expression

    try:
        return float(Expression(str(value), where).evaluate(dict(variables), where))
    except Exception as error:  # noqa: BLE001 -- a catalogue's expression: report it on one line
        raise CatalogueError(f"{where}: parameter value {value!r} is neither a number nor an expression of "
                             f"{', '.join(variables)} ({error})") from None


def apply_patch(spec: ModelSpec, patch: Mapping[str, Any], dt: float, where: str = "",
                variables: Mapping[str, float] | None = None) -> ModelSpec:
    """The model with a (formatted) patch applied: signals rewired, blocks added or merged, shared
    parameters set. New blocks come first (the composition is ordered by dependency anyway).
    Parameter values may be expressions of ``dt`` [s] and of ``variables`` (``peak``: the
    largest |value| of the entry's channel in the training data; the model's parameters by
    their names, at their current values)."""
    variables = {**(variables or {}), "dt": dt}
    from hypa.models.spec import spec_config
    from hypa.physics.fmu_block import resignaled

    config = spec_config(spec)
    rewire = patch.get("rewire") or {}
    for block in config["blocks"].values():
        if block.get("fmu") is not None:  # an FMU's input keeps its variable, fed by the new signal
            block["rename"] = resignaled(block.get("rename") or {},
                                         {s: rewire[s] for s in block["inputs"] if s in rewire})
        block["inputs"] = [rewire.get(s, s) for s in block["inputs"]]
    new = {}
    for name, fields in (patch.get("blocks") or {}).items():
        fields = copy.deepcopy(fields)
        if "parameters" in fields:
            fields["parameters"] = {k: _number(v, variables, where) for k, v in fields["parameters"].items()}
        if name in config["blocks"]:
            target = config["blocks"][name]
            for key, value in fields.items():
                target[key] = {**target.get(key, {}), **value} if isinstance(value, dict) else value
        else:
            new[name] = fields
    config["blocks"] = {**new, **config["blocks"]}
    if patch.get("parameters"):
        config["parameters"] = {**config.get("parameters", {}),
                                **{k: _number(v, variables, where) for k, v in patch["parameters"].items()}}
    try:
        return parse_model_spec(config)
    except ModelSpecError as error:
        raise CatalogueError(f"{where}: the edited model is not valid: {error}") from None


def specific_systems(entries: Sequence[Entry]) -> set[str]:
    """The systems some ``for_each: block`` entry names (matched or put in): the catalogue's own
    physics of them comes before the generic ``for_each: state`` entries."""
    named: set[str] = set()
    for entry in entries:
        systems = entry.where.get("system", ()) if entry.for_each == "block" else ()
        named.update(systems)
        named.update(systems.values() if isinstance(systems, Mapping) else ())
    return named


def _state_block(b: Any, specific: set[str]) -> bool:
    """Whether ``for_each: state`` entries visit the states of the block ``b`` (see below)."""
    return (b.kind == "physics" and b.system not in specific and not b.scheduling
            and not b.name.startswith("diagnosed_"))


def state_blocks(entries: Sequence[Entry], spec: ModelSpec) -> set[str]:
    """The blocks of ``spec`` whose states the entries of ``entries`` read: those the ``for_each:
    state`` entries visit, and those a ``for_each: block`` entry matches (its expressions read the
    block's ``<state>_level``: a tank's level where its outflow through an orifice starts)."""
    specific = specific_systems(entries)
    visited = ({b.name for b in spec.blocks if _state_block(b, specific)}
               if any(e.for_each == "state" for e in entries) else set())
    matched = {b.name for b in spec.blocks for e in entries
               if e.for_each == "block" and b.kind == "physics" and b.system in e.where.get("system", ())}
    return visited | matched


def _state_contexts(spec: ModelSpec, values: Mapping[str, float], specific: set[str]
                    ) -> Iterator[tuple[str, dict[str, Any]]]:
    """Each state of a physics block that the catalogue has no own physics for (not scheduled,
    not a cause's own ``diagnosed_`` block, not curved or limited yet), with the weights of its
    nonzero couplings into the state derivatives at the current values (``{couplings}``: none
    where its dynamics are all in a nonlinearity) and the shares of a spill into the others
    (``{spills}``)."""
    import torch

    from hypa.physics.curved import curve_name
    from hypa.physics.limited import spill_name

    for b in spec.blocks:
        if not _state_block(b, specific):
            continue
        system = b.system_model()
        if not system.n_states:
            continue
        given = {p.name: torch.tensor(p.value, dtype=torch.float64)
                 for p in system.parameter_specs({**values, **spec.parameters})}
        a = system.matrices(given).a
        for j, state in enumerate(system.state_names):
            if state in b.curved or state in b.limited:
                continue
            rows = [r for i, r in enumerate(system.state_names) if float(a[i, j]) != 0.0]
            yield f"{b.name}/{state}", {"block": b.name, "state": state,
                                        "couplings": [curve_name(state, r) for r in rows],
                                        "curve": [curve_name(state)] if rows else [],
                                        "spills": [spill_name(state, r) for r in system.state_names if r != state]}


def _contexts(entry: Entry, spec: ModelSpec, inputs: Sequence[str], outputs: Sequence[str],
              scheduling: Sequence[str], values: Mapping[str, float], uncertain: Mapping[str, Sequence[str]],
              specific: set[str] = frozenset()) -> Iterator[tuple[str, dict[str, Any]]]:
    """(target, placeholders) for each place the entry applies to."""
    if entry.for_each == "state":
        yield from _state_contexts(spec, values, specific)
    elif entry.for_each == "auxiliary":
        consumed = {s for b in spec.blocks for s in (*b.inputs, *b.scheduling.values())}
        blocks = [b for b in spec.blocks if b.kind == "physics" and not b.name.startswith("diagnosed_")
                  and not b.scheduling and b.system_model().n_states]
        for n in inputs:
            if n in consumed or n in scheduling:
                continue
            for b in blocks:
                yield (n if len(blocks) == 1 else f"{b.name}/{n}"), {
                    "channel": n, "block": b.name, "block_inputs": list(b.inputs), "block_driven": list(b.driven)}
    elif entry.for_each == "block_input":
        yield from _block_inputs(spec, outputs)
    elif entry.for_each == "fmu_input":
        yield from _fmu_inputs(spec, inputs)
    elif entry.for_each == "input":
        consumed = {s for b in spec.blocks for s in b.inputs}
        yield from ((n, {"input": n}) for n in inputs if n in consumed)
    elif entry.for_each == "output":
        yield from ((n, {"output": n}) for n in outputs)
    elif entry.for_each == "block":
        systems = entry.where.get("system", ())
        replace = systems if isinstance(systems, Mapping) else {}
        yield from ((b.name, {"block": b.name, "block_input": b.inputs[0] if b.inputs else "",
                              "block_outputs": list(b.outputs), "block_scheduling": dict(b.scheduling),
                              "system": replace.get(b.system, b.system)})
                    for b in spec.blocks if b.kind == "physics" and b.system in systems)
    else:
        declared = any(uncertain.values())
        for b in spec.blocks:
            if b.kind == "fmu" and entry.for_each == "parameter" and not entry.on:  # its Real parameters: refits
                yield from ((name, {"block": b.name, "parameter": name, "qualified": name})
                            for name in b.parameter_names
                            if name not in scheduling and (not declared or name in uncertain.get(b.name, ())))
            if b.kind != "physics":
                continue
            system = b.system_model()
            for p in system.parameter_specs({**values, **spec.parameters}):
                local = p.name.split("/", 1)[-1]
                if local in b.scheduling or p.name in getattr(system, "added", ()):
                    continue  # a curved state's level, spread and weights belong to that cause, not the physics
                if entry.for_each == "scheduling" and local in scheduling:
                    yield local, {"block": b.name, "parameter": local, "channel": local, "qualified": p.name}
                elif (entry.for_each == "parameter" and local not in scheduling
                      and (not declared or local in uncertain.get(b.name, ()))):
                    context = {"block": b.name, "parameter": local, "qualified": p.name}
                    if not entry.on:
                        yield p.name, context
                    elif (_state_block(b, specific) and local not in b.depends
                          and _in_dynamics(system, {**values, **spec.parameters}, p.name)):
                        for kind in entry.on:  # a parameter that varies with a signal of its block (not a driven one)
                            signals = system.input_names if kind == "input" else system.state_names
                            for i, on in enumerate(signals):
                                if kind == "input" and b.inputs[i] in b.driven:
                                    continue
                                yield f"{p.name} on {on}", {**context, "on": on, "on_kind": kind,
                                                            "on_signal": b.inputs[i] if kind == "input" else ""}


def _fmu_inputs(spec: ModelSpec, inputs: Sequence[str]) -> Iterator[tuple[str, dict[str, Any]]]:
    """Each input of an FMU block that no signal feeds (it stays at its start value), with each measured
    input channel (an auxiliary one among them) as the signal it may follow: ``{fmu_input}`` (the FMU's
    variable), ``{fmu_input_id}`` (as an identifier), ``{channel}``, ``{block}``, ``{block_inputs}``; the
    target ``<variable> from <channel>`` (``<block>/...`` where several FMU blocks have one)."""
    from hypa.physics.fmu import read_fmu
    from hypa.physics.fmu_block import fmu_variables

    blocks = [b for b in spec.blocks if b.kind == "fmu"]
    for b in blocks:
        fed = set(fmu_variables(b.rename, b.inputs))
        for name in read_fmu(b.fmu or "").input_names:
            if name in fed:
                continue
            for channel in inputs:
                target = f"{name} from {channel}"
                yield (target if len(blocks) == 1 else f"{b.name}/{target}"), {
                    "block": b.name, "fmu_input": name, "fmu_input_id": re.sub(r"\W", "_", name), "channel": channel,
                    "block_inputs": list(b.inputs)}


def _block_inputs(spec: ModelSpec, outputs: Sequence[str]) -> Iterator[tuple[str, dict[str, Any]]]:
    """Each input of each physics block with states that writes a model output (not a cause's own
    ``diagnosed_`` block, not scheduled), but one that drives a mode of the block already: the
    place of a mode it lacks (``hypa.physics.modes``), its target the input's signal (``<block>/<signal>``
    where several blocks qualify)."""
    blocks = [b for b in spec.blocks if b.kind == "physics" and not b.name.startswith("diagnosed_")
              and not b.scheduling and set(b.outputs) & set(outputs) and b.system_model().n_states]
    for b in blocks:
        system = b.system_model()
        for name, signal in zip(system.input_names, b.inputs):
            if name in b.modes or signal in b.driven:
                continue
            yield (signal if len(blocks) == 1 else f"{b.name}/{signal}"), {
                "block": b.name, "mode": name, "block_input": signal, "block_modes": list(b.modes),
                "block_outputs": list(b.outputs), "system_outputs": list(system.output_names)}


def _mode_parameters(context: Mapping[str, Any], channels: Mapping[str, tuple[float, str]]
                     ) -> tuple[list[str], dict[str, Any]] | None:
    """``{mode_weights}`` and ``{mode_parameters}`` of ``missing_mode``: the weights of the mode on
    the block's outputs, and its time constant (``tau``, the scanned start) and the weights' sizes,
    each output's largest value over the input's (None where a size is not known)."""
    from hypa.physics.modes import mode_names

    # named by the system's own outputs (the wrapper's names), sized by the signals they are wired to
    tau, weights, scales = mode_names(context["mode"], context["system_outputs"])
    peak = channels.get(context["block_input"], (0.0, ""))[0]
    sizes = [channels.get(o, (0.0, ""))[0] for o in context["block_outputs"]]
    if not peak > 0 or not all(size > 0 for size in sizes):
        return None
    return weights, {tau: "tau", **{k: size / peak for k, size in zip(scales, sizes)}}


def _in_dynamics(system: Any, values: Mapping[str, float], name: str) -> bool:
    """Whether the parameter ``name`` changes the system's A, B or e (what a ``depends`` acts on,
    ``hypa.physics.dependent``) at the current values: not one seen at the outputs only."""
    import torch

    given = {p.name: torch.tensor(p.value, dtype=torch.float64) for p in system.parameter_specs(values)}

    def stacked(p: Mapping[str, Any]) -> Any:
        ss = system.matrices(p)
        return torch.cat([ss.a.reshape(-1), ss.b.reshape(-1), *([ss.e.reshape(-1)] if ss.e is not None else [])])

    p0 = given[name]
    moved = stacked({**given, name: p0 * 1.01 if float(p0) != 0.0 else p0 + 1e-3})
    return bool((moved != stacked(given)).any())


def _slowest(spec: ModelSpec, values: Mapping[str, float], dt: float) -> float:
    """The slowest decay time [s] of the model's physics blocks at the current values (their linear
    parts; integrators left out): ``slowest`` in an entry's expressions. A model without a decaying
    mode: 100 sample times."""
    import torch

    times = []
    for b in spec.blocks:
        if b.kind != "physics" or b.scheduling:
            continue
        system = b.system_model()
        if not system.n_states:
            continue
        given = {p.name: torch.tensor(p.value, dtype=torch.float64) for p in system.parameter_specs(values)}
        rates = -torch.linalg.eigvals(system.matrices(given).a).real
        times += [1.0 / float(r) for r in rates if float(r) > 1e-9 / dt]
    return max(times) if times else 100.0 * dt


def _drives(spec: ModelSpec, block: str, channel: str, values: Mapping[str, float],
            states: Mapping[str, tuple[float, ...]], peak: float, dt: float
            ) -> tuple[list[str], dict[str, float]] | None:
    """``{drives}`` and ``{drive_scales}`` of ``unread_channel``: the weights of ``channel`` in each state
    derivative of ``block`` and their sizes k_r = σ_r ρ / peak (``hypa.physics.dependent.Driven``): a
    weight of 1 moves the state by one spread at the block's fastest rate ρ (its spectral radius; 1 / dt
    where it has none) for the channel at its largest value. None where a state's spread is unknown."""
    import torch

    from hypa.physics.dependent import drive_name, drive_scale_name

    b = spec.block(block)
    system = b.system_model()
    given = {p.name: torch.tensor(p.value, dtype=torch.float64) for p in system.parameter_specs(values)}
    rate = float(torch.linalg.eigvals(system.matrices(given).a).abs().max())
    spreads = [states.get(f"{block}/{s}", (None, None))[1] for s in system.state_names]
    if any(s is None or not s > 0 for s in spreads) or not peak > 0:
        return None
    rate = rate if rate > 0 else 1.0 / dt
    return ([drive_name(channel, s) for s in system.state_names],
            {drive_scale_name(channel, s): float(spread) * rate / peak
             for s, spread in zip(system.state_names, spreads)})


def _knobs(edited: ModelSpec, values: Mapping[str, float],
           channels: Mapping[str, tuple[float, str]], where: str = "") -> dict[str, str]:
    """Qualified trainable parameter -> unit, over the edited model's blocks."""
    knobs = {}
    for b in edited.blocks:
        if not b.trainable:
            continue
        own = ELEMENT_PARAMETER.get(b.kind)
        if own:  # a dead time in s, a limit in its input's unit
            unit = "s" if b.kind == "delay" else channels.get(b.inputs[0], (0.0, ""))[1]
            knobs.update({f"{b.name}/{own}": unit} if own in b.trainable else {})
            continue
        try:
            specs = {s.name: s for s in b.parameter_specs({**values, **edited.parameters})}
        except ValueError as error:  # a value out of its range (an entry's expression gave a k of 0)
            raise CatalogueError(f"{where}: {error}") from None
        for t in b.trainable:
            name = f"{b.name}/{t}" if f"{b.name}/{t}" in specs else t
            knobs[name] = specs[name].unit
    return knobs


def _parameter_values(spec: ModelSpec, known: Mapping[str, float], block: str | None) -> dict[str, float]:
    """The model's parameters by name at their current values (given, else nominal), for an entry's
    expressions: the shared ones (unqualified), and the matched ``block``'s own by their local names."""
    values = {}
    for b in spec.blocks:
        if b.kind != "physics":
            continue
        for p in b.system_model().parameter_specs(known):
            local = p.name.split("/", 1)[-1]
            if (p.name == local or b.name == block) and local.isidentifier():
                values[local] = p.value
    return values


def catalogue_candidates(entries: Sequence[Entry], spec: ModelSpec, input_names: Sequence[str],
                         output_names: Sequence[str], scheduling_names: Sequence[str],
                         physical_values: Mapping[str, float], dt: float,
                         uncertain: Mapping[str, Sequence[str]] | None = None,
                         channels: Mapping[str, tuple[float, str]] | None = None,
                         states: Mapping[str, tuple[float, float]] | None = None) -> list[Candidate]:
    """Every entry expanded over the model and the data's channels, as edits of the frozen model.

    ``channels``: per measured channel, its largest |value| in the training data [SI] (``peak``
    in an entry's expressions: of the entry's input, output or scheduling channel, or of a matched
    block's first input where that is measured) and its unit (of a limit on it). An entry's expressions may also
    read the model's parameters by name (``viscous_friction``), the shared ones and the matched
    block's own (by their local names), at their values in this round: nominal, or fitted by an
    earlier round; ``dt`` and ``peak`` win over a parameter of the same name. ``states``: per
    state of a physics block (``<block>/<state>``), its operating point and spread [SI] in the
    nominal model's scaling (``level`` and ``spread`` for ``for_each: state``; without them the
    state entries are not expanded, and an entry whose expressions read a block's states is an
    error), and where given its 10th and 90th percentiles in the model's
    free runs over the training data (``low``, ``high``); a ``for_each: block`` entry reads the
    matched block's states' as ``<state>_level`` and ``<state>_spread`` (``position_spread``)."""
    channels, states = channels or {}, states or {}
    specific = specific_systems(entries)
    uncertain = {b.name: b.trainable for b in spec.blocks} if uncertain is None else uncertain
    base = frozen(spec)
    existing = {b.name for b in base.blocks}
    out = []
    known = {**physical_values, **spec.parameters}
    slowest = _slowest(base, known, dt) if any(e.scan for e in entries) else 0.0
    for entry in entries:
        if not entry.applies(known):
            continue
        for target, context in _contexts(entry, base, input_names, output_names, scheduling_names,
                                         physical_values, uncertain, specific):
            if entry.for_each == "state" and (target not in states or (
                    entry.where.get("state") == "positive" and not states[target][2:3] > (0,))):
                continue  # (where: {state: positive}: its free runs' 10th percentile is above 0)
            if entry.for_each == "auxiliary":  # the channel's weights in each state derivative, and their sizes
                drives = _drives(base, context["block"], context["channel"], known, states,
                                 channels.get(context["channel"], (0.0, ""))[0], dt)
                if drives is None:
                    continue
                context = {**context, "drives": drives[0], "drive_scales": drives[1]}
            if entry.for_each == "block_input":  # the mode's weights on the block's outputs, and their sizes
                mode = _mode_parameters(context, channels)
                if mode is None:
                    continue
                context = {**context, "mode_weights": mode[0], "mode_parameters": mode[1]}
            where = f"catalogue {entry.source}, entry {entry.id} on {target}"
            if entry.fit == AFFINE:
                out.append(Candidate(entry.id, _format(entry.offset, context), base, AFFINE,
                                     (_format(entry.offset, context),)))
                continue
            channel = (context.get("input") or context.get("output") or context.get("channel")
                       or context.get("block_input"))
            own = {} if entry.for_each != "block" else {  # the matched block's states: position_spread
                f"{key.split('/', 1)[1]}_{name}": value for key, scales in states.items()
                if key.startswith(f"{target}/") for name, value in zip(("level", "spread"), scales)}
            variables = {**own, **_parameter_values(base, known, context.get("block")), "slowest": slowest,
                         **({"peak": channels[channel][0]} if channel in channels else {}),
                         **(dict(zip(("level", "spread", "low", "high", "bottom", "top"), states[target]))
                            if entry.for_each == "state" else {})}
            if "on" in context:  # the signal a parameter varies with: its operating point and spread
                scales = _on_scales(context, states, channels)
                if scales is None:
                    continue
                variables.update(on_level=scales[0], on_spread=scales[1])
            patch = _format(dict(entry.patch), context)
            if any(name.startswith("diagnosed_") and name in existing for name in patch.get("blocks", {})):
                continue  # the model has this cause's block already: named in an earlier round
            for scanned, values in _scanned(entry, target, {**variables, "dt": dt}, where):
                out += _candidate(entry, scanned, context, apply_patch(base, patch, dt, where, values),
                                  physical_values, channels, where)
    return out


def _on_scales(context: Mapping[str, Any], states: Mapping[str, tuple[float, ...]],
               channels: Mapping[str, tuple[float, str]]) -> tuple[float, float] | None:
    """``on_level`` and ``on_spread`` of a ``for_each: parameter`` entry with ``on``: a state's
    operating point and spread in the round's model's scaling, an input's 0 and its largest |value| / 3
    (a signal's peak is about three spreads); None where they are not known."""
    if context["on_kind"] == "state":
        scales = states.get(f"{context['block']}/{context['on']}")
        return None if scales is None or not scales[1] > 0 else (float(scales[0]), float(scales[1]))
    peak = channels.get(context["on_signal"], (0.0, ""))[0]
    return (0.0, peak / 3.0) if peak > 0 else None


def _scanned(entry: Entry, target: str, variables: Mapping[str, float], where: str
             ) -> Iterator[tuple[str, dict[str, float]]]:
    """(target, variables) for each start of the entry's ``scan`` (one: none), the target then
    naming it by its name (``current, slow start``), never by its value: the value moves with
    each fold's and round's model (``slowest``), and a candidate must keep its key across them
    (the folds pool it; the final model is rebuilt from the causes' keys)."""
    if not entry.scan:
        yield target, dict(variables)
        return
    name, starts = next(iter(entry.scan.items()))
    for label, start in starts:
        yield f"{target}, {label}", {**variables, name: _number(start, variables, where)}


def _candidate(entry: Entry, target: str, context: Mapping[str, Any], edited: ModelSpec,
               physical_values: Mapping[str, float], channels: Mapping[str, tuple[float, str]], where: str
               ) -> list[Candidate]:
    """The candidate of one edit (none where a state entry finds nothing to fit)."""
    knobs = _knobs(edited, physical_values, channels, where) if entry.fit == GRADIENT else {}
    if entry.fit == GRADIENT and not knobs and entry.for_each == "state":
        return []  # nothing of this state to fit (no coupling to bend): the entry does not apply
    if entry.fit == GRADIENT and not knobs:
        raise CatalogueError(f"{where}: fit: gradient but the patch makes nothing trainable")
    state = context.get("state") if entry.for_each == "state" else None
    if state in channels:  # a state named like a measured channel: its level (a limit) in that unit
        own_level = f"{context['block']}/{state}_"
        knobs = {k: u or (channels[state][1] if k.startswith(own_level) else u) for k, u in knobs.items()}
    systems = entry.where.get("system", ()) if entry.for_each == "block" else ()
    replaces = isinstance(systems, Mapping) and any(old != new for old, new in systems.items())
    return [Candidate(entry.id, target, edited, entry.fit, tuple(knobs), knobs,
                      tuple(_format(b, context) for b in entry.learn), replaces)]
