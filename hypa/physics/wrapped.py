"""A system wrapped with feedback of its own states: the common part of ``curved`` and ``limited``.

:class:`StateFeedback` keeps the wrapped system's signals, parameters and linear part and appends
its own Lur'e feedback columns (``feedback``, ``prepare``, ``nonlinearity``) to the wrapped
system's (``hypa.physics.curved``: couplings that bend with a state; ``hypa.physics.limited``: a
state held at a limit). A subclass says which states it takes (``key: {state: option}``, checked
here), adds its parameters (:meth:`add`) and gives its own columns (``own_*``).
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, StateSpace


class StateFeedback(LTIModel):
    """``base`` with feedback columns of its own on the states of ``options`` (state -> option)."""

    key = ""  # the block key, in messages and the display name
    error: type[ValueError] = ValueError  # raised for a state the system lacks, an option not allowed

    def __init__(self, base: LTIModel, options: Mapping[str, Any], allowed: Sequence[Any], what: str) -> None:
        states = list(base.state_names)
        for state, option in options.items():
            if state not in states:
                raise self.error(f"{self.key}: {base.display_name} has no state {state!r}; its states: "
                                 f"{', '.join(states) or 'none'}")
            if isinstance(option, bool) or option not in allowed:
                raise self.error(f"{self.key}: the {what} of {state!r} must be {' or '.join(map(str, allowed))}, "
                                 f"got {option!r}")
        self.base, self.options = base, dict(options)
        self.state_names, self.input_names, self.output_names = base.state_names, base.input_names, base.output_names
        self.parameters = base.parameters
        self.added = frozenset(getattr(base, "added", frozenset()))  # the parameters wrappers add (not the physics')

    def add(self, specs: Sequence[ParameterSpec]) -> None:
        """The wrapper's own parameters, after the wrapped system's."""
        self.parameters = (*self.parameters, *specs)
        self.added = self.added | {spec.name for spec in specs}

    @property
    def display_name(self) -> str:
        return f"{self.base.display_name} ({self.key} on {', '.join(self.options)})"

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        return self.base.matrices(p)

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        own = self.own_feedback(p)  # (n, own columns)
        return torch.cat([self.base.feedback(p), own], 1) if self.base.is_nonlinear else own

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        prepared = dict(self.base.prepare(p)) if self.base.is_nonlinear else dict(p)
        prepared[f"_{self.key}"] = self.own_prepare(p)
        return prepared

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        own = torch.stack(self.own_signals(x, p[f"_{self.key}"]), -1)
        return torch.cat([self.base.nonlinearity(x, u, p), own], -1) if self.base.is_nonlinear else own

    @abstractmethod
    def own_feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        """The wrapper's columns of F (n, own columns)."""

    @abstractmethod
    def own_prepare(self, p: Mapping[str, Tensor]) -> Any:
        """What ``own_signals`` reads, from the parameters only (once per simulation)."""

    @abstractmethod
    def own_signals(self, x: Tensor, prepared: Any) -> list[Tensor]:
        """The wrapper's feedback signals, each (...,), from the states (..., n) in physical units."""
