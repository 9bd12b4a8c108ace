"""A generic LTI physics block: named parameters θ -> A(θ), B(θ) -> hold -> eq. 5-8 -> eq. 9-11.

``LTIModel`` (``statespace``, re-exported here) says what a physical system is (signal names,
parameters, continuous matrices); ``LTIBlock`` turns it into a differentiable, normalized,
lifted simulator in plain PyTorch.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from hypa.core.errors import UserError
from hypa.physics.discretization import HOLDS, DiscreteLTI, Hold, HoldForm, discretize, hold_form
from hypa.physics.lifted import LiftedMatrices, lifted_from_rows
from hypa.physics.normalized import NormalizedLTI, NormalizingMaps, Scaling
from hypa.physics.parameters import PhysicalParameters
from hypa.physics.scheduled import SchedulingError
from hypa.physics.simulation import BlockSimulation
from hypa.physics.statespace import LTIModel, StateSpace
from hypa.physics.table import ScheduleTable, ScheduleTables

__all__ = ["LTIBlock", "LTIModel", "StateSpace", "UnstablePhysicsError"]


_SCALING = ("state_mean", "state_std", "input_mean", "input_std", "output_mean", "output_std")


class UnstablePhysicsError(UserError):
    """The configured physical parameters give an unstable (or non-finite) model."""


class LTIBlock(BlockSimulation, nn.Module):
    """Normalized, lifted LTI simulator with physical parameters (frozen or trainable).

    Inputs and outputs are normalized (eq. 2). ``forward(x̂_k, û)`` returns the outputs at
    samples k+1..k+S, ŷ_j = Ĉ x̂_j + D̂ û_j + Ĝ (D with the input of the same sample: u holds
    S + ``extra_inputs`` samples), so for the single track (C = I, D = 0) they are the states;
    a pure gain (no states) gives D̂ û_j at every given sample. Sequences of any length are
    simulated free-running by chaining horizon-long lifted windows (exact). ``scheduled`` names
    parameters that vary per sample with a measured signal (``scheduled.py``); the running of
    the block (``forward``, ``states``, ``output``, ``steady_state``, ``estimate_state``) is
    in ``simulation.py``.
    """

    def __init__(
        self,
        model: LTIModel,
        parameters: PhysicalParameters,
        dt: float,
        horizon: int = 100,
        hold: Hold = "zoh",
        scaling: Scaling | None = None,
        scheduled: Sequence[str] = (),
        table: bool = False,
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
            raise ValueError(f"{model.display_name} needs parameters {sorted(missing)}")
        self.model, self.parameters_, self.dt, self.horizon, self.hold = model, parameters, dt, horizon, hold
        self.scheduled = tuple(scheduled)
        # the states whose scaling came from the data (measured, or read alone by a measured output);
        # the others' is the physics' (around 0 for a linear block): set by the model's builder
        self.observed_states: frozenset[int] = frozenset()
        unknown = [s for s in self.scheduled if s not in model.parameter_names]
        if unknown or len(set(self.scheduled)) != len(self.scheduled):
            raise SchedulingError(f"{model.display_name}: cannot schedule {list(scheduled)}; its parameters are "
                                  f"{list(model.parameter_names)} (each at most once)")
        if table and len(self.scheduled) != 1:
            raise SchedulingError(f"{model.display_name}: a table needs one scheduled parameter, got "
                                  f"{list(self.scheduled) or 'none'}")
        self._fixed_names = tuple(k for k in model.parameter_names if k not in self.scheduled)
        if self.scheduled and model.has_nonlinear_output:
            raise SchedulingError(f"{model.display_name}: a system with a nonlinear output cannot be scheduled yet")
        with torch.no_grad():  # feedthrough decides how many inputs a window takes (``extra_inputs``);
            # a nonlinear output h(x, u) may read its own sample's input
            self.feedthrough = bool(model.n_states and ((model.has_nonlinear_output
                                                         and model.nonlinear_output_reads_inputs)
                                                        or torch.count_nonzero(self.state_space().d)))
        n, m, p = model.n_states, len(model.input_names), len(model.output_names)
        scaling = scaling or Scaling.identity(n, m, p)
        if model.outputs_are_states:
            scaling = dataclasses.replace(scaling, output_mean=scaling.state_mean, output_std=scaling.state_std)
        for name in _SCALING:
            self.register_buffer(name, getattr(scaling, name).detach().to(torch.float64).clone())
        self._cache: tuple[tuple, LiftedMatrices, NormalizedLTI] | None = None
        self._maps: tuple[tuple, NormalizingMaps] | None = None
        self.tables = ScheduleTables(model.display_name) if table else None

    # -- the physics, step by step -------------------------------------------------------
    @property
    def form(self) -> HoldForm:
        """How the block's hold reads its input samples (its taps)."""
        return hold_form(self.hold)

    @property
    def n_taps(self) -> int:
        return self.form.n_taps

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

    def linearised_a(self, dtype: torch.dtype = torch.float64) -> Tensor:
        """The continuous A of the system linearised about its operating point: A itself for a
        linear system; for nonlinear physics (Lur'e form) A + F ∂φ/∂x at the scaling's state and
        input means (a measured state's from the data), so a system whose linear part is empty
        (tanks draining through orifices: all dynamics in φ) still has its time constants."""
        ss = self.state_space(dtype)
        if not self.model.is_nonlinear:
            return ss.a
        p = self.parameters_.values(self.model.parameter_names, dtype)
        f, prepared = self.model.feedback(p), self.model.prepare(p)
        x, u = self.state_mean.to(dtype), self.input_mean.to(dtype)
        slope = torch.func.jacrev(lambda s: self.model.nonlinearity(s, u, prepared))(x)  # (r, n)
        return ss.a + f.reshape(ss.a.shape[0], -1) @ slope.reshape(-1, ss.a.shape[0])

    def discrete(self, dtype: torch.dtype = torch.float64) -> DiscreteLTI:
        ss = self.state_space(dtype)
        return discretize(ss.a, ss.b, self.dt, self.hold, ss.e)

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
        rows, out = maps.state_rows(ss.a, ss.b, ss.e), maps.output_rows(ss.c, ss.d)
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
            self._maps = (key, NormalizingMaps.build(scaling, self.dt, self.hold, dtype))
        return self._maps[1]

    def check_stable(self, rtol: float = 1e-6) -> None:
        """Raise ``UnstablePhysicsError`` if an eigenvalue of A has a real part clearly above 0.

        Marginal modes pass: an integrator (a position driven by a velocity) has λ = 0, which
        round-off makes ±ε‖A‖ (±√ε‖A‖ for a double integrator), so only
        Re λ > rtol · ‖A‖_F counts as unstable.
        """
        with torch.no_grad():
            a = self.state_space(torch.float64).a
            if a.numel() == 0:
                return
            if not bool(torch.isfinite(a).all()):
                raise UnstablePhysicsError(f"{self.model.display_name}: A is not finite: {a.tolist()}")
            eig = torch.linalg.eigvals(a)
            tol = rtol * float(torch.linalg.matrix_norm(a))
        if float(eig.real.max()) > tol:
            raise UnstablePhysicsError(
                f"{self.model.display_name} is unstable with parameters "
                + ", ".join(f"{k}={v:.5g}" for k, v in self.parameters_.as_floats().items())
                + f": eigenvalues of A {', '.join(f'{e:.4g}' for e in eig.tolist())} 1/s (a real part > 0). "
                "Check the nominal parameters (e.g. cf*lf vs cr*lr at this velocity)."
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

    def _table(self, rho: Tensor) -> ScheduleTable | None:
        """The verified table of the rows at ρ (B, L, 1) where no gradient needs them, else None (``table.py``)."""
        if self.tables is None or rho.requires_grad or self._rebuilds():
            return None
        return self.tables.get(self._cache_key(rho.dtype, rho.device), rho, self._exact_rows)

    def _exact_rows(self, rho: Tensor) -> Tensor:
        """What a table holds at ρ (K,): the state rows, then the output rows unless the outputs are the states."""
        with torch.no_grad():
            rho = rho[None, :, None]
            ss = self._per_sample(rho)
            parts = [self._state_rows(ss, rho.shape[1])]
            if not self.model.outputs_are_states:
                parts.append(self._normalizing_maps(rho.dtype, rho.device).output_rows(ss.c, ss.d))
            return torch.cat([part[0].reshape(rho.shape[1], -1) for part in parts], 1)

    def extra_repr(self) -> str:
        m = self.model
        return (f"{m.display_name}: {list(m.input_names)} -> {list(m.output_names)}, "
                f"dt={self.dt:g} s, horizon={self.horizon}, hold={self.hold}"
                + (f", scheduled={list(self.scheduled)}" if self.scheduled else "")
                + (", table" if self.tables is not None else ""))
