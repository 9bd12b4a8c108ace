"""Curved couplings: any system's linear couplings from a state made to bend with that state.

A physics block's ``curved: {state: power}`` (power 2, 3 or ``root``) wraps its system
(:class:`Curved`): every coupling A_rj from the state x_j into a state derivative ẋ_r becomes

    A_rj (x_j + w_r (x_j - μ_j) z^(p-1)),   z = (x_j - μ_j) / σ_j,

so that at one spread σ_j from the operating point μ_j the coupling is (1 + w_r) times the
linear one. Power 3 is a symmetric stiffening (w > 0) or softening (w < 0), as a hardening
spring's or a saturating conductance's; power 2 an asymmetric one, as a quadratic drag about a
speed. At x_j = μ_j the term and its slope are zero: the model is its linear self near the
operating point, and ``w = 0`` is the model as it was.

``root`` is the law of a flow through an orifice (Torricelli's √h) for a state that stays
positive (a level, a pressure): every coupling from it becomes

    A_rj (x_j + w (√(μ_j x_j) - x_j)),

with one weight ``curve_<state>`` w for all rows (the flow that leaves one tank is the flow that
fills the next: the same law on both ends), the linear one at ``w = 0`` and A_rj √(μ_j x_j), the
root through the same flow at the level μ_j, at ``w = 1`` (x_j is taken as at least 1e-6 μ_j: the
root's slope stays finite at an empty tank).

The new parameters are the block's own (``<block>/...``): ``<state>_level`` μ_j and
``<state>_spread`` σ_j in the state's unit (fixed: they set the scale of w, not the physics; where
the model does not give them, the block's scaling of the state: ``SignalScaled``), and
one dimensionless ``curve_<state>_on_<row>`` w_r per state r (a row where A_rj is 0 has nothing
to bend: its w does nothing). The generic catalogue's ``cubic_state`` and ``square_state`` entries
(``hypa/diagnosis/catalogue.yaml``) fit them for any system the catalogue knows nothing
specific about. The wrapped system is nonlinear and is simulated like any other (Lur'e form,
``hypa.physics.simulation``): the feedback F's column for x_j is A_{:j} ⊙ w, its signal
(x_j - μ_j) z^(p-1).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.elements import local_name
from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, SignalScaled
from hypa.physics.wrapped import StateFeedback

ROOT = "root"  # the orifice's law, √(μ x)
POWERS = (2, 3, ROOT)


def curve_name(state: str, row: str | None = None) -> str:
    """The local name of the weight w of the coupling from ``state`` into ``row``'s derivative (None:
    of every coupling from it, a root's one weight)."""
    return f"curve_{state}" if row is None else f"curve_{state}_on_{row}"


class CurvedError(ValueError):
    """A ``curved`` mapping that does not fit the system (a state it lacks, a power not 2, 3 or root)."""


class Curved(StateFeedback):
    """``base`` with the couplings from the states of ``curved`` (state -> power) bent (module docstring)."""

    key, error = "curved", CurvedError

    def __init__(self, base: LTIModel, curved: Mapping[str, int | str], block: str = "") -> None:
        super().__init__(base, curved, POWERS, "power")
        self.curved = self.options
        states = list(base.state_names)
        self._columns = [(states.index(s), p, local_name(block, f"{s}_level"), local_name(block, f"{s}_spread"),
                          [local_name(block, curve_name(s))] if p == ROOT else
                          [local_name(block, curve_name(s, r)) for r in states]) for s, p in curved.items()]
        own = []
        for _, _, level, spread, weights in self._columns:
            own += [ParameterSpec(level, 0.0, "", positive=False), ParameterSpec(spread, 1.0, "")]
            own += [ParameterSpec(w, 0.0, "-", positive=False) for w in weights]
        self.add(own)

    def signal_scaled(self) -> tuple[SignalScaled, ...]:
        own = tuple(SignalScaled(("x", j), level=level, spread=spread) for j, _, level, spread, _ in self._columns)
        return (*own, *super().signal_scaled())

    def own_feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        a = self.base.matrices(p).a
        return torch.stack([a[:, j] * torch.stack([p[w] for w in weights]) for j, _, _, _, weights in self._columns], 1)

    def own_prepare(self, p: Mapping[str, Tensor]) -> list[tuple[Tensor, Tensor]]:
        return [(p[level], 1.0 / p[spread]) for _, _, level, spread, _ in self._columns]

    def own_signals(self, x: Tensor, prepared: list[tuple[Tensor, Tensor]]) -> list[Tensor]:
        signals = []
        for (j, power, *_), (level, inverse) in zip(self._columns, prepared):
            if power == ROOT:
                h = x[..., j].clamp_min(1e-6 * level)
                signals.append(torch.sqrt(level * h) - x[..., j])
                continue
            d = x[..., j] - level
            z = d * inverse
            signals.append(d * z if power == 2 else d * z * z)
        return signals
