"""Named physical parameters θ of a physics block: frozen or trainable (grey-box)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import torch
from torch import Tensor, nn

LOG, SIGNED, BOUNDED = 0, 1, 2  # how a parameter is stored: log, relative, scaled sigmoid


@dataclass(frozen=True)
class ParameterSpec:
    """One named physical parameter: nominal ``value`` [``unit``] and how it may move.

    A parameter is stored as an unconstrained raw number θ̃ that an optimizer moves freely:

    - ``bounds=(lo, hi)``: θ = lo + (hi - lo) σ(θ̃), so a learned value never leaves the
      interval however large the step (lo < value < hi; a physically known range).
    - ``positive`` (mass, stiffness, inertia, ...): θ = exp(θ̃), never through zero, and a step
      is relative to the value's scale (a cornering stiffness of 1.5e5 N/rad and a length of
      1.4 m learn at the same pace).
    - otherwise signed (a rear/front steering ratio, an offset force): θ = |θ₀| θ̃ with θ₀ the
      nominal value (1 when it is 0), so a step is relative for them too.

    ``bounds`` take precedence; a positive parameter's bounds must then lie in [0, ∞).

    ``value`` may be given with a unit (``"2.5 Ah"``, ``{"value": 2.5, "unit": "Ah"}``, pint's
    spellings): it is converted to ``unit`` (``C``), the unit the parameter is stored, fitted and
    reported in; a value of another kind is refused in one line (``hypa.core.units.value_in``).
    """

    name: str
    value: float
    unit: str = ""
    positive: bool = True
    bounds: tuple[float, float] | None = None
    trainable: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"a parameter name must be a non-empty string, got {self.name!r}")
        if type(self.value) is not float:  # a unit to convert (or an int, a numpy scalar)
            from hypa.core.units import value_in

            object.__setattr__(self, "value", value_in(self.value, self.unit, self.name))
        if not math.isfinite(self.value):
            raise ValueError(f"parameter {self.name!r} must be finite, got {self.value}")
        if self.bounds is not None:
            try:
                lo, hi = (float(b) for b in self.bounds)
            except (TypeError, ValueError):
                raise ValueError(f"parameter {self.name!r}: bounds must be (lo, hi), got {self.bounds!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"parameter {self.name!r}: bounds must be finite with lo < hi, got {self.bounds!r}")
            if self.positive and lo < 0:
                raise ValueError(f"parameter {self.name!r} [{self.unit}] is positive but its bounds {self.bounds!r} "
                                 "reach below 0: give positive=False or a lower bound >= 0")
            if not lo < self.value < hi:
                raise ValueError(f"parameter {self.name!r} [{self.unit}] = {self.value} must lie strictly inside "
                                 f"its bounds ({lo}, {hi})")
            object.__setattr__(self, "bounds", (lo, hi))
        elif self.positive and not self.value > 0:
            raise ValueError(f"parameter {self.name!r} [{self.unit}] must be positive, got {self.value}")

    @property
    def storage(self) -> int:
        """``BOUNDED``, ``LOG`` or ``SIGNED``: how the raw value maps to the physical one."""
        return BOUNDED if self.bounds is not None else LOG if self.positive else SIGNED

    def check(self, value: float) -> None:
        """Raise ``ValueError`` unless ``value`` is admissible for this parameter."""
        if not math.isfinite(value):
            raise ValueError(f"parameter {self.name!r} must be finite, got {value}")
        if self.bounds is not None and not self.bounds[0] < value < self.bounds[1]:
            raise ValueError(f"parameter {self.name!r} = {value} must lie strictly inside its bounds {self.bounds}")
        if self.bounds is None and self.positive and not value > 0:
            raise ValueError(f"parameter {self.name!r} must be positive, got {value}")


class PhysicalParameters(nn.Module):
    """A set of named physical parameters; ``params()`` returns their physical values.

    Every parameter is an ``nn.Parameter`` (the raw value θ̃ of ``ParameterSpec``) whose
    ``requires_grad`` says whether it is trained, so freezing and unfreezing is one call and
    optimizers see only the trainable ones.
    """

    def __init__(self, specs: Iterable[ParameterSpec], dtype: torch.dtype = torch.float64) -> None:
        super().__init__()
        self.specs: dict[str, ParameterSpec] = {}
        self.raw = nn.ParameterDict()
        self._scale: dict[str, float] = {}  # signed parameters: raw = value / |nominal value|
        self._maps: dict[tuple, tuple[Tensor, ...] | None] = {}  # vectorized maps by (names, device, dtype)
        for spec in specs:
            if not isinstance(spec, ParameterSpec):
                raise TypeError(f"expected a ParameterSpec, got {type(spec).__name__}: {spec!r}")
            if spec.name in self.specs:
                raise ValueError(f"parameter {spec.name!r} given twice")
            self.specs[spec.name] = spec
            self._scale[spec.name] = (abs(spec.value) or 1.0) if spec.storage == SIGNED else 1.0
            self.raw[spec.name] = nn.Parameter(
                torch.tensor(self._raw(spec, spec.value), dtype=dtype), requires_grad=spec.trainable
            )

    def _raw(self, spec: ParameterSpec, value: float) -> float:
        """The raw value θ̃ that stores the physical ``value`` (the inverse of ``value``)."""
        if spec.storage == BOUNDED:
            lo, hi = spec.bounds
            s = (value - lo) / (hi - lo)
            return math.log(s) - math.log1p(-s)  # logit
        return math.log(value) if spec.storage == LOG else value / self._scale[spec.name]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.specs)

    def value(self, name: str) -> Tensor:
        """Physical value of one parameter (differentiable w.r.t. its raw parameter)."""
        if name not in self.specs:
            raise KeyError(f"unknown parameter {name!r}; known: {', '.join(self.specs)}")
        raw, spec = self.raw[name], self.specs[name]
        if spec.storage == BOUNDED:
            lo, hi = spec.bounds
            return lo * torch.sigmoid(-raw) + hi * torch.sigmoid(raw)  # saturates at lo, hi exactly
        return raw.exp() if spec.storage == LOG else raw * self._scale[name]

    def params(self) -> dict[str, Tensor]:
        """All physical values by name."""
        return {name: self.value(name) for name in self.specs}

    def values(self, names: tuple[str, ...], dtype: torch.dtype | None = None) -> dict[str, Tensor]:
        """Physical values of ``names`` in ``dtype``, computed in one vectorized pass.

        Same values as ``value(name)``; a handful of tensor ops instead of a few per parameter
        matters when the physics is rebuilt every training step. Frozen values come back
        without a graph, so the backward pass computes no gradients only to drop them.
        """
        unknown = [n for n in names if n not in self.specs]
        if unknown:
            raise KeyError(f"unknown parameters {unknown}; known: {', '.join(self.specs)}")
        trainable = tuple(n for n in names if self.raw[n].requires_grad) if torch.is_grad_enabled() else ()
        with torch.no_grad():
            values = self._physical(names, dtype)
        if trainable:  # taped separately: no gradients computed for frozen values only to be dropped
            values.update(self._physical(trainable, dtype))
        return values

    def _physical(self, names: tuple[str, ...], dtype: torch.dtype | None) -> dict[str, Tensor]:
        raw = torch.stack([self.raw[n] for n in names])
        key = (names, raw.device, raw.dtype)
        if key not in self._maps:  # the specs never change: build each set of maps once (None: all log)
            self._maps[key] = self._build_maps(names, raw)
        maps = self._maps[key]
        if maps is None:
            physical = raw.exp()
        else:
            log, bounded, scale, lo, hi = maps
            # exp only where stored in log: a bounded raw value may be large, and exp(inf) in the
            # unselected branch of where would turn its zero gradient into NaN
            positive = torch.where(log, raw, torch.zeros_like(raw)).exp()
            physical = torch.where(log, positive, raw * scale)
            if bounded is not None:
                physical = torch.where(bounded, lo * torch.sigmoid(-raw) + hi * torch.sigmoid(raw), physical)
        return dict(zip(names, (physical if dtype is None else physical.to(dtype)).unbind()))

    def _build_maps(self, names: tuple[str, ...], raw: Tensor) -> tuple[Tensor, ...] | None:
        """Masks and constants of the vectorized map raw -> physical for ``names``."""
        kinds = [self.specs[n].storage for n in names]
        if all(k == LOG for k in kinds):
            return None
        t = lambda v: torch.tensor(v, dtype=raw.dtype, device=raw.device)  # noqa: E731
        bounds = [self.specs[n].bounds or (0.0, 1.0) for n in names]
        bounded = torch.tensor([k == BOUNDED for k in kinds], device=raw.device) if BOUNDED in kinds else None
        return (torch.tensor([k == LOG for k in kinds], device=raw.device), bounded,
                t([self._scale[n] for n in names]), t([b[0] for b in bounds]), t([b[1] for b in bounds]))

    def as_floats(self) -> dict[str, float]:
        return {name: float(v.detach()) for name, v in self.params().items()}

    def set_trainable(self, names: Iterable[str] | None = None, trainable: bool = True) -> None:
        """Make the named parameters (all when ``names`` is None) trainable or frozen."""
        for name in self.specs if names is None else names:
            if name not in self.specs:
                raise KeyError(f"unknown parameter {name!r}; known: {', '.join(self.specs)}")
            self.raw[name].requires_grad_(trainable)

    @property
    def trainable_names(self) -> tuple[str, ...]:
        return tuple(n for n in self.specs if self.raw[n].requires_grad)

    @torch.no_grad()
    def set_values(self, values: Mapping[str, float]) -> None:
        """Overwrite physical values in place (e.g. after a fit); each must satisfy its spec."""
        for name, value in values.items():
            spec = self.specs.get(name)
            if spec is None:
                raise KeyError(f"unknown parameter {name!r}; known: {', '.join(self.specs)}")
            spec.check(float(value))
            self.raw[name].fill_(self._raw(spec, float(value)))

    def extra_repr(self) -> str:
        parts = []
        for name, value in self.as_floats().items():
            flag = "*" if self.raw[name].requires_grad else ""
            parts.append(f"{name}{flag}={value:.6g}")
        return ", ".join(parts) + ("  (* trainable)" if self.trainable_names else "")
