"""A trained composition as one step: (state_k, u_k) -> (state_{k+1}, y_k), SI in and SI out.

The free run (``hypa.models.rollout.free_run``) starts a model from the first P + 1 samples of
a record (its past and the window start P) and predicts samples P + 1 on. The step takes over
there: from the state at sample K = P + 1 (``ModelStep.initial_state``, from hypa's own run over
the samples before K) each call takes the inputs and scheduling signals of sample k and returns
the outputs the free run predicts at sample k and the state at k + 1. Signals flow between the
blocks as in ``ComposedModel.signals``, normalized (eq. 2), with the normalization folded into
the step's ends. The state vector is every block's slice in the model's dependency order
(physics, held inputs, dead-time buffers, network states; ``StateSlot``, ``hypa.export.blocks``).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor, nn

from hypa.export.blocks import (
    DelayStep,
    ExportError,
    GainStep,
    NetworkStep,
    NonlinearStep,
    PhysicsStep,
    SaturationStep,
    StateSlot,
    hold_refusal,
)
from hypa.models.building import STEADY
from hypa.models.composed import ComposedModel


def scheduled_squarings(model: ComposedModel, s: Tensor, margin: int = 2, samples: int = 2000) -> dict[str, int]:
    """Per scheduled physics block, the squarings its per-sample exponential needs over the scheduling
    signals s (L, q) [SI] (at most ``samples`` of them, evenly spread), plus ``margin``: the step
    is then as accurate for signals whose ‖M‖ is up to 2^margin times the largest seen."""
    picked = s[torch.linspace(0, s.shape[0] - 1, min(samples, s.shape[0])).round().long()] if s.shape[0] else s
    out = {}
    for b in model.order:
        block = model.blocks[b.name]
        if b.kind == "physics" and b.scheduling and block.model.n_states:
            columns = [model.scheduling_names.index(n) for n in b.scheduling.values()]
            with torch.no_grad():
                out[b.name] = margin + max((block.sample_squarings(rho) for rho in picked[:, columns].double()),
                                           default=0)
    return out


class ModelStep(nn.Module):
    """``forward(state (r,), u (m + q,)) -> (next_state (r,), y (p,))`` of a ``ComposedModel``, batch of one.

    u: the model's inputs, then its scheduling signals, SI; y: its outputs, SI. ``units``: unit
    of each signal by name (for the state layout); ``squarings``: per scheduled block, the
    squarings of its per-sample exponential (``LTIBlock.sample_matrices``).
    """

    def __init__(self, model: ComposedModel, units: Mapping[str, str] | None = None,
                 squarings: Mapping[str, int] | None = None, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        why = hold_refusal(model)
        if why:
            raise ExportError(why)
        self.model, units, squarings, self.dtype = model, dict(units or {}), dict(squarings or {}), dtype
        self.input_names, self.scheduling_names = model.input_names, model.scheduling_names
        self.output_names = tuple(model.spec.outputs)
        self.forms = nn.ModuleDict()
        self.slots: list[StateSlot] = []
        for b in model.order:
            block = model.blocks[b.name]
            if b.kind == "ann":
                template = block.default_state(1, None, dtype)
                form = NetworkStep(b.name, block, template)
                self.slots += [StateSlot(b.name, f"state[{i}]", "network") for i in range(form.size)]
            elif b.kind == "delay":
                form = DelayStep(b.name, block, [model.scales[n] for n in b.inputs], dtype)
                self.slots += form.slots(b.inputs, units)
            elif b.kind == "saturation":
                form = SaturationStep(b.name, block)
            elif not block.model.n_states:
                form = GainStep(b.name, block, dtype)
            else:
                form = NonlinearStep(b.name, block, dtype) if block.model.is_nonlinear else \
                    PhysicsStep(b.name, block, squarings.get(b.name, 0), dtype)
                start = model.starts[b.name]
                unit_of = {**dict(zip(block.model.input_names, (units.get(n, "") for n in b.inputs))),
                           **{s: units.get(m, "") for s, m in zip(block.model.state_names, start.measured)}}
                self.slots += form.slots(unit_of, block.model.input_names, tuple(b.scheduling.values()))
            self.forms[b.name] = form
        self.sizes = {name: form.size for name, form in self.forms.items()}
        scale = lambda names, i: torch.tensor([model.scales[n][i] for n in names], dtype=dtype)  # noqa: E731
        for key, names in (("input", self.input_names), ("scheduling", self.scheduling_names),
                           ("output", self.output_names)):
            self.register_buffer(f"{key}_mean", scale(names, 0), persistent=False)
            self.register_buffer(f"{key}_std", scale(names, 1), persistent=False)
        self.register_buffer("input_offset", model.input_offset.to(dtype), persistent=False)
        self.register_buffer("output_offset", model.output_offset.to(dtype), persistent=False)

    @property
    def state_size(self) -> int:
        return sum(self.sizes.values())

    def forward(self, state: Tensor, u: Tensor) -> tuple[Tensor, Tensor]:
        model, m = self.model, len(self.input_names)
        state, u = state[None], u[None]  # (1, r), (1, m + q)
        inputs = (u[:, :m] - self.input_mean) / self.input_std - self.input_offset  # (1, m)
        physical = u[:, m:]  # (1, q) SI
        scheduled = (physical - self.scheduling_mean) / self.scheduling_std
        signals = {n: inputs[:, i : i + 1] for i, n in enumerate(self.input_names)}
        signals.update({n: scheduled[:, i : i + 1] for i, n in enumerate(self.scheduling_names)})
        offset, new = 0, []
        for b in model.order:
            size = self.sizes[b.name]
            part, offset = state[:, offset : offset + size], offset + size
            x = torch.cat([signals[n] for n in b.inputs], -1)
            rho = None
            if b.scheduling:
                rho = torch.cat([physical[:, self.scheduling_names.index(s)][:, None]
                                 for s in b.scheduling.values()], -1)
            if b.kind == "ann" and b.name in model.bypassed:
                y, after = torch.cat([signals[n] for n in b.residual_of], -1), part
            else:
                if b.kind == "ann" and b.initial_state:  # measured outputs are zeros after the window start
                    x = torch.cat([x, x.new_zeros(1, len(b.initial_state))], -1)
                y, after = self.forms[b.name](x, rho, part)
                if b.kind == "ann" and b.residual_of:
                    y = y + torch.cat([signals[n] for n in b.residual_of], -1)
            new.append(after)
            signals.update({name: y[:, i : i + 1] for i, name in enumerate(b.outputs)})
        y = torch.cat([signals[n] for n in self.output_names], -1) + self.output_offset
        return torch.cat(new, -1)[0], (y * self.output_std + self.output_mean)[0]

    @torch.no_grad()
    def initial_state(self, u: Tensor, y_past: Tensor, s: Tensor) -> Tensor:
        """The state (r,) at sample P + 1 of a record from hypa's own run over it (``rollout.model_inputs``:
        u (1, L, m) and y_past (1, P + 1, p) normalized, s (1, L, q) SI)."""
        model, states = self.model, {}
        signals = model.signals(u, y_past, s, states=states)
        past = y_past.shape[1] - 1
        first, parts = past + 1, []
        for b in model.order:
            form, block = self.forms[b.name], model.blocks[b.name]
            start = max(signals[n][1] for n in b.inputs)
            values = torch.cat([signals[n][0][:, start - signals[n][1] :] for n in b.inputs], -1)  # (1, T, m)
            if isinstance(form, NetworkStep):
                if start > first:
                    raise ExportError(f"block {b.name!r} starts at sample {start}, "
                                      f"after the first exported one {first}")
                chunk = values[:, : first - start]
                if b.initial_state:
                    index = [model.output_names.index(n) for n in b.initial_state]
                    known = chunk.new_zeros(*chunk.shape[:2], len(index))
                    known[:, : past + 1] = y_past[:, : chunk.shape[1], index].to(chunk.dtype)
                    chunk = torch.cat([chunk, known], -1)
                state = block(chunk)[1] if chunk.shape[1] else block.default_state(1, None, self.dtype)
                parts.append(form.initial(state))
            elif isinstance(form, DelayStep):
                parts.append(form.buffer(values, start, first))
            elif isinstance(form, (PhysicsStep, NonlinearStep)):
                parts.append(self._physics_state(b, form, values, start, first, states, s))
        return torch.cat(parts, -1)[0] if parts else torch.zeros(0)

    def _physics_state(self, b, form: PhysicsStep | NonlinearStep, values: Tensor, start: int, first: int,
                       states: dict[str, Tensor], s: Tensor) -> Tensor:
        """A physics block's slice at sample ``first`` (SI): x_first, or x, u, ρ at first - 1 (first-order hold)."""
        block, past = form.block, first - 1
        if self.model.starts[b.name].mode == STEADY:
            x0 = block.steady_state(values[:, 0])
            steps = first - start
            run = block.run(x0, values[:, : steps + block.extra_inputs])[1] if steps else x0[:, :0]
            xs, at = torch.cat([x0[:, None], run], 1), start  # x̂ from sample `start`
        else:
            xs, at = states[b.name], past  # x̂_P, x̂_{P+1}, ...
        sample = first - 1 if form.lagged else first
        if sample < at:
            raise ExportError(f"block {b.name!r} starts at sample {at}: its first-order hold has no state before "
                              f"the first exported sample {first}")
        x = xs[:, sample - at] * block.state_std.to(self.dtype) + block.state_mean.to(self.dtype)
        if not form.lagged:
            return x
        u = values[:, sample - start] * block.input_std.to(self.dtype) + block.input_mean.to(self.dtype)
        rho = [s[:, sample, self.scheduling_names.index(n)][:, None] for n in b.scheduling.values()]
        return torch.cat([x, u, *rho], -1)
