"""Limited states: any system's state made unable to pass a level (an overflow, an end stop).

A physics block's ``limited: {state: upper | lower}`` wraps its system (:class:`Limited`): what
would carry the state x_j past its limit L_j leaves it at a rate of the excess over a time τ_j,

    ẋ_j  -= e / τ_j,        ẋ_r += v_r e / τ_j  (every other state r),
    e = s softplus((x_j - L_j) / s)   (upper),      e = -s softplus((L_j - x_j) / s)   (lower),

so that the state settles at its limit within about τ_j (a sample time: what flows in beyond it
spills) and a share v_r of the spill reaches the state r (an upper tank overflowing into the
lower one: v = 1 where the tanks have the same cross-section, 0 where it is lost). The width s
rounds the corner so that a fit sees the limit from both sides; well inside the limit e is
about 0 and the system is its old self.

The new parameters are the block's own (``<block>/...``): ``<state>_limit`` L_j in the state's
unit (fitted), ``<state>_limit_time`` τ_j [s] and ``<state>_limit_width`` s (fixed: how fast and
how sharply the state stops, set from the sample time and the state's spread by whoever adds the
limit), and one ``spill_<state>_to_<row>`` v_r per other state (fitted; 0 is a spill that is
lost). The generic catalogue's ``upper_state_limit`` and ``lower_state_limit`` entries
(``hypa/diagnosis/catalogue.yaml``) fit them for any system the catalogue knows nothing
specific about. The wrapped system is nonlinear and simulated like any other (Lur'e form,
``hypa.physics.simulation``): the feedback F's column for x_j is (v - e_j) / τ_j with v_j = 0.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.elements import local_name
from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, StateSpace

SIDES = ("upper", "lower")


def spill_name(state: str, row: str) -> str:
    """The local name of the share v of ``state``'s spill that reaches ``row``."""
    return f"spill_{state}_to_{row}"


class LimitedError(ValueError):
    """A ``limited`` mapping that does not fit the system (a state it lacks, a side not upper/lower)."""


class Limited(LTIModel):
    """``base`` with the states of ``limited`` (state -> upper | lower) held at a limit (module docstring)."""

    def __init__(self, base: LTIModel, limited: Mapping[str, str], block: str = "") -> None:
        states = list(base.state_names)
        for state, side in limited.items():
            if state not in states:
                raise LimitedError(f"limited: {base.display_name} has no state {state!r}; its states: "
                                   f"{', '.join(states) or 'none'}")
            if side not in SIDES:
                raise LimitedError(f"limited: the side of {state!r} must be upper or lower, got {side!r}")
        self.base, self.limited = base, dict(limited)
        self.state_names, self.input_names, self.output_names = base.state_names, base.input_names, base.output_names
        self._columns = []
        own = []
        for state, side in limited.items():
            names = [local_name(block, f"{state}_{key}") for key in ("limit", "limit_time", "limit_width")]
            spills = {states.index(r): local_name(block, spill_name(state, r)) for r in states if r != state}
            self._columns.append((states.index(state), 1.0 if side == "upper" else -1.0, *names, spills))
            own += [ParameterSpec(names[0], 0.0, "", positive=False), ParameterSpec(names[1], 1.0, "s"),
                    ParameterSpec(names[2], 1.0, "")]
            own += [ParameterSpec(w, 0.0, "-", positive=False) for w in spills.values()]
        self.parameters = (*base.parameters, *own)
        self.added = frozenset(spec.name for spec in own) | getattr(base, "added", frozenset())

    @property
    def display_name(self) -> str:
        return f"{self.base.display_name} (limited on {', '.join(self.limited)})"

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        return self.base.matrices(p)

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        n = len(self.state_names)
        columns = []
        for j, _, _, time, _, spills in self._columns:
            one = p[time].new_ones(())
            entries = [-one if r == j else p[spills[r]] for r in range(n)]
            columns.append(torch.stack(entries) / p[time])
        own = torch.stack(columns, 1)  # (n, limited states)
        return torch.cat([self.base.feedback(p), own], 1) if self.base.is_nonlinear else own

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        prepared = dict(self.base.prepare(p)) if self.base.is_nonlinear else dict(p)
        prepared["_limited"] = [(p[limit], p[width]) for _, _, limit, _, width, _ in self._columns]
        return prepared

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        signals = []
        for (j, sign, *_), (limit, width) in zip(self._columns, p["_limited"]):
            signals.append(sign * width * torch.nn.functional.softplus(sign * (x[..., j] - limit) / width))
        own = torch.stack(signals, -1)
        return torch.cat([self.base.nonlinearity(x, u, p), own], -1) if self.base.is_nonlinear else own
