"""Limited states: any system's state made unable to pass a level (an overflow, an end stop).

A physics block's ``limited: {state: upper | lower}`` wraps its system (:class:`Limited`): what
would carry the state x_j past its limit L_j leaves it at a rate of the excess over a time τ_j,

    ẋ_j  -= e / τ_j,        ẋ_r += v_r e / τ_j  (every other state r),
    e = s softplus((x_j - L_j) / s)   (upper),      e = -s softplus((L_j - x_j) / s)   (lower),

so that the state settles at its limit within about τ_j (a sample time: what flows in beyond it
spills) and a share v_r > 0 of the spill reaches the state r (an upper tank overflowing into the
lower one: v = 1 where the tanks have the same cross-section, near 0 where it is lost). The width s
rounds the corner so that a fit sees the limit from both sides; well inside the limit e is
about 0 and the system is its old self.

The new parameters are the block's own (``<block>/...``): ``<state>_limit`` L_j in the state's
unit (fitted), ``<state>_limit_time`` τ_j [s] and ``<state>_limit_width`` s (fixed: how fast and
how sharply the state stops, set from the sample time and the state's spread by whoever adds the
limit), and one ``spill_<state>_to_<row>`` v_r per other state (fitted; positive, stored in log
scale like every positive parameter, 0.5 unless given: what spills adds to the other state, never
drains it; a share free to change sign went negative where an overflow is rarely reached, and the
fit missed the limit). The generic catalogue's ``upper_state_limit`` and ``lower_state_limit`` entries
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
from hypa.physics.statespace import LTIModel
from hypa.physics.wrapped import StateFeedback

SIDES = ("upper", "lower")
UNREACHED = 15.0  # corner widths inside its limit: the state never reaches it (softplus(-15) = 3e-7)


def spill_name(state: str, row: str) -> str:
    """The local name of the share v of ``state``'s spill that reaches ``row``."""
    return f"spill_{state}_to_{row}"


class LimitedError(ValueError):
    """A ``limited`` mapping that does not fit the system (a state it lacks, a side not upper/lower)."""


class Limited(StateFeedback):
    """``base`` with the states of ``limited`` (state -> upper | lower) held at a limit (module docstring)."""

    key, error = "limited", LimitedError

    def __init__(self, base: LTIModel, limited: Mapping[str, str], block: str = "") -> None:
        super().__init__(base, limited, SIDES, "side")
        self.limited = self.options
        states = list(base.state_names)
        self._columns = []
        own = []
        for state, side in limited.items():
            names = [local_name(block, f"{state}_{key}") for key in ("limit", "limit_time", "limit_width")]
            spills = {states.index(r): local_name(block, spill_name(state, r)) for r in states if r != state}
            self._columns.append((states.index(state), 1.0 if side == "upper" else -1.0, *names, spills))
            own += [ParameterSpec(names[0], 0.0, "", positive=False), ParameterSpec(names[1], 1.0, "s"),
                    ParameterSpec(names[2], 1.0, "")]
            own += [ParameterSpec(w, 0.5, "-") for w in spills.values()]  # positive: a spill adds to the other state
        self.add(own)

    def own_feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        n, columns = len(self.state_names), []
        for j, _, _, time, _, spills in self._columns:
            one = p[time].new_ones(())
            columns.append(torch.stack([-one if r == j else p[spills[r]] for r in range(n)]) / p[time])
        return torch.stack(columns, 1)

    def unreached(self, reach: Mapping[str, tuple[float, float]], values: Mapping[str, float]) -> dict[str, float]:
        """A limit its state stays more than ``UNREACHED`` corner widths inside of over the run (its
        spill and gradient under e^-15 of the width: 0 to a fit), restarted at the state's extreme,
        where it spills (the wrapped system's too)."""
        out = super().unreached(reach, values)
        for j, sign, limit, _, width, _ in self._columns:
            state = self.state_names[j]
            if state not in reach:
                continue
            extreme = reach[state][1] if sign > 0 else reach[state][0]
            if sign * (values[limit] - extreme) > UNREACHED * abs(values[width]):
                out[limit] = extreme
        return out

    def own_prepare(self, p: Mapping[str, Tensor]) -> list[tuple[Tensor, Tensor]]:
        return [(p[limit], p[width]) for _, _, limit, _, width, _ in self._columns]

    def own_signals(self, x: Tensor, prepared: list[tuple[Tensor, Tensor]]) -> list[Tensor]:
        return [sign * width * torch.nn.functional.softplus(sign * (x[..., j] - limit) / width)
                for (j, sign, *_), (limit, width) in zip(self._columns, prepared)]
