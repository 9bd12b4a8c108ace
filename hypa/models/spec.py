"""A model as data: blocks wired by named signals (the ``model`` config group).

A composition is a list of blocks; each reads named signals and writes named signals. The
measured inputs and scheduling signals are signals from the start; the model's ``outputs``
are compared with the measured outputs. V1, V2, V3, the physical baseline and the
pure networks are YAML files in ``conf/model/``, not Python classes.

The dataclasses here are the one definition of a model's, a block's and a stage's keys: Hydra's
schema of the ``model`` node (:mod:`hypa.models.schema`) is made from their fields,
:func:`parse_model_spec` checks a plain mapping against them and :func:`spec_config` writes them.
Importing this module imports neither torch nor the physics (only checking or building a model does).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hypa.core.errors import DataError, UserError
from hypa.core.trust import check_name

if TYPE_CHECKING:
    from hypa.physics.parameters import ParameterSpec
    from hypa.physics.statespace import LTIModel

BLOCK_KINDS = ("physics", "ann", "delay", "saturation", "fmu")
FMU_INTERFACES = ("auto", "model_exchange", "co_simulation")
# elements: blocks that map each input to one output through one own parameter (not a state space)
ELEMENT_PARAMETER = {"delay": "delay_s", "saturation": "limit"}
STEADY = "steady"  # initial_state of a block that starts in equilibrium with its first input
ESTIMATE = "estimate"  # initial_state estimated by least squares from the past samples
ENCODER = "encoder"  # the least-squares estimate corrected by a network over the past samples
DIAGNOSED = "diagnosed_"  # the prefix of the blocks and signals a diagnosis adds to a model (hypa.diagnosis)


# The metadata of a field that is no key inside its node: the node's own key in its parent (a block's
# name, ``blocks: {<name>: {kind: ..., ...}}``).
NODE_KEY = "node_key"


class ModelSpecError(UserError):
    """A model configuration that cannot be built; the message lists what exists."""


def keys(schema: type) -> tuple[str, ...]:
    """The keys a config node of the dataclass ``schema`` may have, in declared order: its fields but
    the node's own key (a block's ``name``)."""
    return tuple(f.name for f in fields(schema) if not f.metadata.get(NODE_KEY))


def unknown_keys(node: Mapping[str, Any], schema: type) -> list[str]:
    """The keys of ``node`` that ``schema`` does not have, sorted."""
    return sorted(set(map(str, node)) - set(keys(schema)))


@dataclass(frozen=True)
class BlockSpec:
    """One block of a composition.

    kind: ``physics`` (an LTI system from ``hypa.physics.systems``), ``ann`` (a network of
        the ``ann`` config group), ``delay`` (a dead time, ``hypa.physics.elements.DeadTime``:
        each input delayed by the block's parameter ``delay_s``) or ``saturation`` (a limit,
        ``hypa.physics.elements.Saturation``: each input held within ±limit, nearly a clip).
    inputs / outputs: signal names read / written, in the block's own order.
    system: physics only, a built-in system (``single_track``, ``front_steering``, ...) or the import
        path of a user's ``LTIModel`` subclass (``mypackage.motors:DCMotor``).
    trainable: physics, delay and saturation, parameter names learned from data (grey-box); a block's own
        parameters by their short name (``tau_s``).
    parameters: physics, delay and saturation, values of the block's own parameters (a
        lag's ``tau_s``, a dead time's ``delay_s``, a limit's ``limit``), stored as ``<block>/<name>``:
        a number in the parameter's declared unit, or a number with a unit (``2.5 Ah``, ``{value: 2.5,
        unit: Ah}``) converted to it when the model is built (another kind of unit is refused).
    residual_of: ann only, signals the network's output is added to (a correction network);
        when the block is bypassed (first stage of a staged training) its output is exactly
        these signals.
    scale_as: signals whose scale σ the outputs share, giving a network's normalized output a
        physical meaning (a learned rear-wheel angle in units of the front angle's σ, with zero
        mean so that an output of 0 is 0 rad); physics blocks take (μ, σ).
    initial_state: physics blocks with states: the measured outputs whose value at the
        window start are the block's initial state (default: the system's state names when
        all of them are measured), ``steady``: in equilibrium with the block's first input
        (a lag's state), or ``estimate`` (the default when a state is not measured): least
        squares of the state over the window's past samples from the measured outputs the
        block's outputs observe, or ``encoder``: that estimate plus a network (of the ``ann``
        group) over the past inputs and measured outputs, which starts at zero (deepSI's
        SUBNET encoder, anchored on the physics). ann blocks: measured outputs given to the network over the
        past samples and the window start (zero afterwards; with no past, an impulse at the
        start: a pure network has no other way to know where a window starts).
    scheduling: physics only, parameters that vary per sample with a measured signal
        (``{velocity: velocity}``: parameter -> scheduling channel, SI units).
    observe: physics and FMU blocks, which measured output each block output is (``{y_physics: y}``)
        for the initial-state estimate (an FMU's: its start state and its outputs' scale); outputs
        named like a measured output observe it without this.
    table: physics scheduled by one signal only: where no gradient needs its matrices (a
        validation, an evaluation, a simulation), read them off an interpolation table over the
        signal's range, verified against the exact matrices to round-off
        (``hypa.physics.table``); otherwise they are computed at every sample.
    curved: physics only, states whose couplings bend with their deviation, state -> power (2, 3
        or root): each coupling A_rj from x_j becomes A_rj (x_j + w_r (x_j - μ_j) z^(p-1)), z = (x_j
        - μ_j) / σ_j, with the block's own parameters ``<state>_level`` μ_j, ``<state>_spread`` σ_j
        and ``curve_<state>_on_<row>`` w_r (root, an orifice's law: A_rj (x_j + w (√(μ_j x_j) -
        x_j)), one ``curve_<state>`` w for every row) (``hypa.physics.curved``; named by
        ``hypa diagnose``'s ``cubic_state``, ``square_state`` and ``root_state``).
    limited: physics only, states that cannot pass a level, state -> upper or lower: what would
        carry the state past its limit ``<state>_limit`` spills within ``<state>_limit_time``, a
        share ``spill_<state>_to_<row>`` of it into each other state (``hypa.physics.limited``;
        named by ``hypa diagnose``'s ``upper_state_limit`` and ``lower_state_limit``).
    depends: physics only, parameters that vary per sample with a direction or a state, parameter
        -> {by: a state or input of the system, kind: direction | state | cubic}: p (1 + d tanh(s / w)),
        p (1 + a z) or p (1 + a z + b z² + c z³) with z = (s - μ) / σ, with the block's own parameters
        ``<p>_direction_<s>`` d and ``<p>_direction_<s>_width`` w, or ``<p>_slope_<s>`` a,
        ``<p>_slope_<s>_level`` μ and ``<p>_slope_<s>_spread`` σ (and ``<p>_square_<s>`` b,
        ``<p>_cube_<s>`` c) (``hypa.physics.dependent``; named by ``hypa diagnose``'s
        ``direction_parameter`` and ``state_parameter``).
    modes: physics only, inputs of the system (its own names) that each drive a first-order mode
        the system lacks, added into its outputs: the block's own ``mode_<input>_tau_s``,
        ``mode_<input>_on_<output>`` and the fixed ``mode_<input>_scale_on_<output>``
        (``hypa.physics.modes``; named by ``hypa diagnose``'s ``missing_mode``).
    driven: physics only, signals read after the system's own inputs that enter every state
        derivative through the block's own weights ``drive_<signal>_on_<state>`` times the fixed
        ``drive_<signal>_scale_on_<state>`` (``hypa.physics.dependent.Driven``; named by
        ``hypa diagnose``'s ``unread_channel`` for a measured channel the model did not read).
    fmu: an FMI 2.0 FMU (a path) instead of ``system``: the user's own simulator as the physics
        (``hypa.physics.fmu_block``); ``kind: physics`` with ``fmu:`` is ``kind: fmu``. Its parameters
        are the FMU's Real parameters (``parameters:`` sets them, ``trainable:`` names them); inputs
        and outputs are FMU variables by name, or by ``rename``. A relative path is the config
        directory's (resolved when the model is built from a Hydra config), else the working
        directory's. A model read from a file runs an FMU it names only where the user trusts it.
    interface: an FMU block's ``auto`` (model exchange where it has continuous states, else
        co-simulation), ``model_exchange`` (hypa integrates it) or ``co_simulation`` (it steps itself).
    rename: an FMU block's variables -> the signals they are, where the names differ.
    """

    name: str = field(metadata={NODE_KEY: True})  # the block's key in the model's blocks
    kind: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    system: str | None = None
    trainable: tuple[str, ...] = ()
    residual_of: tuple[str, ...] = ()
    scale_as: tuple[str, ...] = ()
    initial_state: tuple[str, ...] = ()
    parameters: Mapping[str, float] = field(default_factory=dict)
    scheduling: Mapping[str, str] = field(default_factory=dict)
    observe: Mapping[str, str] = field(default_factory=dict)
    table: bool = False
    curved: Mapping[str, int | str] = field(default_factory=dict)
    limited: Mapping[str, str] = field(default_factory=dict)
    depends: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    modes: tuple[str, ...] = ()
    driven: tuple[str, ...] = ()
    fmu: str | None = None
    interface: str | None = None  # None: auto
    rename: Mapping[str, str] = field(default_factory=dict)

    def parameter_specs(self, values: Mapping[str, float]) -> list[ParameterSpec]:
        """A physics block's parameters (its system's, at ``values`` by their names), or an FMU block's Real
        parameters (at the values among ``values`` that name them, else the FMU's own)."""
        if self.kind == "fmu":
            from hypa.physics.fmu import read_fmu

            fmu = read_fmu(self.fmu or "")
            names = {p.name for p in fmu.parameters}
            return fmu.parameter_specs({k: v for k, v in values.items() if k in names})
        return self.system_model().parameter_specs(values)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """A physics block's system's parameter names, or an FMU block's Real parameters."""
        if self.kind == "fmu":
            from hypa.physics.fmu import read_fmu

            return tuple(p.name for p in read_fmu(self.fmu or "").parameters)
        return tuple(self.system_model().parameter_names)

    def system_model(self) -> LTIModel:
        """A physics block's system as built for it: ``system`` with its ``curved`` and ``limited``
        states, its ``depends`` parameters, its ``modes`` and its ``driven`` inputs."""
        from hypa.physics.systems import build_system

        return build_system(self.system or "", self.name, self.curved, self.limited, self.depends, self.driven,
                            self.modes)

    @property
    def steady(self) -> bool:
        return self.initial_state == (STEADY,)

    @property
    def estimated(self) -> bool:
        """The initial state comes from the past samples (least squares, maybe with an encoder)."""
        return self.initial_state in ((ESTIMATE,), (ENCODER,))

    @property
    def encoded(self) -> bool:
        return self.initial_state == (ENCODER,)


@dataclass(frozen=True)
class StageSpec:
    """One stage of a staged training: blocks trained, blocks bypassed."""

    name: str
    train: tuple[str, ...]
    bypass: tuple[str, ...] = ()


@dataclass(frozen=True)
class ModelSpec:
    """A composition. Besides blocks, outputs and stages, a model may fix:

    hold: the physics' hold (``zoh`` | ``foh`` | ``cubic``), overriding ``physics.hold`` of the run.
    parameters: values of shared physical parameters, overriding the ``vehicle`` config
        (e.g. a stiffness re-fitted by ``hypa diagnose``); with a unit or not, as a block's.
    sensor_offsets: constant biases [SI] of measured signals (measured - true): subtracted from
        a measured input and from a measured initial state, added to the model output.
    """

    name: str
    blocks: tuple[BlockSpec, ...]
    outputs: tuple[str, ...]
    stages: tuple[StageSpec, ...] = field(default_factory=tuple)
    hold: str | None = None
    parameters: Mapping[str, float] = field(default_factory=dict)
    sensor_offsets: Mapping[str, float] = field(default_factory=dict)

    @property
    def block_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.blocks)

    def block(self, name: str) -> BlockSpec:
        for b in self.blocks:
            if b.name == name:
                return b
        raise ModelSpecError(f"model {self.name!r} has no block {name!r}; blocks: {', '.join(self.block_names)}")


def _names(value: Any, where: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        return (value,)
    if not isinstance(value, Sequence):
        raise ModelSpecError(f"{where} must be a list of signal names, got {str(value)[:80]!r}")
    return tuple(str(v) for v in value)


def _signals(value: Any, where: str) -> tuple[str, ...]:
    """Signal names: names that become file names and module keys (:func:`hypa.core.trust.check_name`)."""
    names = _names(value, where)
    try:
        return tuple(check_name(n, where) for n in names)
    except UserError as error:
        raise ModelSpecError(str(error)) from None


def _values(value: Any, where: str, units: bool = False) -> dict[str, float]:
    """A mapping name -> finite number (SI); with ``units`` also a number with a unit (``2.5 Ah``,
    ``{value: 2.5, unit: Ah}``): a :class:`~hypa.core.units.GivenQuantity`, converted to the unit its
    parameter declares when the model is built."""
    from hypa.core.units import given_value

    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ModelSpecError(f"{where} must map names to numbers, got {value!r}")
    out = {}
    for key, v in value.items():
        if units and not isinstance(v, int | float):
            try:
                out[str(key)] = given_value(v, f"{where}.{key}")
            except DataError as error:
                raise ModelSpecError(str(error)) from None
        else:
            try:
                out[str(key)] = float(v)
            except (TypeError, ValueError):
                raise ModelSpecError(f"{where}.{key} must be a number, got {v!r}") from None
        if not math.isfinite(out[str(key)]):
            raise ModelSpecError(f"{where}.{key} must be finite, got {v!r}")
    return out


def _written(value: Any) -> Any:
    """A spec's value as a model YAML holds it: a spec its node, a mapping a dict, a tuple a list, a
    number given with its unit as given (``2.5 Ah``), another real number a float (a numpy one too)."""
    from hypa.core.units import GivenQuantity

    if is_dataclass(value):
        return _node(value)
    if isinstance(value, Mapping):
        return {str(k): _written(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_written(v) for v in value]
    if isinstance(value, GivenQuantity):
        return str(value)
    return float(value) if isinstance(value, numbers.Real) and not isinstance(value, numbers.Integral) else value


def _signal_map(value: Any, where: str) -> dict[str, str]:
    """A mapping name -> signal name; a list means each name maps to itself."""
    if value is None:
        return {}
    if isinstance(value, str) or (isinstance(value, Sequence) and not isinstance(value, Mapping)):
        return {n: n for n in _signals(value, where)}
    if not isinstance(value, Mapping):
        raise ModelSpecError(f"{where} must map names to signal names, got {str(value)[:80]!r}")
    return {str(k): _signals(str(v), where)[0] for k, v in value.items()}


def _flag(value: Any, where: str) -> bool:
    """true / false (None: false)."""
    if value is None:
        return False
    if not isinstance(value, bool):
        raise ModelSpecError(f"{where} must be true or false, got {value!r}")
    return value


def _powers(value: Any, where: str) -> dict[str, int | str]:
    """A mapping state -> power, 2, 3 or root (None: empty)."""
    if value is None:
        return {}
    if not isinstance(value, Mapping) or any(isinstance(v, bool) or v not in (2, 3, "root") for v in value.values()):
        raise ModelSpecError(f"{where} must map state names to a power, 2, 3 or root (e.g. {{position: 3}}), "
                             f"got {value!r}")
    return {str(k): v if v == "root" else int(v) for k, v in value.items()}


def _sides(value: Any, where: str) -> dict[str, str]:
    """A mapping state -> upper | lower (None: empty)."""
    if value is None:
        return {}
    if not isinstance(value, Mapping) or any(v not in ("upper", "lower") for v in value.values()):
        raise ModelSpecError(f"{where} must map state names to upper or lower (e.g. {{level: upper}}), got {value!r}")
    return {str(k): str(v) for k, v in value.items()}


def _dependences(value: Any, where: str) -> dict[str, dict[str, str]]:
    """A mapping parameter -> {by: signal, kind: direction | state | cubic} (None: empty)."""
    if value is None:
        return {}
    if not isinstance(value, Mapping) or not all(
            isinstance(v, Mapping) and set(v) == {"by", "kind"} and v["kind"] in ("direction", "state", "cubic")
            for v in value.values()):
        raise ModelSpecError(f"{where} must map parameters to {{by: <state or input>, kind: direction | state | "
                             f"cubic}} (e.g. {{R0: {{by: current, kind: direction}}}}), got {value!r}")
    return {str(k): {"by": str(v["by"]), "kind": str(v["kind"])} for k, v in value.items()}


def parse_model_spec(config: Mapping[str, Any]) -> ModelSpec:
    """Parse and check the ``model`` config (a plain mapping) into a :class:`ModelSpec`."""
    from hypa.physics.discretization import HOLDS
    from hypa.physics.systems import PHYSICS_SYSTEMS, is_import_path

    name = _signals(str(config.get("name", "model")), "the model's name")[0]
    unknown = unknown_keys(config, ModelSpec)  # the keys Hydra's schema of `model` has too (hypa.models.schema)
    if unknown:
        raise ModelSpecError(f"model {name!r}: unknown keys {unknown}; known: {', '.join(keys(ModelSpec))}")
    hold = config.get("hold")
    if hold is not None and hold not in HOLDS:
        raise ModelSpecError(f"model {name!r}: hold must be one of {HOLDS} or null, got {hold!r}")
    blocks_cfg = config.get("blocks") or {}
    if not blocks_cfg:
        raise ModelSpecError(f"model {name!r} has no blocks")
    blocks = []
    for block_name, b in blocks_cfg.items():
        _signals(str(block_name), "a block's name")
        if not isinstance(b, Mapping):
            raise ModelSpecError(f"block {block_name!r} must map keys ({', '.join(keys(BlockSpec))}) to values, "
                                 f"got {b!r}")
        unknown = unknown_keys(b, BlockSpec)
        if unknown:
            raise ModelSpecError(f"block {block_name!r}: unknown keys {unknown}; known: {', '.join(keys(BlockSpec))}")
        kind = "fmu" if b.get("kind") == "physics" and b.get("fmu") is not None else b.get("kind")
        if kind not in BLOCK_KINDS:
            raise ModelSpecError(f"block {block_name!r}: kind must be one of {BLOCK_KINDS}, got {kind!r}")
        system = b.get("system")
        # an import path (package.module:Class) is resolved and checked when the model is built
        known = isinstance(system, str) and (system in PHYSICS_SYSTEMS or is_import_path(system))
        _check_fmu(str(block_name), kind, b)
        if kind == "physics" and not known:
            raise ModelSpecError(
                f"block {block_name!r}: unknown physics system {system!r}; known: {', '.join(PHYSICS_SYSTEMS)}, "
                "or an import path package.module:Class"
            )
        blocks.append(BlockSpec(
            name=str(block_name), kind=kind, inputs=_signals(b.get("inputs"), f"{block_name}.inputs"),
            outputs=_signals(b.get("outputs"), f"{block_name}.outputs"), system=system,
            trainable=_names(b.get("trainable"), f"{block_name}.trainable"),
            residual_of=_signals(b.get("residual_of"), f"{block_name}.residual_of"),
            scale_as=_signals(b.get("scale_as"), f"{block_name}.scale_as"),
            initial_state=_signals(b.get("initial_state"), f"{block_name}.initial_state"),
            parameters=_values(b.get("parameters"), f"{block_name}.parameters", units=True),
            scheduling=_signal_map(b.get("scheduling"), f"{block_name}.scheduling"),
            observe=_signal_map(b.get("observe"), f"{block_name}.observe"),
            table=_flag(b.get("table"), f"{block_name}.table"),
            curved=_powers(b.get("curved"), f"{block_name}.curved"),
            limited=_sides(b.get("limited"), f"{block_name}.limited"),
            depends=_dependences(b.get("depends"), f"{block_name}.depends"),
            driven=_signals(b.get("driven"), f"{block_name}.driven"),
            modes=_names(b.get("modes"), f"{block_name}.modes"),
            fmu=None if b.get("fmu") is None else str(b["fmu"]),
            interface=None if b.get("interface") is None else str(b["interface"]),
            rename=_signal_map(b.get("rename"), f"{block_name}.rename"),
        ))
        if kind != "physics" and (blocks[-1].scheduling or blocks[-1].curved or blocks[-1].limited
                                  or blocks[-1].depends or blocks[-1].driven or blocks[-1].modes):
            raise ModelSpecError(f"block {block_name!r}: only physics blocks take scheduling, curved, limited, "
                                 "depends, modes or driven")
        if kind not in ("physics", "fmu") and blocks[-1].observe:
            raise ModelSpecError(f"block {block_name!r}: only physics and FMU blocks take observe")
        if blocks[-1].table and len(blocks[-1].scheduling) != 1:
            raise ModelSpecError(f"block {block_name!r}: table: true needs a physics block scheduled by one signal, "
                                 f"got scheduling {dict(blocks[-1].scheduling) or 'none'}")
        if kind != "fmu" and (blocks[-1].rename or blocks[-1].interface is not None):
            raise ModelSpecError(f"block {block_name!r}: only FMU blocks take rename or interface")
        if kind == "ann" and (blocks[-1].parameters or blocks[-1].trainable):
            raise ModelSpecError(f"block {block_name!r}: an ann block has no physical parameters or trainable")
        own = ELEMENT_PARAMETER.get(kind)
        if own and own not in blocks[-1].parameters:
            raise ModelSpecError(f"block {block_name!r}: a {kind} block needs parameters: {{{own}: <value>}}")
        if own and len(blocks[-1].inputs) != len(blocks[-1].outputs):
            raise ModelSpecError(f"block {block_name!r}: a {kind} block writes one output per input")
    stages = []
    for s in config.get("stages") or []:
        if not isinstance(s, Mapping) or unknown_keys(s, StageSpec) or "name" not in s:
            raise ModelSpecError(f"model {name!r}: a stage has the keys {', '.join(keys(StageSpec))} (name "
                                 f"required), got {s!r}")
        stages.append(StageSpec(name=str(s["name"]), train=_names(s.get("train"), "stage.train"),
                                bypass=_names(s.get("bypass"), "stage.bypass")))
    spec = ModelSpec(name=name, blocks=tuple(blocks), outputs=_signals(config.get("outputs"), "outputs"),
                     stages=tuple(stages), hold=hold,
                     parameters=_values(config.get("parameters"), "parameters", units=True),
                     sensor_offsets=_values(config.get("sensor_offsets"), "sensor_offsets"))
    for stage in spec.stages:
        for block_name in (*stage.train, *stage.bypass):
            spec.block(block_name)  # raises with the list of blocks
        for block_name in stage.bypass:
            if not spec.block(block_name).residual_of:
                raise ModelSpecError(f"stage {stage.name!r} bypasses {block_name!r}, which has no residual_of")
    return spec


def model_imports(config: Mapping[str, Any], ann_name: str | None = None) -> dict[str, str]:
    """The import paths a model config names that are not built into hypa (its blocks' user systems,
    and ``ann_name`` where a block is or starts from a network and ``ann_name`` is not a built-in
    network): what -> import path. They are code: a model read from a file (a checkpoint's, a
    written ``diagnosed.yaml``) imports them only when the user trusts them (:mod:`hypa.core.trust`)."""
    from hypa.ann import ANN_BLOCKS
    from hypa.physics.systems import is_import_path

    found = {}
    for name, block in (config.get("blocks") or {}).items():
        system = block.get("system") if isinstance(block, Mapping) else None
        if isinstance(system, str) and is_import_path(system):
            found[f"block {name!r} system"] = system
        fmu = block.get("fmu") if isinstance(block, Mapping) else None
        if isinstance(fmu, str):  # a simulator's binary: code, as a system's import path
            found[f"block {name!r} FMU"] = fmu
    if ann_name is not None and ann_name not in ANN_BLOCKS and builds_networks(config):
        found["network"] = ann_name
    return found


def _check_fmu(name: str, kind: str, block: Mapping[str, Any]) -> None:
    """An FMU block names its FMU and no system; another names no FMU."""
    fmu = block.get("fmu")
    if kind != "fmu":
        if fmu is not None:
            raise ModelSpecError(f"block {name!r}: fmu: is for physics blocks (kind: physics or fmu), not {kind}")
        return
    if not isinstance(fmu, str) or not fmu.strip():
        raise ModelSpecError(f"block {name!r}: an FMU block needs fmu: <path to an .fmu file>, got {fmu!r}")
    if block.get("system") is not None:
        raise ModelSpecError(f"block {name!r}: give fmu: or system:, not both")
    if (block.get("interface") or "auto") not in FMU_INTERFACES:
        raise ModelSpecError(f"block {name!r}: interface must be one of {', '.join(FMU_INTERFACES)}, "
                             f"got {block.get('interface')!r}")


def builds_networks(config: Mapping[str, Any]) -> bool:
    """Whether a model config builds a network: an ``ann`` block, or a start estimated by an encoder."""
    return any(isinstance(b, Mapping) and (b.get("kind") == "ann" or b.get("initial_state") in (ENCODER, [ENCODER]))
               for b in (config.get("blocks") or {}).values())


def read_model_file(path: Path, trust: Collection[str] = ()) -> dict[str, Any]:
    """A model YAML read as data (``hypa train model_file=...``, e.g. a diagnosis's
    ``conf/model/diagnosed.yaml``): bounded plain YAML (:func:`hypa.core.trust.read_yaml`), the model
    schema's keys only (no ``_target_``, no ``# @package`` that reaches other settings), no
    interpolation, and no import path that ``trust`` does not name. Returns the checked mapping."""
    from hypa.core.trust import check_imports, has_interpolation, read_yaml

    config = read_yaml(path, "model file")
    if not isinstance(config, Mapping):
        raise ModelSpecError(f"{path}: a model file maps model keys ({', '.join(keys(ModelSpec))}) to values")
    if has_interpolation(config):
        raise ModelSpecError(f"{path}: holds an interpolation (${{...}}); a model file is read as data, with "
                             "values only")
    try:
        parse_model_spec(config)
    except ModelSpecError as error:
        raise ModelSpecError(f"{path}: {error}") from None
    config = dict(config)
    blocks = {name: dict(b) if isinstance(b, Mapping) else b for name, b in (config.get("blocks") or {}).items()}
    for block in blocks.values():  # an FMU named relative to the file: its folder's
        if isinstance(block, dict) and isinstance(block.get("fmu"), str) and not Path(block["fmu"]).is_absolute():
            block["fmu"] = str((Path(path).parent / block["fmu"]).resolve())
    config["blocks"] = blocks
    check_imports(model_imports(config), trust, path)
    return config


def spec_config(spec: ModelSpec, name: str | None = None) -> dict[str, Any]:
    """A :class:`ModelSpec` as the mapping of a ``conf/model/*.yaml`` file: the keys that are set (and
    always a model's name, blocks, outputs and stages, a block's kind, inputs and outputs, a stage's
    keys), a parameter given with its unit as given (``2.5 Ah``)."""
    return {**_node(spec), "name": name or spec.name, "blocks": {b.name: _node(b) for b in spec.blocks}}


# The keys of a node written even where empty.
_ALWAYS: dict[type, tuple[str, ...]] = {
    ModelSpec: ("name", "blocks", "outputs", "stages"),
    BlockSpec: ("kind", "inputs", "outputs"),
    StageSpec: ("name", "train", "bypass"),
}


def _node(spec: Any) -> dict[str, Any]:
    """A spec as its config node: the keys that are set, and those always written."""
    return {key: _written(getattr(spec, key)) for key in keys(type(spec))
            if key in _ALWAYS[type(spec)] or getattr(spec, key)}
