"""Building a composition's blocks: their physical parameters, scaling and initial-state mode.

Every signal of a composition has a physical scale (μ, σ) so that blocks can exchange it in
the normalized scale of the paper (eq. 2): measured inputs, outputs and scheduling signals take
the training set's statistics; a block's outputs take the scale of the measured output they
observe, of the signals named in ``scale_as``, or (a static gain) the image of its inputs' (a
static block's measured output keeps the data's scale: the model's outputs are compared in it).
States nobody measures get a data-free scale from the nominal physics
(``hypa.physics.default_state_std``), except a state that an observed output reads alone: it takes
that output's scale in the data (its operating point and spread).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch
from torch import nn

from hypa.ann import build_ann
from hypa.models.spec import ELEMENT_PARAMETER, BlockSpec, ModelSpec, ModelSpecError
from hypa.physics import HOLDS, LTIBlock, LTIModel, ParameterSpec, PhysicalParameters, Scaling, default_state_std
from hypa.physics.elements import DeadTime, Saturation, local_name
from hypa.physics.fmu import FMUDescription, read_fmu
from hypa.physics.fmu_block import FMUBlock, fmu_signals
from hypa.physics.operating_point import Scale, output_level_state_scales, settled_state_scales

MEASURED, STEADY, ESTIMATE = "measured", "steady", "estimate"


@dataclass(frozen=True)
class PhysicsStart:
    """How a physics block with states starts a window.

    mode: ``measured`` (the measured outputs ``measured`` at the window start are its state),
        ``steady`` (equilibrium with its first input) or ``estimate`` (least squares over the
        past samples of the measured outputs ``observed``, one per block output, None where
        an output is not measured).
    """

    mode: str
    measured: tuple[str, ...] = ()
    observed: tuple[str | None, ...] = ()
    index: tuple[int, ...] = ()  # measured: the outputs' columns; estimate: one per block output (0 if unobserved)
    encoder: bool = False  # estimate: a network over the past corrects the least-squares state


def model_hold(spec: ModelSpec, hold: str | None = None, setting: str = "hold") -> str:
    """The hold of ``spec``'s physics (``zoh`` | ``foh``): the model's own ``hold:``, else ``hold``,
    else ``zoh``. The hold belongs to the model (its fitted values belong to it), so ``hold`` only
    fills in for a model that fixes none; both given and different is the user's error, named as
    ``setting`` (``physics.hold`` on a command line)."""
    if hold is not None and hold not in HOLDS:
        raise ModelSpecError(f"{setting} must be one of {', '.join(HOLDS)}, got {hold!r}")
    if hold is not None and spec.hold is not None and hold != spec.hold:
        raise ModelSpecError(f"model {spec.name!r} fixes hold: {spec.hold}, but {setting}={hold} was given: "
                             f"drop one of them (the hold is the model's)")
    return spec.hold or hold or "zoh"


def collect_parameters(spec: ModelSpec, values: Mapping[str, float]
                       ) -> tuple[PhysicalParameters, dict[str, tuple[str, ...]], dict[str, LTIModel], frozenset[str]]:
    """One set of named parameters for all blocks, the trainable ones of each block, each physics
    block's system (built once here, for the builder too), and the parameters the data's scale of a
    signal sets (a wrapper's level, spread or width, :class:`~hypa.physics.statespace.SignalScaled`,
    that neither ``values`` nor the spec gives).

    Shared parameters (the ``vehicle`` group, overridden by the spec's ``parameters``, else the
    system's nominal values) keep their names; each block's own are ``<block>/<name>``.
    """
    values = {**values, **spec.parameters}
    specs: dict[str, ParameterSpec] = {}
    trainable_of: dict[str, tuple[str, ...]] = {}
    systems: dict[str, LTIModel] = {}
    from_data: set[str] = set()
    for b in spec.blocks:
        if b.kind == "ann":
            continue
        local = {local_name(b.name, k): v for k, v in b.parameters.items()}
        own = ELEMENT_PARAMETER.get(b.kind)  # an element's one parameter, else a system's
        if b.kind == "fmu":  # the FMU's Real parameters, named as a system's; its own values unless the model's
            fmu = read_fmu(b.fmu or "")  # parameters or the block's set them (never the vehicle group's)
            systems[b.name] = fmu
            given = {**{p.name: spec.parameters[p.name] for p in fmu.parameters if p.name in spec.parameters},
                     **{k.split("/", 1)[-1]: v for k, v in local.items()}}
            for s in fmu.parameter_specs(given):
                if s.name in specs and specs[s.name].value != s.value:  # one model holds one value per name
                    raise ModelSpecError(f"block {b.name!r}: the FMU parameter {s.name!r} is {s.value:g} here but "
                                         f"{specs[s.name].value:g} in another block; a model holds one value per "
                                         "name: give it once, in the model's parameters")
                specs[s.name] = s
            trainable_of[b.name] = _fmu_trainable(b, fmu)
            continue
        system = None if own else b.system_model()
        if system is not None:
            systems[b.name] = system
        names = (local_name(b.name, own),) if system is None else tuple(system.parameter_names)
        unknown_local = set(local) - set(names)
        if unknown_local:
            raise ModelSpecError(f"block {b.name!r}: parameters {sorted(unknown_local)} are not its own; "
                                 f"it has {', '.join(names)}")
        if system is None:  # a dead time [s], a limit [the signal's unit]: both positive
            block_specs = [ParameterSpec(names[0], local[names[0]], "s" if b.kind == "delay" else "")]
        else:
            given = {**system.nominal_values(), **values, **local}
            missing = [p for p in names if p not in given]
            if missing:
                raise ModelSpecError(f"block {b.name!r} ({b.system}) needs parameters {missing}; give them in "
                                     "the model's or the block's parameters")
            try:  # a value given with a unit is converted to the unit the system declares
                block_specs = system.parameter_specs(given)
            except ValueError as error:
                raise ModelSpecError(f"block {b.name!r} ({b.system}): {error}") from None
            from_data |= {n for scaled in system.signal_scaled() for n in (scaled.level, scaled.spread, scaled.width)
                          if n is not None and n not in values and n not in local}
        resolved = {t: local_name(b.name, t) if local_name(b.name, t) in names else t for t in b.trainable}
        unknown = [t for t, full in resolved.items() if full not in names]
        if unknown:
            raise ModelSpecError(f"block {b.name!r}: {sorted(unknown)} are not parameters of "
                                 f"{b.system or b.kind}; it has {', '.join(names)}")
        unscheduled = [p for p in b.scheduling if p not in names]
        if unscheduled:
            raise ModelSpecError(f"block {b.name!r}: scheduling {unscheduled} are not parameters of {b.system}; "
                                 f"it has {', '.join(names)}")
        for s in block_specs:
            specs[s.name] = s
        trainable_of[b.name] = tuple(resolved.values())
    unread = set(spec.parameters) - set(specs)
    if unread:
        raise ModelSpecError(f"model {spec.name!r}: parameters {sorted(unread)} are read by no block; "
                             f"read: {', '.join(specs)}")
    params = PhysicalParameters(specs.values())
    params.set_trainable({t for ts in trainable_of.values() for t in ts}, True)
    return params, trainable_of, systems, frozenset(from_data)


def _fmu_trainable(b: BlockSpec, fmu: FMUDescription) -> tuple[str, ...]:
    names = {p.name for p in fmu.parameters}
    unknown = [t.split("/", 1)[-1] for t in b.trainable if t.split("/", 1)[-1] not in names]
    if unknown:
        raise ModelSpecError(f"block {b.name!r}: {sorted(unknown)} are not parameters of its FMU; it has "
                             f"{', '.join(sorted(names))}")
    return tuple(t.split("/", 1)[-1] for t in b.trainable)


def _rows_read_nonlinearly(system: LTIModel, nominal: Mapping[str, torch.Tensor]) -> frozenset[int]:
    """The outputs whose nonlinear part h (``output_nonlinearity``) is not zero: at the nominal values
    and at two points of states and inputs (0.5 and 0.25: a state of charge's range); none for a
    linear output."""
    if not system.has_nonlinear_output:
        return frozenset()
    n, m = system.n_states, len(system.input_names)
    with torch.no_grad():
        values = [system.output_nonlinearity(torch.full((n,), v, dtype=torch.float64),
                                             torch.full((m,), v, dtype=torch.float64), nominal)
                  for v in (0.5, 0.25)]
    return frozenset(torch.nonzero((values[0] != 0) | (values[1] != 0)).flatten().tolist())


class BlockBuilder:
    """Builds blocks in dependency order, keeping the scale of every signal written so far.

    Args:
        scales: (μ, σ) of the signals available so far (measured inputs and scheduling
            signals); block outputs are added as blocks are built.
        measured: (μ, σ) of the measured outputs (targets; usable as initial states).
        scheduling: names of the measured scheduling signals.
    """

    def __init__(self, params: PhysicalParameters, systems: Mapping[str, LTIModel], scales: Mapping[str, Scale],
                 measured: Mapping[str, Scale], scheduling: Sequence[str], dt: float, horizon: int, hold: str,
                 ann: str, ann_hparams: Mapping, from_data: frozenset[str] = frozenset()) -> None:
        self.params, self.systems, self.scales, self.measured = params, systems, dict(scales), dict(measured)
        self.from_data = from_data  # parameters a signal's scale sets (collect_parameters)
        self.scheduling = tuple(scheduling)
        self.dt, self.horizon, self.hold, self.ann, self.ann_hparams = dt, horizon, hold, ann, dict(ann_hparams)
        self.starts: dict[str, PhysicsStart] = {}
        self.encoders = nn.ModuleDict()  # block name -> initial-state encoder network

    def scale_of(self, names: Sequence[str], where: str) -> list[Scale]:
        missing = [n for n in names if n not in self.scales and n not in self.measured]
        if missing:
            raise ModelSpecError(f"{where}: no scaling for {missing}")
        return [self.scales.get(n) or self.measured[n] for n in names]

    def build(self, b: BlockSpec) -> nn.Module:
        if b.kind == "ann":
            return self._ann(b)
        if b.kind == "fmu":
            return self._fmu(b)
        if b.kind in ELEMENT_PARAMETER:  # a shift or a limit: outputs keep their inputs' scale
            scales = self.scale_of(b.inputs, f"block {b.name!r} inputs")
            self.scales.update(zip(b.outputs, scales))
            name = local_name(b.name, ELEMENT_PARAMETER[b.kind])
            return DeadTime(self.params, name, self.dt) if b.kind == "delay" else Saturation(self.params, name, scales)
        return self._physics(b)

    def _ann(self, b: BlockSpec) -> nn.Module:
        if b.residual_of:
            outputs = self.scale_of(b.residual_of, f"block {b.name!r} residual_of")
        elif b.scale_as:  # zero mean: a network output of 0 is 0 in SI units (e.g. no rear steering)
            outputs = [(0.0, std) for _, std in self.scale_of(b.scale_as, f"block {b.name!r} scale_as")]
        elif all(o in self.measured for o in b.outputs):
            outputs = [self.measured[o] for o in b.outputs]
        else:
            raise ModelSpecError(f"ann block {b.name!r}: give scale_as or residual_of so its outputs "
                                 f"{list(b.outputs)} have a physical scale")
        if len(outputs) != len(b.outputs):
            raise ModelSpecError(f"block {b.name!r}: {len(b.outputs)} outputs but {len(outputs)} scales")
        self.scale_of(b.inputs, f"block {b.name!r} inputs")
        self.scales.update(zip(b.outputs, outputs))
        missing = [s for s in b.initial_state if s not in self.measured]
        if missing:
            raise ModelSpecError(f"block {b.name!r}: initial state {missing} is not a measured output; "
                                 f"measured: {list(self.measured)}")
        zero_init = bool(b.residual_of or b.scale_as)  # start as pure physics / no rear steering
        return build_ann(self.ann, len(b.inputs) + len(b.initial_state), len(b.outputs), zero_init=zero_init,
                         **self.ann_hparams)

    def _fmu(self, b: BlockSpec) -> FMUBlock:
        """An FMU block: its outputs scaled as the measured outputs they are (else (0, 1): SI), started from
        the data where its states are measured outputs."""
        fmu = self.systems[b.name]
        where = f"block {b.name!r} ({fmu.path.name})"
        if self.hold not in ("zoh", "foh"):
            raise ModelSpecError(f"{where}: an FMU's inputs are held by a zero- or first-order hold, not "
                                 f"{self.hold} (physics.hold=zoh or foh)")
        fmu_in, fmu_out = fmu_signals(fmu, b.rename, b.inputs, b.outputs, where)
        def measured_as(variable: str) -> str | None:  # its signal, the measured one that observes, its own name
            signal = b.rename.get(variable, variable)
            return next((n for n in (signal, b.observe.get(signal), variable) if n and n in self.measured), None)

        measured = tuple(measured_as(s) for s in fmu.state_names)
        measured = measured if measured and None not in measured else ()
        # an output scaled as the measured output it is (by its signal's name or its FMU variable's), else SI
        outputs = [self.measured.get(measured_as(v) or "", (0.0, 1.0)) for v in fmu_out]
        self.scales.update(zip(b.outputs, outputs))
        block = FMUBlock(b.name, fmu, self.params, [p.name for p in fmu.parameters], fmu_in, fmu_out,
                         self.scale_of(b.inputs, f"{where} inputs"), outputs, self.dt, self.hold,
                         b.interface or "auto", measured)
        block.measured_columns = self._columns(measured) if measured else ()
        return block

    def _physics(self, b: BlockSpec) -> LTIBlock:
        system = self.systems[b.name]
        if len(b.inputs) != len(system.input_names) or len(b.outputs) != len(system.output_names):
            raise ModelSpecError(f"block {b.name!r}: {b.system} maps {list(system.input_names)} -> "
                                 f"{list(system.output_names)}; got {list(b.inputs)} -> {list(b.outputs)}")
        unknown = [s for s in b.scheduling.values() if s not in self.scheduling]
        if unknown:
            raise ModelSpecError(f"block {b.name!r}: scheduling signals {unknown} are not measured scheduling "
                                 f"channels; the data declare: {list(self.scheduling) or 'none'}")
        inputs = self.scale_of(b.inputs, f"block {b.name!r} inputs")
        nominal = {k: torch.tensor(v, dtype=torch.float64) for k, v in self.params.as_floats().items()}
        ss = system.matrices(nominal)
        n = system.n_states
        observed: set[int] = set()  # the states the data scale
        if n == 0:
            states, outputs = [], self._gain_scale(b, inputs, ss.d)
        else:
            start = self._start(b, system)
            self.starts[b.name] = start
            if start.encoder:  # (inputs, observed outputs, mask) over the past -> state correction
                self.encoders[b.name] = build_ann(self.ann, len(b.inputs) + len(b.outputs), n, zero_init=True,
                                                  **self.ann_hparams)
            outputs = self._output_scale(b, system, start, inputs)
            if start.mode == MEASURED:
                states, observed = [self.measured[s] for s in start.measured], set(range(n))
            elif system.outputs_are_states:
                states, observed = outputs, {j for j, o in enumerate(b.outputs) if o in self.measured}
            else:
                std = default_state_std(ss, self.dt, torch.tensor([s for _, s in inputs], dtype=torch.float64),
                                        self.horizon)
                states, read = self._observed_state_scales(ss, start, inputs, [(0.0, float(s)) for s in std],
                                                           _rows_read_nonlinearly(system, nominal))
                unread, observed = [j for j in range(n) if j not in read], set(read)
                if system.is_nonlinear:  # the operating point of a state no output reads alone: where it settles
                    settled = settled_state_scales(system, self.params, self.dt, inputs, states, unread)
                    states, unread = (states, unread) if settled is states else (settled, [])
                if system.has_nonlinear_output and unread:  # ... else where the outputs are the data's means
                    measured = [self.measured[m] if m is not None else None for m in start.observed or ()]
                    states = output_level_state_scales(system, self.params, inputs, measured, states, unread)
        self.scales.update(zip(b.outputs, outputs))
        self._signal_scaled(system, states, inputs)
        t = lambda pairs, i: torch.tensor([p[i] for p in pairs], dtype=torch.float64)  # noqa: E731
        scaling = Scaling(t(states, 0), t(states, 1), t(inputs, 0), t(inputs, 1), t(outputs, 0), t(outputs, 1))
        block = LTIBlock(system, self.params, self.dt, self.horizon, hold=self.hold if n else "zoh",
                         scaling=scaling, scheduled=tuple(b.scheduling), table=b.table)
        block.observed_states = frozenset(observed)
        if not b.scheduling:  # a scheduled block's stability depends on the signal
            block.check_stable()
        return block

    def _signal_scaled(self, system: LTIModel, states: Sequence[Scale], inputs: Sequence[Scale]) -> None:
        """A wrapper's level, spread and width that the model leaves to the data (``from_data``): the
        block's scaling of the state or input they scale, its operating point, spread and a tenth of
        it (a state's weight is then per spread of what the data show: a cubic over a stroke of
        0.25 m needs no weights of 10³). The weights are 0 at the start, so the scaling the block
        gets from its nominal physics does not depend on them."""
        values = {}
        for scaled in system.signal_scaled():
            where, j = scaled.source
            mean, std = (states if where == "x" else inputs)[j]
            if not (std > 0 and math.isfinite(mean) and math.isfinite(std)):
                continue  # no scale to take: the defaults (0 and 1 in the signal's unit) stay
            for name, value in ((scaled.level, mean), (scaled.spread, std), (scaled.width, std / 10)):
                if name in self.from_data:
                    values[name] = float(value)
        self.params.set_values(values)

    def _start(self, b: BlockSpec, system) -> PhysicsStart:
        if b.steady:
            if b.scheduling:
                raise ModelSpecError(f"block {b.name!r}: a steady start needs constant matrices; use "
                                     "initial_state: estimate for a scheduled block")
            return PhysicsStart(STEADY)
        if b.initial_state and not b.estimated:
            missing = [s for s in b.initial_state if s not in self.measured]
            if missing or len(b.initial_state) != system.n_states:
                raise ModelSpecError(f"block {b.name!r}: initial state {list(b.initial_state)} must be steady, "
                                     f"estimate, encoder, or name its {system.n_states} states among the measured "
                                     f"outputs {list(self.measured)}")
            return PhysicsStart(MEASURED, measured=tuple(b.initial_state), index=self._columns(b.initial_state))
        if not b.estimated and all(s in self.measured for s in system.state_names):
            return PhysicsStart(MEASURED, measured=tuple(system.state_names), index=self._columns(system.state_names))
        observed = tuple(b.observe.get(o, o if o in self.measured else None) for o in b.outputs)
        unknown = [o for o in observed if o is not None and o not in self.measured]
        if unknown:
            raise ModelSpecError(f"block {b.name!r}: observe {unknown} are not measured outputs; "
                                 f"measured: {list(self.measured)}")
        if not any(observed):
            raise ModelSpecError(
                f"block {b.name!r}: its states {list(system.state_names)} are not measured and none of its "
                f"outputs {list(b.outputs)} is a measured output, so its initial state cannot be estimated; "
                "give observe: {output: measured output} or initial_state: steady")
        return PhysicsStart(ESTIMATE, observed=observed, encoder=b.encoded,
                            index=tuple(self._columns([m])[0] if m else 0 for m in observed))

    def _columns(self, names: Sequence[str]) -> tuple[int, ...]:
        """Columns of measured outputs in the data's order (that of ``measured``)."""
        order = list(self.measured)
        return tuple(order.index(n) for n in names)

    def _output_scale(self, b: BlockSpec, system, start: PhysicsStart, inputs: list[Scale]) -> list[Scale]:
        if b.scale_as:
            scales = self.scale_of(b.scale_as, f"block {b.name!r} scale_as")
        elif start.mode == MEASURED and system.outputs_are_states:
            scales = [self.measured[s] for s in start.measured]
        elif start.mode == STEADY:
            if not system.outputs_are_states:
                raise ModelSpecError(f"block {b.name!r}: its outputs are not its {system.n_states} states; give "
                                     "scale_as so they have a physical scale")
            scales = inputs  # its outputs are its states: scaled like its inputs
        else:
            observed = start.observed or (None,) * len(b.outputs)
            sources = [o if o in self.measured else m for o, m in zip(b.outputs, observed)]
            if None in sources:
                unmeasured = [o for o, m in zip(b.outputs, sources) if m is None]
                raise ModelSpecError(f"block {b.name!r}: outputs {unmeasured} are not measured; give scale_as "
                                     "so they have a physical scale")
            scales = [self.measured[m] for m in sources]
        if len(scales) != len(b.outputs):
            raise ModelSpecError(f"block {b.name!r}: {len(b.outputs)} outputs but {len(scales)} scales "
                                 "(scale_as, or its inputs for a steady start)")
        return scales

    def _observed_state_scales(self, ss, start: PhysicsStart, inputs: list[Scale], states: list[Scale],
                               curved: frozenset[int] = frozenset()) -> tuple[list[Scale], set[int]]:
        """``states`` with the data's scale for each state that an observed output reads alone, and
        the indices of those states.

        Where row i of C (at the nominal parameters) has a single nonzero entry c_j, the
        measured output y_i = c_j x_j + (D u)_i tells state j's operating point and spread:
        μ_j = (μ_yi - (D μu)_i) / c_j, σ_j = σ_yi / |c_j|. The data-free scale of the nominal
        physics (``default_state_std``, around 0) knows neither: a level of 5.6 V measured with a
        spread of 0.67 V would be scaled by the spread the inputs give it in the linear part
        alone (1e-3 of another state's where the coupling is nonlinear), and the estimate's
        ridge would pull it toward 0 V. A row that a nonlinear output also reads (``curved``: a
        cell's OCV(SOC) − v₁) reads no state alone.
        """
        if start.mode != ESTIMATE or not start.observed:
            return states, set()
        states, read = list(states), set()
        mean_in = torch.tensor([m for m, _ in inputs], dtype=torch.float64)
        for row, measured in enumerate(start.observed):
            if measured is None or row in curved:
                continue
            entries = torch.nonzero(ss.c[row]).flatten().tolist()
            if len(entries) != 1:
                continue
            j, gain = entries[0], float(ss.c[row, entries[0]])
            mean_y, std_y = self.measured[measured]
            feedthrough = float(ss.d[row] @ mean_in) if ss.d.numel() else 0.0
            states[j] = ((mean_y - feedthrough) / gain, std_y / abs(gain))
            read.add(j)
        return states, read

    def _gain_scale(self, b: BlockSpec, inputs: list[Scale], d: torch.Tensor) -> list[Scale]:
        if b.scale_as:
            return self.scale_of(b.scale_as, f"block {b.name!r} scale_as")
        mean_in = torch.tensor([m for m, _ in inputs], dtype=torch.float64)
        std_in = torch.tensor([s for _, s in inputs], dtype=torch.float64)
        mean_out, std_out = d @ mean_in, d.abs() @ std_in  # y = D u: μy = D μu, σy <= |D| σu
        # a measured output keeps the data's scale: the model's outputs are compared with the data in it
        image = [self.measured.get(o, (m, s)) for o, m, s in zip(b.outputs, mean_out.tolist(), std_out.tolist())]
        if not all(s > 0 for _, s in image):
            raise ModelSpecError(f"block {b.name!r}: its gain is zero at the nominal parameters; "
                                 "give scale_as to fix the output scaling")
        return image
