"""Dependent parameters: any system's parameter made to depend on a direction or on a state.

A physics block's ``depends: {parameter: {by: signal, kind: direction | state | cubic}}`` wraps its
system (:class:`Dependent`): the parameter p takes, at every sample, the value

    p (1 + d tanh(s / w))            (direction: a friction by the direction of motion, a
                                      resistance that differs in charge and discharge)
    p (1 + a (s - μ) / σ)            (state: a resistance rising at a low state of charge)
    p (1 + a z + b z² + c z³),       (cubic: a force that varies over a stroke, bent at its
       z = (s - μ) / σ                ends; the state kind's a, and b, c)

where s is a state of the system or one of its inputs (by the system's own names), w a width
over which the sign is smoothed and μ, σ the signal's operating point and spread (fixed: they set
the scale of a, b and c). Where the model does not give them, the block's scaling of the signal
sets them (the data's mean and standard deviation for a measured one; w a tenth of that spread:
``SignalScaled``). ``d = 0`` / ``a = 0`` (and ``b = c = 0``) is the model as it was.

The parameter enters the user's ``matrices(p)`` in any way, so the wrapper evaluates them at
p0 and p0 ± h (h = p0 √(d² + ε²), ε = 10⁻³: the modification's full size, ``d``, ``a`` or √(a² + b² + c²)) once
per simulation and adds to dx/dt the quadratic through the three points,

    δ S [x; u; 1] + ½ δ² K [x; u; 1],    δ = p(s) - p0,
    S = (M(p0 + h) - M(p0 - h)) / 2h,    K = (M(p0 + h) - 2 M(p0) + M(p0 - h)) / h²,

with M = [A B e]. That is exact for a parameter that enters A, B and e affinely or
quadratically (a friction coefficient over a mass, a mass in a numerator) whatever s, and for
any dependence where the modification is at its full size (tanh(s / w) = ±1: away from zero
speed; the state one spread from its operating point); elsewhere it is second-order accurate
in δ. The wrapped system is nonlinear (Lur'e form, ``hypa.physics.simulation``): F is the
identity, its signal the sum above. Where the parameter also enters C or D (an accelerometer
reads -c v / m: the damping c that differs by the direction of motion), the outputs take the
same quadratic in [C D] [x; u] as a nonlinear output h(x, u) (``output_nonlinearity``): the
measured acceleration moves with the damping the dynamics use.

The new parameters are the block's own (``<block>/...``): ``<p>_direction_<s>`` d and
``<p>_direction_<s>_width`` w (in s's unit), or ``<p>_slope_<s>`` a, ``<p>_slope_<s>_level`` μ and
``<p>_slope_<s>_spread`` σ, and for the cubic ``<p>_square_<s>`` b and ``<p>_cube_<s>`` c. The
generic catalogue's ``direction_parameter`` and ``state_parameter`` entries
(``hypa/diagnosis/catalogue.yaml``) fit d and a for the uncertain parameters of any system.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.elements import local_name
from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, SignalScaled, StateSpace

KINDS = ("direction", "state", "cubic")
EPSILON = 1e-3  # the smallest relative step h / p0 of the three evaluations (where d or a is 0)


class DependentError(ValueError):
    """A ``depends`` mapping that does not fit the system (a parameter or signal it lacks, a kind unknown)."""


def dependence_names(parameter: str, on: str, kind: str) -> tuple[str, ...]:
    """The local names of a dependence's own parameters: the fitted weight first, then the fixed ones
    (the cubic's: the state kind's three, then its fitted b and c)."""
    if kind == "direction":
        return f"{parameter}_direction_{on}", f"{parameter}_direction_{on}_width"
    names = f"{parameter}_slope_{on}", f"{parameter}_slope_{on}_level", f"{parameter}_slope_{on}_spread"
    return (*names, f"{parameter}_square_{on}", f"{parameter}_cube_{on}") if kind == "cubic" else names


class Dependent(LTIModel):
    """``base`` with the parameters of ``depends`` (parameter -> {by, kind}) varying per sample (module docstring)."""

    key = "depends"

    def __init__(self, base: LTIModel, depends: Mapping[str, Mapping[str, str]], block: str = "") -> None:
        states, inputs = list(base.state_names), list(base.input_names)
        names = set(base.parameter_names)
        self.base, self.depends = base, {k: dict(v) for k, v in depends.items()}
        self.state_names, self.input_names, self.output_names = base.state_names, base.input_names, base.output_names
        self._terms = []
        own = []
        for parameter, how in self.depends.items():
            qualified = local_name(block, parameter) if local_name(block, parameter) in names else parameter
            if qualified not in names:
                raise DependentError(f"depends: {base.display_name} has no parameter {parameter!r}; its parameters: "
                                     f"{', '.join(n.split('/', 1)[-1] for n in base.parameter_names) or 'none'}")
            kind, on = how.get("kind"), how.get("by")
            if kind not in KINDS:
                raise DependentError(f"depends: the kind of {parameter!r} must be {' or '.join(KINDS)}, got {kind!r}")
            if on in states:
                source = ("x", states.index(on))
            elif on in inputs:
                source = ("u", inputs.index(on))
            else:
                raise DependentError(f"depends: {parameter!r} depends on {on!r}, which is neither a state nor an "
                                     f"input of {base.display_name} (states: {', '.join(states) or 'none'}; inputs: "
                                     f"{', '.join(inputs) or 'none'})")
            local = [local_name(block, n) for n in dependence_names(parameter, on, kind)]
            self._terms.append((qualified, kind, source, local))
            own.append(ParameterSpec(local[0], 0.0, "-", positive=False))
            if kind == "direction":
                own.append(ParameterSpec(local[1], 1.0, ""))
            else:
                own += [ParameterSpec(local[1], 0.0, "", positive=False), ParameterSpec(local[2], 1.0, "")]
                own += [ParameterSpec(name, 0.0, "-", positive=False) for name in local[3:]]
        self.parameters = (*base.parameters, *own)
        self.added = frozenset(getattr(base, "added", frozenset())) | {s.name for s in own}
        nominal = {spec.name: torch.tensor(spec.value, dtype=torch.float64) for spec in base.parameters}
        self._in_outputs = any(not torch.equal(self._outputs(nominal), self._outputs(
            {**nominal, q: nominal[q] + 1e-2 * max(abs(float(nominal[q])), 1.0)})) for q, *_ in self._terms)

    @property
    def display_name(self) -> str:
        return f"{self.base.display_name} ({self.key} on {', '.join(self.depends)})"

    def signal_scaled(self) -> tuple[SignalScaled, ...]:
        own = tuple(SignalScaled(source, width=local[1]) if kind == "direction" else
                    SignalScaled(source, level=local[1], spread=local[2]) for _, kind, source, local in self._terms)
        return (*own, *super().signal_scaled())

    def _outputs(self, p: Mapping[str, Tensor]) -> Tensor:
        """[C D] (p, n + m) of the wrapped system at ``p``."""
        ss = self.base.matrices(p)
        return torch.cat([ss.c, ss.d.to(ss.c.dtype)], 1)

    @property
    def has_nonlinear_output(self) -> bool:
        """Whether a dependent parameter enters C or D (or the wrapped system measures through an h)."""
        return self._in_outputs or self.base.has_nonlinear_output

    def output_nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        """δ S_y [x; u] + ½ δ² K_y [x; u] (the module docstring's quadratic, of [C D]), plus the wrapped
        system's h where it has one."""
        u = u.to(x.dtype)
        own = x.new_zeros((*x.shape[:-1], len(self.output_names)))
        if self._in_outputs:
            middle, xu = self._outputs(p), torch.cat([x, u], -1)
            for qualified, kind, (where, j), local in self._terms:
                p0 = p[qualified]
                h = p0 * _size(p, local)
                up, down = self._outputs({**p, qualified: p0 + h}), self._outputs({**p, qualified: p0 - h})
                slope, curvature = (up - down) / (2 * h), (up - 2 * middle + down) / (h * h)
                signal = (x if where == "x" else u)[..., j]
                delta = (p0 * _shape(kind, signal, *(p[n] for n in local)))[..., None]
                own = own + delta * (xu @ slope.T.to(x.dtype) + 0.5 * delta * (xu @ curvature.T.to(x.dtype)))
        return own + self.base.output_nonlinearity(x, u, p) if self.base.has_nonlinear_output else own

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        return self.base.matrices(p)

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        n = len(self.state_names)
        one = next(iter(p.values()))
        own = torch.eye(n, dtype=one.dtype, device=one.device)
        return torch.cat([self.base.feedback(p), own], 1) if self.base.is_nonlinear else own

    def _stacked(self, p: Mapping[str, Tensor]) -> Tensor:
        """M = [A B e] (n, n + m + 1) of the wrapped system at ``p``."""
        ss = self.base.matrices(p)
        e = ss.e if ss.e is not None else ss.a.new_zeros(ss.a.shape[0])
        return torch.cat([ss.a, ss.b, e.reshape(-1, 1).to(ss.a.dtype)], 1)

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        prepared = dict(self.base.prepare(p)) if self.base.is_nonlinear else dict(p)
        terms = []
        middle = self._stacked(p)
        for qualified, kind, source, local in self._terms:
            p0 = p[qualified]
            h = p0 * _size(p, local)
            up, down = self._stacked({**p, qualified: p0 + h}), self._stacked({**p, qualified: p0 - h})
            slope, curvature = (up - down) / (2 * h), (up - 2 * middle + down) / (h * h)
            # S and ½K side by side, split by what they multiply (x, u, 1): one product each per step
            both = torch.cat([slope, 0.5 * curvature], 0).T  # (n + m + 1, 2n)
            n = slope.shape[0]
            terms.append((kind, source, p0, [p[name] for name in local], both[:n], both[n:-1], both[-1]))
        prepared["_depends"] = terms
        return prepared

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        # δ S [x; u; 1] + ½ δ² K [x; u; 1] = δ (a + δ b), [a b] = x S_x' + u S_u' + s_1 (the module docstring)
        u, n, own = u.to(x.dtype), x.shape[-1], None
        for kind, (where, j), p0, own_values, on_x, on_u, constant in p["_depends"]:
            s = (x if where == "x" else u)[..., j]
            delta = (p0 * _shape(kind, s, *own_values))[..., None]
            if x.dim() == 2:
                both = torch.addmm(torch.addmm(constant, x, on_x), u, on_u)
            else:
                both = x @ on_x + u @ on_u + constant
            term = delta * (both[..., :n] + delta * both[..., n:])
            own = term if own is None else own + term
        own = x.new_zeros(x.shape) if own is None else own
        return torch.cat([self.base.nonlinearity(x, u, p), own], -1) if self.base.is_nonlinear else own


def _size(p: Mapping[str, Tensor], local: list[str]) -> Tensor:
    """The relative step h / p0 of the three evaluations: the dependence's full size (module docstring)."""
    weights = [p[local[0]], *(p[name] for name in local[3:])]  # d or a (and the cubic's b, c)
    return torch.sqrt(sum(w * w for w in weights) + EPSILON**2)


def _shape(kind: str, s: Tensor, weight: Tensor, scale_or_level: Tensor, spread: Tensor | None = None,
           square: Tensor | None = None, cube: Tensor | None = None) -> Tensor:
    """The relative change of the parameter at the signal's values ``s``: d tanh(s / w), a z, or
    a z + b z² + c z³ with z = (s - μ) / σ (the module docstring; the arguments in ``dependence_names`` order)."""
    if kind == "direction":
        return weight * torch.tanh(s / scale_or_level)
    z = (s - scale_or_level) / spread
    if kind == "state":
        return weight * z
    return z * (weight + z * (square + z * cube))


class Driven(LTIModel):
    """``base`` driven by more inputs: each signal of ``driven`` enters every state derivative,

        dx_r/dt += w_r k_r v,

    with ``drive_<v>_on_<state>`` w_r (dimensionless, fitted, 0: the model as it was) and
    ``drive_<v>_scale_on_<state>`` k_r [state unit / s per unit of v] (fixed: the size of a w of 1,
    set from the state's spread, the model's rate and the signal's size by whoever adds it). A
    measured channel the model did not read (a race car's roll angle on a banked oval: gravity's
    lateral component) enters the physics where it acts, one number per state; the outputs are the
    wrapped system's. The block reads the new signals after its own inputs. Linear where the
    wrapped system is (the generic catalogue's ``unread_channel``, ``hypa/diagnosis/catalogue.yaml``).
    """

    key = "driven"

    def __init__(self, base: LTIModel, driven: tuple[str, ...] | list[str], block: str = "") -> None:
        clash = [v for v in driven if v in base.input_names]
        if clash or len(set(driven)) != len(driven):
            raise DependentError(f"driven: {', '.join(map(repr, clash or driven))} is an input of "
                                 f"{base.display_name} already, or named twice")
        self.base, self.driven = base, tuple(driven)
        self.state_names, self.output_names = base.state_names, base.output_names
        self.input_names = (*base.input_names, *self.driven)
        self._columns = [([local_name(block, drive_name(v, s)) for s in base.state_names],
                          [local_name(block, drive_scale_name(v, s)) for s in base.state_names]) for v in self.driven]
        own = [ParameterSpec(w, 0.0, "-", positive=False) for weights, _ in self._columns for w in weights]
        own += [ParameterSpec(k, 1.0, "") for _, scales in self._columns for k in scales]
        self.parameters = (*base.parameters, *own)
        self.added = frozenset(getattr(base, "added", frozenset())) | {s.name for s in own}

    @property
    def display_name(self) -> str:
        return f"{self.base.display_name} ({self.key} by {', '.join(self.driven)})"

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        ss = self.base.matrices(p)
        columns = [torch.stack([p[w] * p[k] for w, k in zip(weights, scales)]).to(ss.b.dtype).reshape(-1, 1)
                   for weights, scales in self._columns]
        d = torch.cat([ss.d, ss.d.new_zeros(ss.d.shape[0], len(columns))], 1)
        return StateSpace(ss.a, torch.cat([ss.b, *columns], 1), ss.c, d, ss.e)

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor | None:
        return self.base.feedback(p)

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        return self.base.prepare(p)

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        return self.base.nonlinearity(x, u[..., : len(self.base.input_names)], p)

    @property
    def is_nonlinear(self) -> bool:
        return self.base.is_nonlinear


def drive_name(signal: str, state: str) -> str:
    """The local name of the weight w of ``signal`` in ``state``'s derivative (:class:`Driven`)."""
    return f"drive_{signal}_on_{state}"


def drive_scale_name(signal: str, state: str) -> str:
    """The local name of the fixed size k of that weight (:class:`Driven`)."""
    return f"drive_{signal}_scale_on_{state}"
