"""Added modes: any system given a first-order mode it lacks, driven by one of its inputs.

A physics block's ``modes: [input, ...]`` wraps its system (:class:`Moded`): for each input v
named (by the system's own input names) a state m follows v through a first-order lag and adds
into every output through a weight each,

    τ ṁ = v - m,        y_o += w_o k_o m,

with the block's own parameters ``mode_<v>_tau_s`` τ [s] and ``mode_<v>_on_<output>`` w_o
(dimensionless, fitted; 0: the model as it was), and the fixed ``mode_<v>_scale_on_<output>`` k_o
(the output's unit per v's: the size of a w of 1, set from the signals' sizes by whoever adds the
mode). A battery's second RC pair (v the current, y the terminal voltage), a sensor's lag, a slow
thermal mass the model lumps away. The mode's state is one of the block's states (``mode_<v>``):
it starts where the measured outputs over the past put it, with the block's own states
(``initial_state: estimate``; at w = 0, at its operating point), not in equilibrium with the
input's first sample (a slow mode's state carries the input's history). Linear where the wrapped
system is; the generic catalogue's ``missing_mode`` (``hypa/diagnosis/catalogue.yaml``) fits τ
and the weights for any system.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from hypa.physics.dependent import DependentError
from hypa.physics.elements import local_name
from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, StateSpace


def mode_state(signal: str) -> str:
    """The name of the state of the mode driven by ``signal``."""
    return f"mode_{signal}"


def mode_names(signal: str, outputs: Sequence[str]) -> tuple[str, list[str], list[str]]:
    """The local names of a mode's time constant, its weights on ``outputs`` and their fixed sizes."""
    return (f"mode_{signal}_tau_s", [f"mode_{signal}_on_{o}" for o in outputs],
            [f"mode_{signal}_scale_on_{o}" for o in outputs])


class Moded(LTIModel):
    """``base`` with a first-order mode per input of ``modes`` added into its outputs (module docstring)."""

    key = "modes"

    def __init__(self, base: LTIModel, modes: Sequence[str], block: str = "") -> None:
        inputs = list(base.input_names)
        unknown = [v for v in modes if v not in inputs]
        if unknown or len(set(modes)) != len(modes):
            raise DependentError(f"modes: {', '.join(map(repr, unknown or modes))} is not an input of "
                                 f"{base.display_name} (inputs: {', '.join(inputs) or 'none'}), or named twice")
        self.base, self.modes = base, tuple(modes)
        self.input_names, self.output_names = base.input_names, base.output_names
        self.state_names = (*base.state_names, *(mode_state(v) for v in self.modes))
        self._modes = []
        own = []
        for v in self.modes:
            tau, weights, scales = mode_names(v, base.output_names)
            tau, weights, scales = (local_name(block, tau), [local_name(block, w) for w in weights],
                                    [local_name(block, k) for k in scales])
            self._modes.append((inputs.index(v), tau, weights, scales))
            own += [ParameterSpec(tau, 1.0, "s"), *(ParameterSpec(w, 0.0, "-", positive=False) for w in weights),
                    *(ParameterSpec(k, 1.0, "") for k in scales)]
        self.parameters = (*base.parameters, *own)
        self.added = frozenset(getattr(base, "added", frozenset())) | {s.name for s in own}

    @property
    def display_name(self) -> str:
        return f"{self.base.display_name} ({self.key} of {', '.join(self.modes)})"

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        ss = self.base.matrices(p)
        n, k = ss.a.shape[0], len(self._modes)
        rates = torch.stack([1.0 / p[tau] for _, tau, _, _ in self._modes]).to(ss.a.dtype)  # (k,)
        a = torch.cat([torch.cat([ss.a, ss.a.new_zeros(n, k)], 1),
                       torch.cat([ss.a.new_zeros(k, n), torch.diag(-rates)], 1)], 0)
        drive = ss.b.new_zeros(k, ss.b.shape[1])
        for i, (j, _, _, _) in enumerate(self._modes):
            drive[i, j] = 1.0
        b = torch.cat([ss.b, drive * rates[:, None]], 0)
        weights = torch.stack([torch.stack([p[w] * p[s] for w, s in zip(ws, ks)]) for _, _, ws, ks in self._modes], 1)
        c = torch.cat([ss.c, weights.to(ss.c.dtype)], 1)
        e = None if ss.e is None else torch.cat([ss.e, ss.e.new_zeros(k)])
        return StateSpace(a, b, c, ss.d, e)

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor | None:
        f = self.base.feedback(p)
        return None if f is None else torch.cat([f, f.new_zeros(len(self._modes), f.shape[1])], 0)

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        return self.base.prepare(p)

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        return self.base.nonlinearity(x[..., : len(self.base.state_names)], u, p)

    @property
    def is_nonlinear(self) -> bool:
        return self.base.is_nonlinear
