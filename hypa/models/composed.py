"""Execute a composition: physics and ANN blocks wired by named, normalized signals.

Every signal is kept in the normalized scale of the paper (eq. 2) together with the sample
index it starts at. A sequence holds P past samples, the window start (sample P, the paper's
k) and the samples to predict; the measured outputs are given up to the window start only, so
targets cannot leak. Measured inputs and scheduling signals start at sample 0; a physics block
with states starts its outputs one sample after the window start (it predicts x_{k+1} from
u_k); networks, gains and delays keep their inputs' start. Blocks align their inputs on the
samples all of them cover, so any length works: a training window and a whole record alike.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor, nn

from hypa.data.signature import DataSignature
from hypa.models.building import ESTIMATE, MEASURED, STEADY, BlockBuilder, collect_parameters, model_hold
from hypa.models.memo import FrozenMemo
from hypa.models.spec import ELEMENT_PARAMETER, BlockSpec, ModelSpec, ModelSpecError, parse_model_spec

if TYPE_CHECKING:
    from hypa.data import HypaDataModule

Signal = tuple[Tensor, int]  # (B, T, 1) normalized values, index of the first sample


PAST_MARGIN = 4  # an estimated start sees this many times as many measured values as the block has states


class ComposedModel(nn.Module):
    """A HyPA-Net: the blocks of ``spec`` in dependency order.

    Args:
        spec: the composition.
        physical_values: nominal values of shared physical parameters (the ``vehicle`` group);
            a system's own nominal values fill in the rest (all of them: ``None``).
        input_names / output_names: measured inputs and outputs (targets), in data order.
        input_scale / output_scale: (mean, std) per measured signal in SI units (the training
            set's normalization; :meth:`from_data` takes them from the data instead).
        dt: sample time [s]; horizon: lifted window length N; hold: ``zoh`` or ``foh`` for a spec
            that fixes none (``None``: the spec's, else ``zoh``; a different one than the spec's
            is a ``ModelSpecError``, see :func:`~hypa.models.building.model_hold`).
        ann_name / ann_hparams: the network used by every ANN block (``ann`` config group).
        scheduling_names / scheduling_scale: measured scheduling signals and their (mean, std).
    """

    def __init__(
        self,
        spec: ModelSpec,
        physical_values: Mapping[str, float] | None,
        input_names: Sequence[str],
        output_names: Sequence[str],
        input_scale: Mapping[str, tuple[float, float]],
        output_scale: Mapping[str, tuple[float, float]],
        dt: float,
        horizon: int = 100,
        hold: str | None = None,
        ann_name: str = "lstm",
        ann_hparams: Mapping[str, Any] | None = None,
        scheduling_names: Sequence[str] = (),
        scheduling_scale: Mapping[str, tuple[float, float]] | None = None,
    ) -> None:
        super().__init__()
        self.spec, self.input_names, self.output_names = spec, tuple(input_names), tuple(output_names)
        self.scheduling_names = tuple(scheduling_names)
        self.measured_scale = dict(output_scale)
        self.order = self._dependency_order(spec)
        self.parameters_, self._trainable_of, systems, from_data = collect_parameters(spec, physical_values or {})
        self.trainable_physics = tuple(sorted({t for ts in self._trainable_of.values() for t in ts}))
        self.hold = model_hold(spec, hold)
        self._register_offsets(spec.sensor_offsets, input_scale)
        scales = {**input_scale, **(scheduling_scale or {})}
        builder = BlockBuilder(self.parameters_, systems, scales, self.measured_scale, self.scheduling_names, dt,
                               horizon, self.hold, ann_name, ann_hparams or {}, from_data)
        self.blocks = nn.ModuleDict({b.name: builder.build(b) for b in self.order})
        self.scales, self.starts, self.encoders = builder.scales, builder.starts, builder.encoders
        self._observed: dict[str, str] = {}  # block -> buffer: which of its outputs are measured (estimate)
        for k, (name, how) in enumerate(self.starts.items()):
            if how.mode == ESTIMATE:
                self._observed[name] = f"_observed{k}"
                self.register_buffer(self._observed[name], torch.tensor([m is not None for m in how.observed]),
                                     persistent=False)
        self._ann_measured = {b.name: [self.output_names.index(n) for n in b.initial_state]  # measured columns
                              for b in self.order if b.kind == "ann" and b.initial_state}
        missing = [o for o in spec.outputs if o not in self.scales]
        if missing:
            raise ModelSpecError(f"model outputs {missing} are written by no block; signals: {sorted(self.scales)}")
        if tuple(spec.outputs) != self.output_names:
            raise ModelSpecError(f"model outputs {list(spec.outputs)} must be the measured outputs "
                                 f"{list(self.output_names)}, in that order")
        self.bypassed: set[str] = set()
        self.memo: FrozenMemo | None = None  # the frozen blocks' outputs by window, while networks train
        self.set_stage(None)

    @classmethod
    def from_data(cls, data: DataSignature | HypaDataModule, spec: ModelSpec | Mapping[str, Any],
                  physical_values: Mapping[str, float] | None = None, *, horizon: int | None = None,
                  hold: str | None = None, ann_name: str = "lstm",
                  ann_hparams: Mapping[str, Any] | None = None) -> ComposedModel:
        """``spec`` (a :class:`ModelSpec` or its dict) on ``data``'s channels (a data module after
        ``setup()`` or its :class:`~hypa.data.DataSignature`): names, scales (mean, std) [SI] and dt [s]
        from the data; ``horizon`` defaults to the data's window N, ``hold`` to the spec's."""
        data = DataSignature.of(data)
        spec = spec if isinstance(spec, ModelSpec) else parse_model_spec(dict(spec))
        return cls(spec, physical_values, data.input_names, data.output_names, data.scale(data.input_names),
                   data.scale(data.output_names), data.dt, data.window if horizon is None else horizon, hold,
                   ann_name, ann_hparams, data.scheduling_names, data.scale(data.scheduling_names))

    def suggested_past(self) -> int:
        """The past samples (``data.past``) this model's estimated starts should see: ``PAST_MARGIN``
        times the fewest that determine the states (:meth:`past_needed`), in measured values; 0
        where no block estimates its start."""
        needed = self.past_needed()
        return PAST_MARGIN * (max(needed.values()) + 1) - 1 if needed else 0

    def networks_reading_outputs(self) -> tuple[str, ...]:
        """The networks that start from the measured outputs over the past (their ``initial_state``):
        how many past samples they need, only the data can say (:func:`hypa.data.memory.linear_memory`)."""
        return tuple(name for name, index in self._ann_measured.items() if index)

    def past_needed(self) -> dict[str, int]:
        """Per physics block started from an estimate: the fewest past samples (``data.past``)
        whose measured outputs, with the window start, are as many values as the block has states."""
        needed = {}
        for name, start in self.starts.items():
            if start.mode == ESTIMATE:
                measured = sum(m is not None for m in start.observed)
                needed[name] = -(-self.blocks[name].model.n_states // measured) - 1
        return needed

    # -- construction -------------------------------------------------------------------
    def _dependency_order(self, spec: ModelSpec) -> list[BlockSpec]:
        available = {*self.input_names, *self.scheduling_names}
        order, pending = [], list(spec.blocks)
        while pending:
            ready = [b for b in pending if set(b.inputs) | set(b.residual_of) <= available]
            if not ready:
                lines = [f"{b.name} needs {sorted(set(b.inputs) | set(b.residual_of) - available)}" for b in pending]
                raise ModelSpecError(
                    f"model {spec.name!r}: blocks wait for signals nobody writes ({'; '.join(lines)}); "
                    f"available signals: {sorted(available)}; measured outputs are initial states only"
                )
            for b in ready:
                clash = set(b.outputs) & available
                if clash:
                    raise ModelSpecError(f"block {b.name!r} writes {sorted(clash)}, which already exist")
                available |= set(b.outputs)
                order.append(b)
                pending.remove(b)
        return order

    def _register_offsets(self, offsets: Mapping[str, float], input_scale: Mapping[str, tuple[float, float]]) -> None:
        """Normalized sensor offsets b/σ of the measured inputs and outputs (zeros where none)."""
        unknown = set(offsets) - set(self.input_names) - set(self.output_names)
        if unknown:
            raise ModelSpecError(f"sensor_offsets {sorted(unknown)} are not measured signals; measured: "
                                 f"{', '.join((*self.input_names, *self.output_names))}")
        norm = lambda names, scale: torch.tensor([offsets.get(n, 0.0) / scale[n][1] for n in names],  # noqa: E731
                                             dtype=torch.float64)
        self.register_buffer("input_offset", norm(self.input_names, input_scale), persistent=False)
        self.register_buffer("output_offset", norm(self.output_names, self.measured_scale), persistent=False)
        self.has_offsets = bool(offsets)

    # -- training stages ---------------------------------------------------------------
    def set_stage(self, train: Sequence[str] | None, bypass: Sequence[str] = ()) -> None:
        """Train only the blocks in ``train`` (all when None) and bypass the ``bypass`` ones."""
        unknown = (set(train or ()) | set(bypass)) - set(self.blocks)
        if unknown:
            raise ModelSpecError(f"unknown blocks {sorted(unknown)}; blocks: {', '.join(self.blocks)}")
        active = set(self.blocks) if train is None else set(train)
        self.bypassed = set(bypass)
        physics = set()
        for b in self.order:
            if b.kind == "ann":
                self.blocks[b.name].requires_grad_(b.name in active and b.name not in self.bypassed)
            elif b.name in active:
                physics |= set(self._trainable_of[b.name])
            if b.name in self.encoders:  # an encoder trains with its block
                self.encoders[b.name].requires_grad_(b.name in active)
        self.parameters_.set_trainable(None, False)
        self.parameters_.set_trainable(physics, True)

    # -- simulation ---------------------------------------------------------------------
    def forward(self, u: Tensor, y_past: Tensor, s: Tensor | None = None,
                initial: Mapping[str, Tensor] | None = None) -> Tensor:
        """Predicted outputs (B, L-P-1, p), normalized, at samples P+1..L-1.

        u: (B, L, m) normalized measured inputs at samples 0..L-1; y_past: (B, P+1, p)
        normalized measured outputs at samples 0..P (P past samples and the window start;
        (B, p) means P = 0); s: (B, L, q) scheduling signals in SI units; ``initial``: see
        :meth:`signals`.
        """
        y_past = y_past[:, None] if y_past.dim() == 2 else y_past
        return self.outputs(self.signals(u, y_past, s, initial), y_past.shape[1] - 1)

    def started_blocks(self) -> dict[str, int]:
        """The physics blocks with states that start at the window start P from the measurements
        (measured or estimated): block name -> its number of states. These are the states that
        ``signals(initial=...)`` can set and ``signals(states=...)`` reports."""
        return {name: self.blocks[name].model.n_states for name, how in self.starts.items()
                if how.mode != STEADY and self.blocks[name].model.n_states}

    @torch.no_grad()
    def eigenvalues(self) -> Tensor:
        """The modes [1/s] of the physics blocks at the current parameter values (complex, every
        block's eigenvalues of A together; a scheduled block's at its parameters' nominal values, a
        nonlinear block's linearised about its operating point, :meth:`LTIBlock.linearised_a`; an FMU's
        at its own initial state, ``FMUBlock.eigenvalues``). What the model's own time scales are read
        from (:class:`hypa.diagnosis.scales.Scales`); empty for a model without states."""
        modes = [torch.linalg.eigvals(self.blocks[b.name].linearised_a(torch.float64))
                 for b in self.order if b.kind == "physics" and self.blocks[b.name].model.n_states]
        modes += [self.blocks[b.name].eigenvalues() for b in self.order if b.kind == "fmu"]
        return torch.cat(modes) if modes else torch.zeros(0, dtype=torch.complex128)

    def outputs(self, signals: Mapping[str, Signal], past: int = 0) -> Tensor:
        """The model outputs (B, L-P-1, p) at samples P+1..L-1 from ``signals``."""
        outputs = []
        for name in self.spec.outputs:
            values, start = signals[name]
            if start > past + 1:
                raise ModelSpecError(f"output {name!r} starts at sample {start}; it must cover sample {past + 1}")
            outputs.append(values[:, past + 1 - start :])
        y = torch.cat(outputs, dim=-1)
        return y + self.output_offset.to(y.dtype) if self.has_offsets else y

    def signals(self, u: Tensor, y_past: Tensor, s: Tensor | None = None, initial: Mapping[str, Tensor] | None = None,
                states: dict[str, Tensor] | None = None) -> dict[str, Signal]:
        """Every signal of the composition: name -> ((B, T, 1) normalized values, first sample).

        ``initial``: block name -> its normalized state x̂_P (B, n) at the window start, used instead
        of the measured or estimated one (multiple shooting estimates them); ``states``, when given,
        receives block name -> x̂_{P..L-1} (B, L-P, n), the start and the states it ran through, for
        each block of :meth:`started_blocks`. With a :attr:`memo` (set while networks train), the
        :meth:`frozen_blocks`' signals of a window seen before are the ones kept for it.
        """
        y_past = y_past[:, None] if y_past.dim() == 2 else y_past
        given: dict[str, Signal] = {}
        inputs = [t for t in (u, y_past, s) if t is not None]
        if (self.memo is not None and initial is None and states is None and u.shape[0]
                and not any(t.requires_grad for t in inputs)):  # (a gradient to the inputs needs the blocks run)
            frozen = self.frozen_blocks()
            if len(frozen) < len(self.order) and any(self._runs_steps(n) for n in frozen):
                values = torch.cat([p.detach().flatten().double() for p in self.parameters_.parameters()]
                                   or [torch.zeros(0, dtype=torch.float64)])
                run = lambda u_, y_, s_: self._signals(u_, y_, s_, None, None, {}, set(frozen))  # noqa: E731
                given = self.memo.signals((frozen, u.device), values, u, y_past, s, run)
            elif self.memo.entries:  # a stage that trains the physics: what was kept is of no use now
                self.memo.clear()
        return self._signals(u, y_past, s, initial, states, given, None)

    def frozen_blocks(self) -> tuple[str, ...]:
        """The blocks whose outputs nothing being trained can change (:mod:`hypa.models.memo`), in
        order: none while a physical parameter trains; else the physics, FMU and element blocks
        without a state encoder, and the bypassed networks, fed only by measured signals and other
        such blocks."""
        if any(p.requires_grad for p in self.parameters_.parameters()):
            return ()
        fed, frozen = {*self.input_names, *self.scheduling_names}, []
        for b in self.order:
            fixed = b.name in self.bypassed if b.kind == "ann" else b.name not in self.encoders
            if fixed and all(n in fed for n in (*b.inputs, *b.residual_of)):
                frozen.append(b.name)
                fed |= set(b.outputs)
        return tuple(frozen)

    def _runs_steps(self, name: str) -> bool:
        """A block that simulates sample by sample (a physics block with states, an FMU): what is
        worth keeping; a gain or a delay costs less than finding its outputs in the memo."""
        kind = self.spec.block(name).kind
        return kind == "fmu" or (kind != "ann" and kind not in ELEMENT_PARAMETER
                                 and self.blocks[name].model.n_states > 0)

    def _signals(self, u: Tensor, y_past: Tensor, s: Tensor | None, initial: Mapping[str, Tensor] | None,
                 states: dict[str, Tensor] | None, given: Mapping[str, Signal], only: set[str] | None
                 ) -> dict[str, Signal]:
        """:meth:`signals`, the outputs in ``given`` taken as they are (their blocks not run) and, with
        ``only``, those blocks run alone: their outputs returned, no measured signal."""
        y_past = y_past[:, None] if y_past.dim() == 2 else y_past
        if self.has_offsets:  # the true signals behind the biased sensors
            u = u - self.input_offset.to(u.dtype)
            y_past = y_past - self.output_offset.to(y_past.dtype)
        signals: dict[str, Signal] = {n: (u[..., i : i + 1], 0) for i, n in enumerate(self.input_names)}
        physical: dict[str, Tensor] = {}  # scheduling signals in SI units, (B, L)
        if self.scheduling_names:
            if s is None or s.shape[-1] != len(self.scheduling_names):
                raise ValueError(f"the model needs scheduling signals {list(self.scheduling_names)}")
            for i, name in enumerate(self.scheduling_names):
                mean, std = self.scales[name]
                physical[name] = s[..., i].to(u.dtype)
                signals[name] = (((s[..., i : i + 1] - mean) / std).to(u.dtype), 0)
        signals.update(given)
        for b in self.order:
            if (only is not None and b.name not in only) or (b.outputs and all(n in given for n in b.outputs)):
                continue
            names = (*b.inputs, *b.residual_of)
            start = max(signals[n][1] for n in names)
            end = min(signals[n][1] + signals[n][0].shape[1] for n in names)
            if end - start < 2:
                raise ValueError(f"block {b.name!r}: inputs overlap on {end - start} samples; need at least 2")
            aligned = lambda ns: torch.cat([signals[n][0][:, start - signals[n][1] : end - signals[n][1]]  # noqa: E731, B023 -- called in this iteration
                                            for n in ns], dim=-1)
            if b.kind == "ann":
                y, out_start = self._ann(b, aligned, y_past, start), start
            elif b.kind in ELEMENT_PARAMETER:
                y, out_start = self.blocks[b.name](aligned(b.inputs)), start
            elif b.kind == "fmu":
                y, out_start = self._fmu(b, aligned(b.inputs), y_past, start)
            else:
                rho = torch.stack([physical[s][:, start:end] for s in b.scheduling.values()], -1) \
                    if b.scheduling else None  # (B, T, q) SI
                y, out_start = self._physics(b, aligned(b.inputs), rho, y_past, start, end,
                                             None if initial is None else initial.get(b.name), states)
            for i, name in enumerate(b.outputs):
                signals[name] = (y[..., i : i + 1], out_start)
        if only is not None:
            return {name: signals[name] for b in self.order if b.name in only for name in b.outputs}
        return signals

    def _ann(self, b: BlockSpec, aligned, y_past: Tensor, start: int) -> Tensor:
        if b.name in self.bypassed:
            return aligned(b.residual_of)
        x = aligned(b.inputs)  # (B, T, inputs)
        if b.initial_state:  # the measured outputs over the past and the window start, zero after
            if start != 0:
                raise ModelSpecError(f"block {b.name!r} reads measured outputs but starts at sample {start}")
            index = self._ann_measured[b.name]
            known = x.new_zeros(*x.shape[:2], len(index))
            known[:, : y_past.shape[1]] = y_past[..., index].to(x.dtype)
            x = torch.cat([x, known], dim=-1)
        y, _ = self.blocks[b.name](x)  # (B, T, outputs)
        return y + aligned(b.residual_of) if b.residual_of else y

    def _physics(self, b: BlockSpec, u: Tensor, rho: Tensor | None, y_past: Tensor, start: int, end: int,
                 x_start: Tensor | None = None, states: dict[str, Tensor] | None = None) -> tuple[Tensor, int]:
        """Outputs of a physics block and their first sample; u (B, end-start, m) from ``start``.
        ``x_start``: its state at the window start instead of the measured or estimated one;
        ``states``: receives its states from the window start on (see :meth:`signals`)."""
        block = self.blocks[b.name]
        if not block.model.n_states:
            return block(None, u, scheduling=rho), start
        how = self.starts[b.name]
        if how.mode == STEADY:  # in equilibrium with its first input: outputs from `start` on
            x0 = block.steady_state(u[:, 0])
            y0 = block.output(x0, u[:, 0])  # the states themselves when the outputs are the states
            steps = end - start - 1
            return torch.cat([y0[:, None], block(x0, u[:, : steps + block.extra_inputs])], dim=1), start
        past = y_past.shape[1] - 1
        if start > past:
            raise ModelSpecError(f"block {b.name!r} starts at sample {start}, after the window start {past}")
        if x_start is not None:
            x0 = x_start.to(u.dtype)
        elif how.mode == MEASURED:
            x0 = y_past[:, past, list(how.index)].to(u.dtype)
        else:  # ESTIMATE: least squares over samples start..past of the outputs it observes
            assert how.mode == ESTIMATE
            observed = getattr(self, self._observed[b.name])  # (p_block,) bool
            y = y_past[:, start:, list(how.index)].to(u.dtype)  # (B, past-start+1, p_block)
            lead = past - start + 1
            x0 = block.estimate_state(u[:, : lead + 1], y, observed,  # a cubic hold's x̂_P reads one more
                                      scheduling=None if rho is None else rho[:, :lead])
            if how.encoder:  # the network sees the same past; unmeasured outputs are zeros
                past_seq = torch.cat([u[:, :lead], y * observed.to(y.dtype)], dim=-1)  # (B, lead, m + p)
                x0 = x0 + self.encoders[b.name](past_seq)[0][:, -1]
        steps = end - past - 1
        take = steps + block.extra_inputs
        u_k = u[:, past - start : past - start + take]
        rho_k = None if rho is None else rho[:, past - start : past - start + take]
        before = u[:, : past - start] if block.form.past else None  # what a cubic hold reads before the start
        if states is None:
            return block(x0, u_k, scheduling=rho_k, before=before), past + 1
        y, x = block.run(x0, u_k, scheduling=rho_k, before=before)
        states[b.name] = torch.cat([x0[:, None], x], 1)
        return y, past + 1

    def _fmu(self, b: BlockSpec, u: Tensor, y_past: Tensor, start: int) -> tuple[Tensor, int]:
        """Outputs of an FMU block from the sample after the window start on, the FMU run from the window
        start: from the measured values of its states there, else from its own initialization."""
        block, past = self.blocks[b.name], y_past.shape[1] - 1
        if start > past:
            raise ModelSpecError(f"block {b.name!r} starts at sample {start}, after the window start {past}")
        x0 = None
        if block.measured_states:
            scale = torch.tensor([self.measured_scale[n] for n in block.measured_states], dtype=torch.float64,
                                 device=u.device)
            x0 = y_past[:, past, list(block.measured_columns)].double() * scale[:, 1] + scale[:, 0]
        y, _ = block(u[:, past - start :], x0)
        return y[:, 1:], past + 1

    def to_physical(self, name: str, values: Tensor) -> Tensor:
        """A signal in SI units from its normalized values."""
        mean, std = self.scales.get(name) or self.measured_scale[name]
        return values * std + mean

    def extra_repr(self) -> str:
        wiring = "; ".join(f"{b.name}: {list(b.inputs)} -> {list(b.outputs)}" for b in self.order)
        return f"{self.spec.name}: {wiring}"
