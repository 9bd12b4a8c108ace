"""Named physical parameters θ of a physics block: frozen or trainable (grey-box)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass(frozen=True)
class ParameterSpec:
    """One named physical parameter.

    ``positive`` parameters (mass, stiffness, inertia, ...) are stored as their logarithm, so
    an optimizer can never push them through zero and a step is relative to the value's scale
    (a cornering stiffness of 1.5e5 N/rad and a length of 1.4 m learn at the same pace).
    Signed parameters (a rear/front steering ratio) are stored divided by the magnitude of
    their nominal value, so an optimizer step is relative for them too.
    """

    name: str
    value: float
    unit: str = ""
    positive: bool = True
    trainable: bool = False

    def __post_init__(self) -> None:
        if not math.isfinite(self.value):
            raise ValueError(f"parameter {self.name!r} must be finite, got {self.value}")
        if self.positive and not self.value > 0:
            raise ValueError(f"parameter {self.name!r} [{self.unit}] must be positive, got {self.value}")


class PhysicalParameters(nn.Module):
    """A set of named physical parameters; ``params()`` returns their physical values.

    Every parameter is an ``nn.Parameter`` whose ``requires_grad`` says whether it is trained,
    so freezing and unfreezing is one call and optimizers see only the trainable ones.
    """

    def __init__(self, specs: Iterable[ParameterSpec], dtype: torch.dtype = torch.float64) -> None:
        super().__init__()
        self.specs: dict[str, ParameterSpec] = {}
        self.raw = nn.ParameterDict()
        self._scale: dict[str, float] = {}  # signed parameters: raw = value / |nominal value|
        self._positive: dict[tuple, tuple[Tensor, Tensor] | None] = {}  # (positive mask, signed scale) by names, device
        for spec in specs:
            if spec.name in self.specs:
                raise ValueError(f"parameter {spec.name!r} given twice")
            self.specs[spec.name] = spec
            self._scale[spec.name] = 1.0 if spec.positive else (abs(spec.value) or 1.0)
            raw = math.log(spec.value) if spec.positive else spec.value / self._scale[spec.name]
            self.raw[spec.name] = nn.Parameter(
                torch.tensor(raw, dtype=dtype), requires_grad=spec.trainable
            )

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.specs)

    def value(self, name: str) -> Tensor:
        """Physical value of one parameter (differentiable w.r.t. its raw parameter)."""
        if name not in self.specs:
            raise KeyError(f"unknown parameter {name!r}; known: {', '.join(self.specs)}")
        raw = self.raw[name]
        return raw.exp() if self.specs[name].positive else raw * self._scale[name]

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
        key = (names, raw.device)
        if key not in self._positive:  # the specs never change: build each mask once (None: all positive)
            mask = [self.specs[n].positive for n in names]
            scale = torch.tensor([self._scale[n] for n in names], dtype=raw.dtype, device=raw.device)
            self._positive[key] = None if all(mask) else (torch.tensor(mask, device=raw.device), scale)
        signed = self._positive[key]
        physical = raw.exp() if signed is None else torch.where(signed[0], raw.exp(), raw * signed[1])
        return dict(zip(names, (physical if dtype is None else physical.to(dtype)).unbind()))

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
        """Overwrite physical values in place (e.g. after a fit)."""
        for name, value in values.items():
            spec = self.specs.get(name)
            if spec is None:
                raise KeyError(f"unknown parameter {name!r}; known: {', '.join(self.specs)}")
            if spec.positive and not value > 0:
                raise ValueError(f"parameter {name!r} must be positive, got {value}")
            self.raw[name].fill_(math.log(value) if spec.positive else value / self._scale[name])

    def extra_repr(self) -> str:
        parts = []
        for name, value in self.as_floats().items():
            flag = "*" if self.raw[name].requires_grad else ""
            parts.append(f"{name}{flag}={value:.6g}")
        return ", ".join(parts) + ("  (* trainable)" if self.trainable_names else "")
