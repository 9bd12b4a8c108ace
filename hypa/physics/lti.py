"""A generic LTI physics block: named parameters θ -> A(θ), B(θ) -> hold -> eq. 5-8 -> eq. 9-11.

``LTIModel`` says what a physical system is (signal names, parameters, continuous matrices);
``LTIBlock`` turns it into a differentiable, normalized, lifted simulator in plain PyTorch.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from hypa.physics.discretization import HOLDS, DiscreteLTI, Hold, discretize
from hypa.physics.lifted import LiftedMatrices, lifted_from_rows, simulate_from_rows, simulate_lifted
from hypa.physics.normalized import NormalizedLTI, NormalizingMaps, Scaling
from hypa.physics.parameters import ParameterSpec, PhysicalParameters


_SCALING = ("state_mean", "state_std", "input_mean", "input_std", "output_mean", "output_std")


class UnstablePhysicsError(ValueError):
    """The configured physical parameters give an unstable (or non-finite) model."""


@dataclass(frozen=True)
class StateSpace:
    """Continuous dx/dt = A x + B u, y = C x + D u (physical units)."""

    a: Tensor  # (n, n)
    b: Tensor  # (n, m)
    c: Tensor  # (p, n)
    d: Tensor  # (p, m)


class LTIModel(ABC):
    """A physical system: names of its signals and parameters and its continuous matrices."""

    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    parameter_names: tuple[str, ...]

    @abstractmethod
    def parameter_specs(self, values: Mapping[str, float]) -> list[ParameterSpec]:
        """Specs (units, constraints) of the parameters this model reads, valued from ``values``."""

    @abstractmethod
    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        """Continuous A, B, C, D from physical parameter values (differentiable)."""

    @property
    def n_states(self) -> int:
        return len(self.state_names)

    @property
    def outputs_are_states(self) -> bool:
        """True when y = x (C = I, D = 0): outputs share the states' names and scaling."""
        return self.n_states > 0 and self.output_names == self.state_names


class LTIBlock(nn.Module):
    """Normalized, lifted LTI simulator with physical parameters (frozen or trainable).

    Inputs and outputs are normalized (eq. 2). A block's output at window step j is the one
    produced by consuming input u_{k+j}: ŷ_j = Ĉ x̂_{k+j+1} + D̂ û_{k+j} + Ĝ, so for the
    single-track model (C = I, D = 0) output j is the state x̂_{k+j+1}, and for a pure gain
    (no states) it is D̂ û_{k+j}. Sequences of any length are simulated free-running by
    chaining horizon-long lifted windows through their last state (exact, see ``forward``).
    """

    def __init__(
        self,
        model: LTIModel,
        parameters: PhysicalParameters,
        dt: float,
        horizon: int = 100,
        hold: Hold = "zoh",
        scaling: Scaling | None = None,
    ) -> None:
        super().__init__()
        if hold not in HOLDS:
            raise ValueError(f"unknown hold {hold!r}; choose one of {', '.join(HOLDS)}")
        if not dt > 0:
            raise ValueError(f"sample time dt must be positive, got {dt}")
        if horizon < 1:
            raise ValueError(f"horizon must be at least 1, got {horizon}")
        missing = set(model.parameter_names) - set(parameters.names)
        if missing:
            raise ValueError(f"{type(model).__name__} needs parameters {sorted(missing)}")
        self.model, self.parameters_, self.dt, self.horizon, self.hold = model, parameters, dt, horizon, hold
        n, m, p = model.n_states, len(model.input_names), len(model.output_names)
        scaling = scaling or Scaling.identity(n, m, p)
        if model.outputs_are_states:
            scaling = dataclasses.replace(scaling, output_mean=scaling.state_mean, output_std=scaling.state_std)
        for name in _SCALING:
            self.register_buffer(name, getattr(scaling, name).detach().to(torch.float64).clone())
        self._cache: tuple[tuple, LiftedMatrices, NormalizedLTI] | None = None
        self._maps: tuple[tuple, NormalizingMaps] | None = None

    # -- the physics, step by step -------------------------------------------------------
    @property
    def n_taps(self) -> int:
        return 1 if self.hold == "zoh" else 2

    @property
    def scaling(self) -> Scaling:
        return Scaling(self.state_mean, self.state_std, self.input_mean, self.input_std,
                       self.output_mean, self.output_std)

    def set_scaling(self, scaling: Scaling) -> None:
        """Set μ, σ of states, inputs and outputs (physical units), e.g. from training data."""
        scaling.validate()
        if self.model.outputs_are_states:
            scaling = dataclasses.replace(scaling, output_mean=scaling.state_mean, output_std=scaling.state_std)
        for name in _SCALING:
            getattr(self, name).copy_(getattr(scaling, name).detach().to(torch.float64))

    def state_space(self, dtype: torch.dtype = torch.float64) -> StateSpace:
        """Continuous matrices from the current parameter values, in ``dtype``."""
        return self.model.matrices(self.parameters_.values(self.model.parameter_names, dtype))

    def discrete(self, dtype: torch.dtype = torch.float64) -> DiscreteLTI:
        ss = self.state_space(dtype)
        return discretize(ss.a, ss.b, self.dt, self.hold)

    def normalized(self, dtype: torch.dtype = torch.float64) -> NormalizedLTI:
        """Â, B̂_t, Ĥ (eq. 6-8) and Ĉ, D̂, Ĝ, in ``dtype``."""
        return self._normalized(dtype)[1]

    def _normalized(self, dtype: torch.dtype) -> tuple[Tensor, NormalizedLTI]:
        """[Â, B̂_0, ..., Ĥ] as one (n, n + T m + 1) tensor (what the lifting reads) and its parts.

        Normalizing before the hold (``NormalizingMaps``) makes eq. 6-8 part of the one matrix
        exponential instead of a dozen taped ops after it: fewer graph nodes per training step.
        """
        ss = self.state_space(dtype)
        maps = self._normalizing_maps(dtype, ss.a.device)
        rows, out = maps.state_rows(ss.a, ss.b), maps.output_rows(ss.c, ss.d)
        n, m = ss.b.shape
        taps = tuple(rows[:, n + t * m : n + (t + 1) * m] for t in range(self.n_taps))
        norm = NormalizedLTI(a=rows[:, :n], b_taps=taps, h=rows[:, -1], c=out[:, :n], d=out[:, n:-1], g=out[:, -1])
        return rows, norm

    def _normalizing_maps(self, dtype: torch.dtype, device: torch.device) -> NormalizingMaps:
        """The scaling's constant maps in ``dtype``, rebuilt only when the scaling changes."""
        buffers = [getattr(self, name) for name in _SCALING]
        key = (dtype, device, *((id(t), t._version) for t in buffers))
        if self._maps is None or self._maps[0] != key:
            scaling = Scaling(*(t.to(device) for t in buffers))
            self._maps = (key, NormalizingMaps.build(scaling, self.dt, self.n_taps, dtype))
        return self._maps[1]

    def check_stable(self) -> None:
        """Raise ``UnstablePhysicsError`` unless every eigenvalue of A has a negative real part."""
        with torch.no_grad():
            a = self.state_space(torch.float64).a
            if a.numel() == 0:
                return
            if not bool(torch.isfinite(a).all()):
                raise UnstablePhysicsError(f"{type(self.model).__name__}: A is not finite: {a.tolist()}")
            eig = torch.linalg.eigvals(a)
        if float(eig.real.max()) >= 0:
            raise UnstablePhysicsError(
                f"{type(self.model).__name__} is unstable with parameters "
                f"{self.parameters_.as_floats()}: eigenvalues of A are "
                f"{[complex(round(e.real, 4), round(e.imag, 4)) for e in eig.tolist()]} "
                "(a real part >= 0). Check the nominal parameters (e.g. cf*lf vs cr*lr at this velocity)."
            )

    # -- lifted matrices, rebuilt only when something they depend on changed -----------------
    # Both run on every forward: they read the parameter dict's underlying ``_parameters`` (a
    # plain dict, which also sees parameters swapped in by torch.func.functional_call) because
    # going through ParameterDict's accessors costs more than the frozen window's matmul.
    def _cache_key(self, dtype: torch.dtype, device: torch.device) -> tuple:
        buffers = self._buffers
        tensors = (*self.parameters_.raw._parameters.values(), *(buffers[n] for n in _SCALING))
        return (dtype, device, *((id(t), t._version) for t in tensors))

    def _rebuilds(self) -> bool:
        """Whether the physics must be rebuilt on every call so that gradients reach θ."""
        return torch.is_grad_enabled() and any(p.requires_grad for p in self.parameters_.raw._parameters.values())

    def lifted(self, dtype: torch.dtype = torch.float32) -> tuple[LiftedMatrices, NormalizedLTI]:
        """𝒜, ℬ, ℋ (eq. 11) and Â, B̂, Ĥ, Ĉ, D̂, Ĝ, built in ``dtype``.

        With trainable parameters and gradients on they are rebuilt every call so gradients
        reach θ; otherwise they are cached until a parameter or the scaling changes.
        """
        return self._lifted(dtype, self._rebuilds())

    def _lifted(self, dtype: torch.dtype, rebuild: bool) -> tuple[LiftedMatrices, NormalizedLTI]:
        key = None if rebuild else self._cache_key(dtype, self.state_mean.device)
        if key is not None and self._cache is not None and self._cache[0] == key:
            return self._cache[1], self._cache[2]
        rows, norm = self._normalized(dtype)
        lifted = lifted_from_rows(rows, self.n_taps, self.horizon)
        if key is not None:
            self._cache = (key, lifted, norm)
        return lifted, norm

    # -- simulation ---------------------------------------------------------------------
    def forward(self, x0: Tensor | None, u: Tensor) -> Tensor:
        """Normalized outputs ŷ (B, S, p) from initial state x̂_k (B, n) and inputs û (B, S+T-1, m).

        S = horizon is one lifted product; any other S is simulated free-running in horizon-long
        chunks chained through their last state, all chunks' input responses in one product.
        """
        states, norm = self._simulate(x0, u)
        if self.model.outputs_are_states:
            return states
        y = u[:, : states.shape[1]] @ norm.d.T + norm.g
        return y + states @ norm.c.T if self.model.n_states else y

    def steady_state(self, u0: Tensor) -> Tensor:
        """Normalized equilibrium x̂ (B, n) for the constant normalized input û0 (B, m).

        0 = A x + B u gives x = -A⁻¹ B u in physical units (the same for either hold, which is
        exact for a constant input); a block started there needs no measured initial state.
        """
        ss = self.state_space(u0.dtype)
        u_phys = u0 * self.input_std.to(u0.dtype) + self.input_mean.to(u0.dtype)
        x = -torch.linalg.solve(ss.a, (u_phys @ ss.b.T).T).T  # (B, n)
        return (x - self.state_mean.to(u0.dtype)) / self.state_std.to(u0.dtype)

    def states(self, x0: Tensor | None, u: Tensor) -> Tensor:
        """Normalized states x̂_{k+1..k+S} (B, S, n); see ``forward``."""
        return self._simulate(x0, u)[0]

    def _simulate(self, x0: Tensor | None, u: Tensor) -> tuple[Tensor, NormalizedLTI]:
        """States and the normalized system; one window of trainable physics is one graph node."""
        rebuild = self._rebuilds()
        if rebuild and x0 is not None and x0.shape[-1] and u.shape[1] - self.n_taps + 1 == self.horizon:
            rows, norm = self._normalized(u.dtype)
            return simulate_from_rows(rows, self.n_taps, x0, u), norm
        lifted, norm = self._lifted(u.dtype, rebuild)
        return self._states(lifted, x0, u), norm

    def _states(self, lifted: LiftedMatrices, x0: Tensor | None, u: Tensor) -> Tensor:
        batch, n = u.shape[0], self.model.n_states
        if x0 is None:
            if n:
                raise ValueError(f"{type(self.model).__name__} has {n} states: give an initial state")
            x0 = u.new_zeros(batch, 0)
        steps = u.shape[1] - self.n_taps + 1
        if steps == self.horizon:
            return simulate_lifted(lifted, x0, u)
        if steps < 1:
            raise ValueError(f"need at least {self.n_taps} input samples, got {u.shape[1]}")
        chunks = math.ceil(steps / self.horizon)
        pad = chunks * self.horizon + self.n_taps - 1 - u.shape[1]
        u_pad = torch.cat([u, u.new_zeros(batch, pad, u.shape[2])], dim=1)
        windows = u_pad.unfold(1, lifted.input_length, self.horizon)  # (B, C, m, N+T-1)
        windows = windows.transpose(2, 3).reshape(batch, chunks, -1)
        forced = (windows @ lifted.b.T + lifted.h).view(batch, chunks, self.horizon, n)
        if n:
            a_n = lifted.a[-n:]  # Â^N
            starts, x = [], x0
            for c in range(chunks):
                starts.append(x)
                x = x @ a_n.T + forced[:, c, -1]
            free = (torch.stack(starts, 1) @ lifted.a.T).view(batch, chunks, self.horizon, n)
            forced = forced + free
        return forced.reshape(batch, chunks * self.horizon, n)[:, :steps]

    def simulate_physical(self, x0: Tensor | None, u: Tensor) -> Tensor:
        """``forward`` in physical units: normalize, simulate, de-normalize (x0 (B, n), u (B, L, m))."""
        dtype = u.dtype
        x0n = None if x0 is None else (x0 - self.state_mean.to(dtype)) / self.state_std.to(dtype)
        un = (u - self.input_mean.to(dtype)) / self.input_std.to(dtype)
        return self(x0n, un) * self.output_std.to(dtype) + self.output_mean.to(dtype)

    def extra_repr(self) -> str:
        m = self.model
        return (f"{type(m).__name__}: {list(m.input_names)} -> {list(m.output_names)}, "
                f"dt={self.dt:g} s, horizon={self.horizon}, hold={self.hold}")
