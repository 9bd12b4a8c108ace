"""Execute a composition: physics and ANN blocks wired by named, normalized signals.

Every signal is kept in the normalized scale of the paper (eq. 2) together with the sample
index it starts at. Measured inputs start at sample 0 of a window; a physics block with states
starts its outputs one sample later (it predicts x_{k+1} from u_k); networks and static gains
keep their inputs' start. Blocks align their inputs on the samples all of them cover, so any
sequence length works: a 101-sample training window and a whole record free-running alike.
Measured states enter only as initial states, never as sequences, so targets cannot leak.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from hypa.ann import build_ann
from hypa.models.spec import BlockSpec, ModelSpec, ModelSpecError
from hypa.physics import LTIBlock, ParameterSpec, PhysicalParameters, Scaling
from hypa.physics.elements import DeadTime, local_name
from hypa.physics.systems import build_system

Signal = tuple[Tensor, int]  # (B, T, 1) normalized values, index of the first sample


class ComposedModel(nn.Module):
    """A HyPA-Net: the blocks of ``spec`` in dependency order.

    Args:
        spec: the composition.
        physical_values: nominal values of every physical parameter the systems read.
        input_names / state_names: measured inputs and states, in data order.
        input_scale / state_scale: (mean, std) per measured signal in SI units (the training
            set's normalization).
        dt: sample time [s]; horizon: lifted window length N; hold: ``zoh`` or ``foh`` (unless
            the spec fixes its own).
        ann_name / ann_hparams: the network used by every ANN block (``ann`` config group).
    """

    def __init__(
        self,
        spec: ModelSpec,
        physical_values: Mapping[str, float],
        input_names: Sequence[str],
        state_names: Sequence[str],
        input_scale: Mapping[str, tuple[float, float]],
        state_scale: Mapping[str, tuple[float, float]],
        dt: float,
        horizon: int = 100,
        hold: str = "zoh",
        ann_name: str = "lstm",
        ann_hparams: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__()
        self.spec, self.input_names, self.state_names = spec, tuple(input_names), tuple(state_names)
        self.scales: dict[str, tuple[float, float]] = {**input_scale}
        self.measured_state_scale = dict(state_scale)
        self.order = self._dependency_order(spec)
        self._trainable_of: dict[str, tuple[str, ...]] = {}
        self.parameters_ = self._physical_parameters(spec, physical_values)
        self.hold = spec.hold or hold
        self._register_offsets(spec.sensor_offsets)
        self.blocks = nn.ModuleDict()
        for block in self.order:
            self.blocks[block.name] = self._build_block(block, dt, horizon, self.hold, ann_name,
                                                        dict(ann_hparams or {}))
        missing = [o for o in spec.outputs if o not in self.scales]
        if missing:
            raise ModelSpecError(f"model outputs {missing} are written by no block; signals: {sorted(self.scales)}")
        if len(spec.outputs) != len(self.state_names):
            raise ModelSpecError(f"model outputs {spec.outputs} must match the measured states {self.state_names}")
        self.bypassed: set[str] = set()
        self.set_stage(None)

    # -- construction -------------------------------------------------------------------
    def _dependency_order(self, spec: ModelSpec) -> list[BlockSpec]:
        available, order, pending = set(self.input_names), [], list(spec.blocks)
        while pending:
            ready = [b for b in pending if set(b.inputs) | set(b.residual_of) <= available]
            if not ready:
                lines = [f"{b.name} needs {sorted(set(b.inputs) | set(b.residual_of) - available)}" for b in pending]
                raise ModelSpecError(
                    f"model {spec.name!r}: blocks wait for signals nobody writes ({'; '.join(lines)}); "
                    f"available signals: {sorted(available)}; measured states are initial states only"
                )
            for b in ready:
                clash = set(b.outputs) & available
                if clash:
                    raise ModelSpecError(f"block {b.name!r} writes {sorted(clash)}, which already exist")
                available |= set(b.outputs)
                order.append(b)
                pending.remove(b)
        return order

    def _physical_parameters(self, spec: ModelSpec, values: Mapping[str, float]) -> PhysicalParameters:
        """One set of named parameters: shared ones (vehicle, overridden by the spec's
        ``parameters``) and each block's own, stored as ``<block>/<name>``."""
        values = {**values, **spec.parameters}
        specs: dict[str, ParameterSpec] = {}
        trainable: set[str] = set()
        for b in spec.blocks:
            if b.kind == "ann":
                continue
            local = {local_name(b.name, k): v for k, v in b.parameters.items()}
            system = None if b.kind == "delay" else build_system(b.system, b.name)
            names = (local_name(b.name, "delay_s"),) if system is None else system.parameter_names
            unknown_local = set(local) - set(names)
            if unknown_local:
                raise ModelSpecError(f"block {b.name!r}: parameters {sorted(unknown_local)} are not its own; "
                                     f"it has {', '.join(names)}")
            missing = [p for p in names if p not in values and p not in local]
            if missing:
                raise ModelSpecError(f"block {b.name!r} ({b.system or b.kind}) needs parameters {missing}; give "
                                     "them in the vehicle config or the block's parameters")
            if system is None:
                block_specs = [ParameterSpec(names[0], local[names[0]], "s")]
            else:
                block_specs = system.parameter_specs({**values, **local})
            resolved = {t: local_name(b.name, t) if local_name(b.name, t) in names else t for t in b.trainable}
            unknown = [t for t, full in resolved.items() if full not in names]
            if unknown:
                raise ModelSpecError(f"block {b.name!r}: {sorted(unknown)} are not parameters of "
                                     f"{b.system or b.kind}; it has {', '.join(names)}")
            for s in block_specs:
                specs[s.name] = s
            trainable |= set(resolved.values())
            self._trainable_of[b.name] = tuple(resolved.values())
        unread = set(spec.parameters) - set(specs)
        if unread:
            raise ModelSpecError(f"model {spec.name!r}: parameters {sorted(unread)} are read by no block; "
                                 f"read: {', '.join(specs)}")
        params = PhysicalParameters(specs.values())
        params.set_trainable(trainable, True)
        self.trainable_physics = tuple(sorted(trainable))
        return params

    def _register_offsets(self, offsets: Mapping[str, float]) -> None:
        """Normalized sensor offsets b/σ of the measured inputs and states (zeros where none)."""
        unknown = set(offsets) - set(self.input_names) - set(self.state_names)
        if unknown:
            raise ModelSpecError(f"sensor_offsets {sorted(unknown)} are not measured signals; measured: "
                                 f"{', '.join((*self.input_names, *self.state_names))}")
        norm = lambda names, scale: torch.tensor([offsets.get(n, 0.0) / scale[n][1] for n in names],  # noqa: E731
                                             dtype=torch.float64)
        self.register_buffer("input_offset", norm(self.input_names, self.scales), persistent=False)
        self.register_buffer("state_offset", norm(self.state_names, self.measured_state_scale), persistent=False)
        self.has_offsets = bool(offsets)

    def _scale_of(self, names: Sequence[str], where: str) -> list[tuple[float, float]]:
        missing = [n for n in names if n not in self.scales and n not in self.measured_state_scale]
        if missing:
            raise ModelSpecError(f"{where}: no scaling for {missing}")
        return [self.scales.get(n) or self.measured_state_scale[n] for n in names]

    def _build_block(self, b: BlockSpec, dt: float, horizon: int, hold: str, ann: str, hparams: dict) -> nn.Module:
        inputs = self._scale_of(b.inputs, f"block {b.name!r} inputs")
        if b.kind == "ann":
            if b.residual_of:
                outputs = self._scale_of(b.residual_of, f"block {b.name!r} residual_of")
            elif b.scale_as:  # zero mean: a network output of 0 is 0 in SI units (e.g. no rear steering)
                outputs = [(0.0, std) for _, std in self._scale_of(b.scale_as, f"block {b.name!r} scale_as")]
            elif all(o in self.measured_state_scale for o in b.outputs):
                outputs = [self.measured_state_scale[o] for o in b.outputs]
            else:
                raise ModelSpecError(f"ann block {b.name!r}: give scale_as or residual_of so its outputs "
                                     f"{list(b.outputs)} have a physical scale")
            if len(outputs) != len(b.outputs):
                raise ModelSpecError(f"block {b.name!r}: {len(b.outputs)} outputs but {len(outputs)} scales")
            self.scales.update(zip(b.outputs, outputs))
            missing = [s for s in b.initial_state if s not in self.measured_state_scale]
            if missing:
                raise ModelSpecError(f"block {b.name!r}: initial state {missing} is not measured")
            zero_init = bool(b.residual_of or b.scale_as)  # start as pure physics / no rear steering
            d_in = len(b.inputs) + len(b.initial_state)
            return build_ann(ann, d_in, len(b.outputs), zero_init=zero_init, **hparams)

        if b.kind == "delay":  # a shift: outputs keep their inputs' scale
            self.scales.update(zip(b.outputs, inputs))
            return DeadTime(self.parameters_, local_name(b.name, "delay_s"), dt)

        system = build_system(b.system, b.name)
        if len(b.inputs) != len(system.input_names) or len(b.outputs) != len(system.output_names):
            raise ModelSpecError(f"block {b.name!r}: {b.system} maps {list(system.input_names)} -> "
                                 f"{list(system.output_names)}; got {list(b.inputs)} -> {list(b.outputs)}")
        nominal = {k: torch.tensor(v, dtype=torch.float64) for k, v in self.parameters_.as_floats().items()}
        d = system.matrices(nominal).d
        if system.n_states and b.steady:  # states nobody measures: scaled like scale_as, else the inputs
            states = self._scale_of(b.scale_as, f"block {b.name!r} scale_as") if b.scale_as else inputs
            if not system.outputs_are_states or len(states) != system.n_states:
                raise ModelSpecError(f"block {b.name!r}: a steady start needs a system whose outputs are its "
                                     f"{system.n_states} states, scaled by scale_as (or by its inputs)")
            outputs = states
        elif system.n_states:
            initial = b.initial_state or system.state_names
            missing = [s for s in initial if s not in self.measured_state_scale]
            if missing:
                raise ModelSpecError(f"block {b.name!r}: initial state {missing} is not measured; "
                                     f"measured states: {list(self.measured_state_scale)}")
            states = [self.measured_state_scale[s] for s in initial]
            outputs = states if system.outputs_are_states else self._scale_of(b.scale_as, f"block {b.name!r}")
        elif b.scale_as:
            states, outputs = [], self._scale_of(b.scale_as, f"block {b.name!r} scale_as")
        else:  # a static gain: y = D u, so μy = D μu and σy = |D| σu
            mean_in = torch.tensor([m for m, _ in inputs], dtype=torch.float64)
            std_in = torch.tensor([s for _, s in inputs], dtype=torch.float64)
            mean_out, std_out = d @ mean_in, d.abs() @ std_in
            if not bool((std_out > 0).all()):
                raise ModelSpecError(f"block {b.name!r}: its gain is zero at the nominal parameters; "
                                     "give scale_as to fix the output scaling")
            states, outputs = [], list(zip(mean_out.tolist(), std_out.tolist()))
        self.scales.update(zip(b.outputs, outputs))
        t = lambda pairs, i: torch.tensor([p[i] for p in pairs], dtype=torch.float64)  # noqa: E731
        scaling = Scaling(t(states, 0), t(states, 1), t(inputs, 0), t(inputs, 1), t(outputs, 0), t(outputs, 1))
        block = LTIBlock(system, self.parameters_, dt, horizon, hold=hold if system.n_states else "zoh",
                         scaling=scaling)
        block.check_stable()
        return block

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
        self.parameters_.set_trainable(None, False)
        self.parameters_.set_trainable(physics, True)

    # -- simulation ---------------------------------------------------------------------
    def forward(self, u: Tensor, x0: Tensor) -> Tensor:
        """Predicted states (B, L-1, p), normalized, at samples 1..L-1 of the inputs.

        u: (B, L, m) normalized measured inputs at samples 0..L-1; x0: (B, n) normalized
        measured states at sample 0.
        """
        return self.outputs(self.signals(u, x0))

    def outputs(self, signals: Mapping[str, Signal]) -> Tensor:
        """The model outputs (B, L-1, p) at samples 1..L-1 from ``signals(u, x0)``."""
        outputs = []
        for name in self.spec.outputs:
            values, start = signals[name]
            if start > 1:
                raise ModelSpecError(f"output {name!r} starts at sample {start}; it must cover sample 1")
            outputs.append(values[:, 1 - start :])
        y = torch.cat(outputs, dim=-1)
        return y + self.state_offset.to(y.dtype) if self.has_offsets else y

    def signals(self, u: Tensor, x0: Tensor) -> dict[str, Signal]:
        """Every signal of the composition: name -> ((B, T, 1) normalized values, first sample)."""
        if self.has_offsets:  # the true signals behind the biased sensors
            u = u - self.input_offset.to(u.dtype)
            x0 = x0 - self.state_offset.to(x0.dtype)
        signals: dict[str, Signal] = {n: (u[..., i : i + 1], 0) for i, n in enumerate(self.input_names)}
        initial = {n: x0[:, i : i + 1] for i, n in enumerate(self.state_names)}
        for b in self.order:
            names = (*b.inputs, *b.residual_of)
            start = max(signals[n][1] for n in names)
            end = min(signals[n][1] + signals[n][0].shape[1] for n in names)
            if end - start < 2:
                raise ValueError(f"block {b.name!r}: inputs overlap on {end - start} samples; need at least 2")
            aligned = lambda ns: torch.cat([signals[n][0][:, start - signals[n][1] : end - signals[n][1]]  # noqa: E731
                                            for n in ns], dim=-1)
            block = self.blocks[b.name]
            if b.kind == "ann":
                if b.name in self.bypassed:
                    y = aligned(b.residual_of)
                else:
                    x = aligned(b.inputs)  # (B, T, inputs)
                    if b.initial_state:  # the measured state as an impulse at sample 0
                        if start != 0:
                            raise ModelSpecError(f"block {b.name!r} reads an initial state but starts at {start}")
                        impulse = x.new_zeros(*x.shape[:2], len(b.initial_state))
                        impulse[:, 0] = torch.cat([initial[s] for s in b.initial_state], dim=-1)
                        x = torch.cat([x, impulse], dim=-1)
                    y, _ = block(x)  # (B, T, outputs)
                    y = y + aligned(b.residual_of) if b.residual_of else y
                out_start = start
            elif b.kind == "delay":
                y, out_start = block(aligned(b.inputs)), start
            elif b.steady:  # starts in equilibrium with its first input: outputs from sample `start` on
                steps = end - start - 1
                inputs = aligned(b.inputs)
                x_init = block.steady_state(inputs[:, 0])
                y = torch.cat([x_init[:, None], block(x_init, inputs[:, : steps + block.n_taps - 1])], dim=1)
                out_start = start
            elif block.model.n_states:
                if start != 0:
                    raise ModelSpecError(f"block {b.name!r} needs a measured initial state at sample {start}")
                steps = end - start - 1
                x_init = torch.cat([initial[s] for s in (b.initial_state or block.model.state_names)], dim=-1)
                y = block(x_init, aligned(b.inputs)[:, : steps + block.n_taps - 1])
                out_start = start + 1
            else:
                y, out_start = block(None, aligned(b.inputs)), start
            for i, name in enumerate(b.outputs):
                signals[name] = (y[..., i : i + 1], out_start)
        return signals

    def to_physical(self, name: str, values: Tensor) -> Tensor:
        """A signal in SI units from its normalized values."""
        mean, std = self.scales.get(name) or self.measured_state_scale[name]
        return values * std + mean

    def extra_repr(self) -> str:
        wiring = "; ".join(f"{b.name}: {list(b.inputs)} -> {list(b.outputs)}" for b in self.order)
        return f"{self.spec.name}: {wiring}"
