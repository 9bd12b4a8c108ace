"""The system contract: the continuous state space a system's ``matrices`` returns, and ``LTIModel``.

The lowest layer of ``hypa.physics``: what a built-in or a user's system is, with nothing of
how it is simulated (``lti.LTIBlock``, ``simulation``, ``scheduled``), so every engine module
can import it without a circle.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass

from torch import Tensor

from hypa.physics.parameters import ParameterSpec


@dataclass(frozen=True)
class StateSpace:
    """Continuous dx/dt = A x + B u + e, y = C x + D u (physical units).

    ``e`` is a constant drift (an offset force, gravity): zero when None.
    """

    a: Tensor  # (n, n)
    b: Tensor  # (n, m)
    c: Tensor  # (p, n)
    d: Tensor  # (p, m)
    e: Tensor | None = None  # (n,)


@dataclass(frozen=True)
class SignalScaled:
    """Fixed parameters of a wrapper (``depends``, ``curved``) that set the scale of its fitted
    weights by a signal's size: ``level`` and ``spread`` its operating point and spread, ``width`` a
    tenth of that spread (a sign smoothed over it), each a parameter name or None. ``source``:
    ("x" | "u", index), the system's state or input. Where the model does not give them, the block's
    scaling of that signal (the data's) sets them (``hypa.models.building``)."""

    source: tuple[str, int]
    level: str | None = None
    spread: str | None = None
    width: str | None = None


class LTIModel(ABC):
    """A physical system: the contract a built-in or a user's system follows.

    Class (or instance) attributes name the signals and parameters; ``matrices`` maps scalar
    parameter values to the continuous state space dx/dt = A x + B u + e, y = C x + D u (the
    hold turns it into eq. 1)::

        class Oscillator(LTIModel):
            state_names = ("position", "velocity")          # x (n,)
            input_names = ("force",)                        # u (m,)
            output_names = ("position",)                    # y (p,) the measured outputs
            parameters = (ParameterSpec("mass", 2.0, "kg"), ParameterSpec("stiffness", 50.0, "N/m"))

            def matrices(self, p):                          # p: name -> scalar tensor
                ...
                return StateSpace(a, b, c, d)               # (n, n), (n, m), (p, n), (p, m)

    ``matrices`` is written for scalar values and must be differentiable in them (torch ops
    only); a scheduled parameter is handled by the engine, not by the system: it evaluates
    ``matrices`` at every sample with ``torch.func.vmap``, or with one plain call where the code
    is also batch-safe (every entry computed elementwise and the matrices built with
    ``torch.stack``, no ``reshape`` or matmul of entries; checked once against vmap, see
    ``hypa.physics.scheduled.batch_layout``), several times faster.
    ``hypa.physics.systems.check_system`` says what a class gets wrong.

    **Nonlinear physics** (Lur'e form): a system that also defines ``feedback`` and
    ``nonlinearity`` is dx/dt = A x + B u + e + F w with w = φ(x, u), a static nonlinearity
    fed back into the linear part (a saturating tire force, a stiffening spring, Coulomb
    friction), where ``matrices`` is the linear part (the system for small signals). It is
    simulated step by step (the linear part exact under the hold, w linear over each sample by a
    predictor-corrector: second order in dt) rather than lifted, and its initial-state estimate
    and equilibrium are the linear part's.

    **Nonlinear outputs**: a system that also defines ``output_nonlinearity(x, u, p)`` measures
    y = C x + D u + h(x, u) (a battery's terminal voltage OCV(SOC) − v₁ − R₀ I, a sensor's
    curve), h (..., p) added to the linear output. Its states are simulated as they would be
    without it (lifted where the dynamics are linear) and h is applied to them; its initial-state
    estimate is refined by Gauss-Newton on the nonlinear output. A wrapper that keeps the system
    it wraps as ``base`` (``hypa.physics.wrapped``) measures through the wrapped system's h.
    """

    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    parameters: tuple[ParameterSpec, ...] = ()  # nominal values, units, positivity / bounds
    output_reads_inputs: bool = True  # h(x, u) reads its own sample's inputs (a feedthrough); False: h(x) only

    @abstractmethod
    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        """Continuous A, B, C, D (and optionally e) from physical parameter values (differentiable)."""

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor | None:
        """F (n, r): how the nonlinearity's outputs w enter dx/dt; None for a linear system."""
        return None

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        """What ``nonlinearity`` reads: ``p``, plus anything that depends on the parameters only
        (computed once per simulation instead of at every sample); default: ``p`` itself."""
        return p

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        """w = φ(x, u) (..., r) from states (..., n) and inputs (..., m) in physical units;
        ``p``: what ``prepare`` returned."""
        raise NotImplementedError(f"{type(self).__name__} defines feedback but no nonlinearity")

    def output_nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        """h(x, u) (..., p) added to y = C x + D u, from states (..., n) and inputs (..., m) in physical
        units; ``p``: the parameter values by name (scalar tensors). Torch ops only, elementwise in
        the leading dims (differentiable). Not defined: y is linear (a wrapper's: its ``base``'s h)."""
        base = getattr(self, "base", None)
        if isinstance(base, LTIModel) and base.has_nonlinear_output:
            return base.output_nonlinearity(x, u, p)
        raise NotImplementedError(f"{type(self).__name__} has no output_nonlinearity")

    @property
    def nonlinear_output_reads_inputs(self) -> bool:
        """Whether h reads the inputs of its own sample (``output_reads_inputs`` of the system that defines
        h; a wrapper without an h of its own: its ``base``'s). An h(x) adds no feedthrough."""
        base = getattr(self, "base", None)
        if type(self).output_nonlinearity is LTIModel.output_nonlinearity and isinstance(base, LTIModel):
            return base.nonlinear_output_reads_inputs
        return self.output_reads_inputs

    def signal_scaled(self) -> tuple[SignalScaled, ...]:
        """The parameters a signal's scale sets (:class:`SignalScaled`), this wrapper's and its
        ``base``'s; none for a plain system."""
        base = getattr(self, "base", None)
        return base.signal_scaled() if isinstance(base, LTIModel) else ()

    def unreached(self, reach: Mapping[str, tuple[float, float]], values: Mapping[str, float]) -> dict[str, float]:
        """Parameters whose effect the states never meet over a run (``reach``: state -> its lowest and
        highest value in the state's unit; ``values``: the parameters'), each with a value where it
        would act: a limit the state never reaches has no gradient, so no fit brings it back
        (``hypa.physics.limited``). This wrapper's and its ``base``'s; none for a plain system."""
        base = getattr(self, "base", None)
        return base.unreached(reach, values) if isinstance(base, LTIModel) else {}

    @property
    def has_nonlinear_output(self) -> bool:
        """Whether the outputs have a nonlinear part h (``output_nonlinearity`` overridden, or a wrapped
        system's ``base`` has one)."""
        if type(self).output_nonlinearity is not LTIModel.output_nonlinearity:
            return True
        base = getattr(self, "base", None)
        return isinstance(base, LTIModel) and base.has_nonlinear_output

    @property
    def display_name(self) -> str:
        """The system's name in messages: its class name (a wrapper, ``Curved``, names what it wraps)."""
        return type(self).__name__

    @property
    def is_nonlinear(self) -> bool:
        """Whether the system has a nonlinear feedback (``feedback`` overridden)."""
        return type(self).feedback is not LTIModel.feedback

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the parameters ``matrices`` reads (those of ``parameters``)."""
        return tuple(spec.name for spec in self.parameters)

    def parameter_specs(self, values: Mapping[str, float]) -> list[ParameterSpec]:
        """The specs of ``parameters``, valued from ``values`` where given (nominal otherwise).

        Unit, positivity and bounds stay the system's own: a configuration sets values only, each
        a number in the spec's unit or a number with a unit (``"2.5 Ah"``), converted to it.
        """
        return [dataclasses.replace(spec, value=values.get(spec.name, spec.value)) for spec in self.parameters]

    def nominal_values(self) -> dict[str, float]:
        """Nominal value of every parameter by name."""
        return {spec.name: spec.value for spec in self.parameters}

    @property
    def n_states(self) -> int:
        return len(self.state_names)

    @property
    def outputs_are_states(self) -> bool:
        """True when y = x (C = I, D = 0): outputs share the states' names and scaling."""
        return self.n_states > 0 and self.output_names == self.state_names
