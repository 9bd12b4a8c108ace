"""An FMU as a block of a composition: normalized signals in and out, its parameters hypa's named ones.

``FMUBlock`` maps the block's signals to the FMU's variables (by name, or by the block's ``rename``
map: FMU variable -> signal), runs the FMU (``hypa.physics.fmu.FMUSimulator``) on the data's grid
with the block's hold, and returns its outputs normalized with the block's output scale. Its
parameters are the FMU's Real parameters held in the model's ``PhysicalParameters`` (so ``parameters:``
sets them, ``trainable:`` names them, and the output-error identification fits them as a class's,
by differences of free runs). The FMU starts from the data where its states are measured outputs
(their values at the window start), else from its own initialization, said once in one line.

The FMU runs outside torch. A network after it (correcting its outputs) trains as usual; a network
feeding it (V1's shape) trains through it: the gradient to the FMU's inputs comes from its per-sample
sensitivities (forward differences of its outputs and of hypa's RK4 step over its model exchange)
and the adjoint recursion over the record. A parameter of it trained by gradient is refused in one
line: its parameters are fitted by the output-error identification.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from hypa.physics.fmu import FMUDescription, FMUError, FMUSimulator
from hypa.physics.parameters import PhysicalParameters

log = logging.getLogger(__name__)

Scale = tuple[float, float]


class FMUBlock(nn.Module):
    """One FMU in a composition.

    Args:
        name: the block's name (for messages).
        description: the FMU (``read_fmu``).
        params: the model's parameters; the FMU's are ``parameter_names`` among them.
        inputs, outputs: the block's signals, in order; ``fmu_inputs``, ``fmu_outputs``: the FMU
            variables they are (the block's ``rename`` applied).
        input_scale, output_scale: (μ, σ) of each input and output signal [SI].
        dt: the data's sample time [s]; hold: ``zoh`` or ``foh``; interface: ``auto``,
            ``model_exchange`` or ``co_simulation``.
        measured_states: per FMU state, the measured output that starts it (all or none).
    """

    def __init__(self, name: str, description: FMUDescription, params: PhysicalParameters,
                 parameter_names: Sequence[str], fmu_inputs: Sequence[str], fmu_outputs: Sequence[str],
                 input_scale: Sequence[Scale], output_scale: Sequence[Scale], dt: float, hold: str = "zoh",
                 interface: str = "auto", measured_states: Sequence[str] = ()) -> None:
        super().__init__()
        self.name, self.description, self.params = name, description, params
        self.parameter_names = tuple(parameter_names)
        self.fmu_inputs, self.fmu_outputs = tuple(fmu_inputs), tuple(fmu_outputs)
        self.dt, self.hold, self.measured_states = float(dt), hold, tuple(measured_states)
        self.interface = description.interface(interface)
        self._simulator: FMUSimulator | None = None
        self._said_start = False
        as_tensor = lambda pairs, i: torch.tensor([p[i] for p in pairs], dtype=torch.float64)  # noqa: E731
        self.register_buffer("input_mean", as_tensor(input_scale, 0), persistent=False)
        self.register_buffer("input_std", as_tensor(input_scale, 1), persistent=False)
        self.register_buffer("output_mean", as_tensor(output_scale, 0), persistent=False)
        self.register_buffer("output_std", as_tensor(output_scale, 1), persistent=False)

    @property
    def n_states(self) -> int:
        return len(self.description.states)

    @property
    def simulator(self) -> FMUSimulator:
        """The FMU's instance, created at the first run (one per block and process)."""
        if self._simulator is None:
            self._simulator = FMUSimulator(self.description, self.interface, instance=self.name)
        return self._simulator

    def __getstate__(self) -> dict:  # an instance of native code does not travel (pickling, a worker process)
        state = dict(self.__dict__)
        state["_simulator"] = None
        return state

    def close(self) -> None:
        if self._simulator is not None:
            self._simulator.close()
            self._simulator = None

    def parameter_values(self) -> dict[str, float]:
        values = self.params.as_floats()
        return {n: values[n] for n in self.parameter_names}

    def eigenvalues(self) -> Tensor:
        """The FMU's modes [1/s] at its own initial state (``FMUSimulator.modes``; empty in co-simulation)."""
        return torch.as_tensor(self.simulator.modes(self.parameter_values()), dtype=torch.complex128)

    def forward(self, u: Tensor, x0: Tensor | None = None) -> tuple[Tensor, Tensor | None]:
        """Outputs (B, T, p) normalized from inputs (B, T, m) normalized, from states x0 (B, n) [SI] or the
        FMU's own initialization; and the states it ran through (B, T, n) [SI] where the interface shows them.
        A gradient reaches the inputs (model exchange: ``FMUSimulator.sensitivities``), not the parameters."""
        if torch.is_grad_enabled() and any(self.params.raw[n].requires_grad for n in self.parameter_names):
            raise FMUError(f"block {self.name!r} is an FMU, which runs outside torch: no gradient reaches its "
                           "parameters (fit them by hypa's identification, and train the networks in a stage "
                           "without the FMU's block)")
        if torch.is_grad_enabled() and u.requires_grad:
            return _ThroughFMU.apply(u, x0, self), None
        y, runs, _ = self._run(u, x0)
        states = torch.as_tensor(np.stack([r.x for r in runs]), device=u.device) if runs[0].x is not None else None
        return y, states

    def _run(self, u: Tensor, x0: Tensor | None) -> tuple[Tensor, list, np.ndarray]:
        """The normalized outputs, each batch element's run, and the inputs [SI] (B, T, m)."""
        if x0 is None and not self._said_start:
            states = self.description.state_names
            why = f"its states {', '.join(states)} are not all measured" if states else "it declares no states"
            log.info("block %r: the FMU (%s) starts from its own initialization: %s", self.name,
                     self.interface.replace("_", " "), why)
            self._said_start = True
        parameters = self.parameter_values()
        si = (u.detach().double() * self.input_std + self.input_mean).cpu().numpy()
        ys, runs = [], []
        for b in range(si.shape[0]):
            start = None if x0 is None else x0[b].detach().double().cpu().numpy()
            run = self.simulator.run(parameters, self.fmu_inputs, si[b], 0.0, self.dt, start, self.hold,
                                     read=self.fmu_outputs)
            if x0 is not None and not run.started_from_data and not self._said_start:
                log.info("block %r: the FMU does not let hypa set its states; it starts from its own "
                         "initialization", self.name)
                self._said_start = True
            ys.append(self._outputs(run.y))
            runs.append(run)
        y = torch.as_tensor(np.stack(ys), dtype=torch.float64, device=u.device)
        return ((y - self.output_mean) / self.output_std).to(u.dtype), runs, si

    def input_gradient(self, y_bar: Tensor, runs: list, si: np.ndarray) -> Tensor:
        """dL/du (B, T, m) normalized from dL/dy (B, T, p) normalized, by the adjoint over each run."""
        names = self.description.output_names
        index = [names.index(n) for n in self.fmu_outputs]
        scale_out = (1.0 / self.output_std).cpu().numpy()
        grads = []
        for b, run in enumerate(runs):
            sensitivity = self.simulator.sensitivities(self.fmu_inputs, si[b], run, 0.0, self.dt, self.hold)
            full = np.zeros((si.shape[1], len(names)))
            full[:, index] = y_bar[b].detach().double().cpu().numpy() * scale_out
            grads.append(sensitivity.input_gradient(full) * self.input_std.cpu().numpy())
        return torch.as_tensor(np.stack(grads), dtype=y_bar.dtype, device=y_bar.device)

    def _outputs(self, y: np.ndarray) -> np.ndarray:
        names = self.description.output_names
        return y[:, [names.index(n) for n in self.fmu_outputs]]

    def extra_repr(self) -> str:
        return (f"{self.description.path.name}, {self.interface}, {len(self.fmu_inputs)} inputs, "
                f"{len(self.fmu_outputs)} outputs, {self.n_states} states")


class _ThroughFMU(torch.autograd.Function):
    """The FMU's run with the gradient to its inputs by the adjoint of its per-sample sensitivities."""

    @staticmethod
    def forward(ctx, u: Tensor, x0: Tensor | None, block: FMUBlock) -> Tensor:
        y, runs, si = block._run(u, x0)
        ctx.block, ctx.runs, ctx.si = block, runs, si
        return y

    @staticmethod
    def backward(ctx, y_bar: Tensor) -> tuple[Tensor, None, None]:
        return ctx.block.input_gradient(y_bar, ctx.runs, ctx.si).to(y_bar.dtype), None, None


def fmu_variables(rename: Mapping[str, str], signals: Sequence[str]) -> tuple[str, ...]:
    """The FMU variable each signal is (``rename``: FMU variable -> signal; a signal it does not name is the
    variable of its own name)."""
    variable = {signal: fmu for fmu, signal in rename.items()}
    return tuple(variable.get(s, s) for s in signals)


def resignaled(rename: Mapping[str, str], moves: Mapping[str, str]) -> dict[str, str]:
    """``rename`` with each signal of ``moves`` (old signal -> new signal) replaced, its FMU variable kept: a
    block's input fed by a new signal, an output written under a new name."""
    return {**rename, **dict(zip(fmu_variables(rename, list(moves)), moves.values()))}


def fmu_signals(description: FMUDescription, rename: Mapping[str, str], inputs: Sequence[str],
                outputs: Sequence[str], where: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The FMU variables the block's ``inputs`` and ``outputs`` are (``rename``: FMU variable -> signal)."""
    unknown = sorted(set(rename) - {*description.input_names, *description.output_names, *description.state_names})
    if unknown:
        raise FMUError(f"{where}: rename names {unknown}, which are not the FMU's inputs, outputs or states")
    fmu_in, fmu_out = fmu_variables(rename, inputs), fmu_variables(rename, outputs)
    missing_in = [s for s, v in zip(inputs, fmu_in) if v not in description.input_names]
    missing_out = [s for s, v in zip(outputs, fmu_out) if v not in description.output_names]
    if missing_in or missing_out:
        raise FMUError(f"{where}: {missing_in + missing_out} are not among the FMU's inputs "
                       f"{list(description.input_names)} and outputs {list(description.output_names)}; "
                       "give rename: {<FMU variable>: <signal>} where the names differ")
    return fmu_in, fmu_out
