"""One sample of each kind of block: the step forms a one-step model (``hypa.export.step``) chains.

Every form maps the block's normalized inputs at sample k (1, m), its scheduling signals ρ_k
(1, q) [SI] where it has any, and its slice of the state vector (1, r) to its normalized
outputs at sample k and its slice at k + 1. Nothing of the physics is written again: the
forms hold the blocks' own normalized matrices (eq. 5-8), call a scheduled block's
``sample_matrices``, a nonlinear block's ``lure_step``, and the networks' own ``forward`` on
one-sample chunks (the sequence contract of ``hypa.ann.base``: chunked runs equal whole ones) or
their ``step`` where they have one.

States, as the state vector holds them (``StateSlot``):

* a physics block under a zero-order hold: its states x_k [SI]; x_{k+1} = Â x_k + B̂ u_k + Ĥ
  needs nothing later than sample k;
* under a first-order hold: x_{k-1}, u_{k-1} (and ρ_{k-1}) [SI], because x_k = Â x_{k-1} +
  B̂_0 u_{k-1} + B̂_1 u_k + Ĥ reads the input of sample k, which the step only gets with it
  (a nonlinear block likewise under either hold: its corrector reads u_k);
* a dead time: its input's last ``whole + 1`` samples [SI], newest first;
* a network: its state (LSTM h, c; S4 and Mamba layer states; a Transformer's fixed-size
  context), flattened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torch.utils import _pytree as pytree

from hypa.ann.base import SequenceBlock
from hypa.core.errors import UserError
from hypa.physics.elements import DeadTime, Saturation
from hypa.physics.lti import LTIBlock

Scale = tuple[float, float]  # (mean, std) [SI]


class ExportError(UserError):
    """A model, or a block of it, that has no exact one-step form (yet), or an export that fails its check."""


def hold_refusal(model) -> str | None:
    """Why a block of ``model`` (a ``ComposedModel``) cannot step causally (one line), or None.

    A step reads the inputs up to its own sample: a zero- or first-order hold does (the state
    holds x_{k-1} and u_{k-1} for the latter), a cubic hold reads one sample after that."""
    for b in model.order:
        block = model.blocks[b.name]
        if b.kind == "fmu":
            return (f"block {b.name!r} is an FMU ({block.description.path.name}), another simulator: hypa exports "
                    "no step around it (export the networks' runs or the FMU itself)")
        if b.kind == "physics" and block.model.n_states and block.form.lead > 1:
            return (f"block {b.name!r} holds its inputs by a {block.hold} hold, which reads the input a sample "
                    "ahead of its output: no causal step (train it with physics.hold=foh to export it)")
    return None


@dataclass(frozen=True)
class StateSlot:
    """One entry of the state vector: ``block``'s ``name`` (``kind``: physics, held_input,
    held_scheduling, delay or network), in ``unit`` ('' for a network's internal state)."""

    block: str
    name: str
    kind: str
    unit: str = ""


def _constant(module: nn.Module, name: str, value: Tensor, dtype: torch.dtype = torch.float32) -> None:
    module.register_buffer(name, value.detach().to(dtype).clone(), persistent=False)


class PhysicsStep(nn.Module):
    """A physics block with states, one sample: x̂_{k+1} = Â x̂_k + Σ_t B̂_t û_{k+t} + Ĥ, ŷ_k = Ĉ x̂_k + D̂ û_k + Ĝ.

    A scheduled block's matrices come from ρ every step (``LTIBlock.sample_matrices`` with
    ``squarings``); a constant block's are its own, taken once in ``dtype`` (float32: the dtype of
    hypa's free run). The state slice is SI (``state_mean``, ``state_std`` fold the scaling).
    """

    def __init__(self, name: str, block: LTIBlock, squarings: int = 0, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        model = block.model
        self.block, self.name, self.squarings = block, name, squarings
        self.n, self.m, self.q = model.n_states, len(model.input_names), len(block.scheduled)
        self.lagged = block.hold == "foh"  # x_k needs u_k: the state holds sample k - 1
        self.same, self.feedthrough = model.outputs_are_states, block.feedthrough
        self.curved = model.has_nonlinear_output  # y = C x + D u + h(x, u): h by the block's own torch code
        for key in ("state_mean", "state_std", "input_mean", "input_std"):
            _constant(self, key, getattr(block, key), dtype)
        if not block.scheduled:
            with torch.no_grad():
                norm = block.normalized(dtype)
            for key in ("a", "h", "c", "d", "g"):
                _constant(self, key, getattr(norm, key), dtype)
            _constant(self, "b_taps", torch.stack(norm.b_taps), dtype)

    @property
    def size(self) -> int:
        return self.n + (self.m + self.q if self.lagged else 0)

    def slots(self, unit_of: dict[str, str], inputs: tuple[str, ...], scheduling: tuple[str, ...]) -> list[StateSlot]:
        """The slice's entries; ``unit_of``: unit of a state, by the block's state name."""
        model, when = self.block.model, "[k-1]" if self.lagged else ""
        slots = [StateSlot(self.name, f"{s}{when}", "physics", unit_of.get(s, "")) for s in model.state_names]
        if self.lagged:
            slots += [StateSlot(self.name, f"{u}[k-1]", "held_input", unit_of.get(u, "")) for u in inputs]
            slots += [StateSlot(self.name, f"{s}[k-1]", "held_scheduling", unit_of.get(s, "")) for s in scheduling]
        return slots

    def matrices(self, rho: Tensor | None) -> tuple[Tensor, ...]:
        """Â, B̂_t (T, n, m), Ĥ, Ĉ, D̂, Ĝ at ρ (1, q), or the constant ones."""
        if rho is None:
            return self.a, self.b_taps, self.h, self.c, self.d, self.g
        norm = self.block.sample_matrices(rho[0], self.squarings)
        return norm.a, torch.stack(norm.b_taps), norm.h, norm.c, norm.d, norm.g

    def forward(self, u: Tensor, rho: Tensor | None, state: Tensor) -> tuple[Tensor, Tensor]:
        n, m = self.n, self.m
        x = (state[:, :n] - self.state_mean) / self.state_std  # (1, n) normalized
        if self.lagged:  # advance x_{k-1} -> x_k with the matrices at ρ_{k-1}
            u_prev = (state[:, n : n + m] - self.input_mean) / self.input_std
            a, b, h = self.matrices(None if rho is None else state[:, n + m :])[:3]
            x = x @ a.T + u_prev @ b[0].T + u @ b[1].T + h
        a, b, h, c, d, g = self.matrices(rho)
        if self.same:
            y = x
        else:
            y = x @ c.T + g
            y = y + u @ d.T if self.feedthrough else y
            y = y + self.block.nonlinear_output(x, u) if self.curved else y
        physical = lambda values, mean, std: values * std + mean  # noqa: E731
        if self.lagged:
            parts = [physical(x, self.state_mean, self.state_std), physical(u, self.input_mean, self.input_std)]
            return y, torch.cat(parts if rho is None else [*parts, rho], -1)
        x_next = x @ a.T + u @ b[0].T + h
        return y, physical(x_next, self.state_mean, self.state_std)


class NonlinearStep(nn.Module):
    """A nonlinear (Lur'e) physics block, one sample: x_k from x_{k-1}, u_{k-1} and u_k by the block's own
    ``lure_step`` (Heun's predictor-corrector reads the input after the step), all SI; the state
    slice holds x_{k-1} and u_{k-1} whatever the hold."""

    lagged = True

    def __init__(self, name: str, block: LTIBlock, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        if block.scheduled:
            raise ExportError(f"block {name!r}: a nonlinear system cannot be scheduled")
        self.block, self.name = block, name
        self.n, self.m, self.q = block.model.n_states, len(block.model.input_names), 0
        self.same, self.feedthrough = block.model.outputs_are_states, block.feedthrough
        self.curved = block.model.has_nonlinear_output
        with torch.no_grad():
            lure = block.lure_parts(dtype)
            norm = block.normalized(dtype)
        detach = lambda t: t.detach().clone() if isinstance(t, Tensor) else t  # noqa: E731
        self.lure = lure._replace(phi_t=detach(lure.phi_t), taps=tuple(detach(t) for t in lure.taps),
                                  drift=detach(lure.drift), now_t=detach(lure.now_t), next_t=detach(lure.next_t),
                                  held_t=detach(lure.held_t),
                                  prepared={k: detach(v) for k, v in lure.prepared.items()})
        for key in ("c", "d", "g"):
            _constant(self, key, getattr(norm, key), dtype)
        for key in ("state_mean", "state_std", "input_mean", "input_std"):
            _constant(self, key, getattr(block, key), dtype)

    @property
    def size(self) -> int:
        return self.n + self.m

    slots = PhysicsStep.slots  # the same layout as a first-order hold's: x_{k-1}, u_{k-1}

    def forward(self, u: Tensor, rho: Tensor | None, state: Tensor) -> tuple[Tensor, Tensor]:
        n, lure = self.n, self.lure
        x_prev, u_prev = state[:, :n], state[:, n:]  # SI
        u_now = u * self.input_std + self.input_mean
        forced = sum(v @ g.T for v, g in zip((u_prev, u_now), lure.taps))
        if lure.drift is not None:
            forced = forced + lure.drift
        x = self.block.lure_step(lure, x_prev, u_prev, u_now, forced)
        x_hat = (x - self.state_mean) / self.state_std
        if self.same:
            y = x_hat
        else:
            y = x_hat @ self.c.T + self.g
            y = y + u @ self.d.T if self.feedthrough else y
            y = y + self.block.nonlinear_output(x_hat, u) if self.curved else y
        return y, torch.cat([x, u_now], -1)


class GainStep(nn.Module):
    """A physics block without states: ŷ_k = D̂ û_k + Ĝ (at ρ_k when scheduled)."""

    size = 0

    def __init__(self, name: str, block: LTIBlock, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        self.block, self.name = block, name
        if not block.scheduled:
            with torch.no_grad():
                norm = block.normalized(dtype)
            _constant(self, "d", norm.d, dtype)
            _constant(self, "g", norm.g, dtype)

    def forward(self, u: Tensor, rho: Tensor | None, state: Tensor) -> tuple[Tensor, Tensor]:
        if rho is None:
            y = u @ self.d.T + self.g
            if self.block.model.has_nonlinear_output:  # y = D u + h(u)
                y = y + self.block.nonlinear_output(u.new_zeros(*u.shape[:-1], 0), u)
            return y, state
        norm = self.block.sample_matrices(rho[0], 0)
        return u @ norm.d.T + norm.g, state


class DelayStep(nn.Module):
    """A dead time of (whole + f) samples: y_k = (1 - f) u_{k-whole} + f u_{k-whole-1} (``DeadTime``).

    The state holds u_{k-1}, ..., u_{k-whole-1} [SI], newest first, per channel.
    """

    def __init__(self, name: str, block: DeadTime, scales: list[Scale], dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        samples = float(block.delay_s().detach()) / block.dt
        self.name, self.whole, self.frac = name, int(math.floor(samples)), samples - math.floor(samples)
        self.m = len(scales)
        _constant(self, "mean", torch.tensor([s[0] for s in scales], dtype=torch.float64), dtype)
        _constant(self, "std", torch.tensor([s[1] for s in scales], dtype=torch.float64), dtype)

    @property
    def size(self) -> int:
        return (self.whole + 1) * self.m

    def slots(self, inputs: tuple[str, ...], unit_of: dict[str, str]) -> list[StateSlot]:
        return [StateSlot(self.name, f"{u}[k-{j + 1}]", "delay", unit_of.get(u, ""))
                for j in range(self.whole + 1) for u in inputs]

    def buffer(self, u: Tensor, start: int, k: int) -> Tensor:
        """The state at sample k from u (1, T, m) normalized, starting at sample ``start`` (held before it)."""
        rows = [u[:, max(k - 1 - j - start, 0)] for j in range(self.whole + 1)]  # (1, m) each, newest first
        return torch.cat(rows, -1) * self.std.repeat(self.whole + 1) + self.mean.repeat(self.whole + 1)

    def forward(self, u: Tensor, rho: Tensor | None, state: Tensor) -> tuple[Tensor, Tensor]:
        past = ((state.view(1, self.whole + 1, self.m) - self.mean) / self.std)  # u_{k-1}, ..., u_{k-whole-1}
        newer = u if self.whole == 0 else past[:, self.whole - 1]
        older = past[:, self.whole]
        y = newer + self.frac * (older - newer)
        shifted = torch.cat([u[:, None], past[:, :-1]], 1) * self.std + self.mean
        return y, shifted.reshape(1, -1)


class SaturationStep(nn.Module):
    """A limit: static, the block's own ``forward`` on one sample."""

    size = 0

    def __init__(self, name: str, block: Saturation) -> None:
        super().__init__()
        self.name, self.limit = name, block

    def forward(self, u: Tensor, rho: Tensor | None, state: Tensor) -> tuple[Tensor, Tensor]:
        return self.limit(u[:, None])[:, 0], state


class NetworkStep(nn.Module):
    """A network, one sample: its own ``forward`` on a one-sample chunk, or its ``step`` where it has one
    (S4: real arithmetic; Transformer: a fixed-size cache), with ``step_state`` turning the state
    ``forward`` returns into the one ``step`` holds. The state flattened, its layout that of
    ``template`` (a state as ``forward`` returns it, batch of one)."""

    def __init__(self, name: str, network: SequenceBlock, template: object) -> None:
        super().__init__()
        self.name, self.network = name, network
        self.stepped = callable(getattr(network, "step", None)) and callable(getattr(network, "step_state", None))
        leaves, self.spec = pytree.tree_flatten(network.step_state(template) if self.stepped else template)
        if not all(isinstance(t, Tensor) and not t.is_complex() for t in leaves):
            raise ExportError(f"block {name!r}: the state of {type(network).__name__} is not a structure of real "
                              "tensors, and the network has no step form (step, step_state) for one")
        self.shapes = [tuple(t.shape) for t in leaves]
        self.sizes = [t.numel() for t in leaves]

    @property
    def size(self) -> int:
        return sum(self.sizes)

    def initial(self, state: object) -> Tensor:
        """The flat state (1, r) from a state as the network's ``forward`` returns it."""
        return self.flatten(self.network.step_state(state) if self.stepped else state)

    def flatten(self, state: object) -> Tensor:
        flat = [t.reshape(1, -1) for t in pytree.tree_flatten(state)[0]]
        return torch.cat(flat, -1) if flat else torch.zeros(1, 0)

    def unflatten(self, flat: Tensor) -> object:
        leaves, offset = [], 0
        for shape, size in zip(self.shapes, self.sizes):
            leaves.append(flat[:, offset : offset + size].reshape(shape))
            offset += size
        return pytree.tree_unflatten(leaves, self.spec)

    def forward(self, x: Tensor, rho: Tensor | None, state: Tensor) -> tuple[Tensor, Tensor]:
        if self.stepped:
            y, new = self.network.step(x, self.unflatten(state))
            return y, self.flatten(new)
        y, new = self.network(x[:, None], self.unflatten(state))
        return y[:, 0], self.flatten(new)
