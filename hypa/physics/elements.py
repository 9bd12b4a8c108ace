"""Generic input-path elements: a first-order lag (an LTI system), a dead time (a shift) and a
limit (a static saturation).

Both carry their own parameter (a time constant, a delay), so several of them can sit in one
model: their parameter names are prefixed with the block's name (``front_lag/tau_s``), while
the vehicle's parameters (``cf``, ``steering_ratio``, ...) stay shared by every block.
They are what the diagnosis adds when it names an ``input_lag`` or an ``input_delay``
(``hypa/diagnosis/catalogue.yaml``), and any model YAML can use them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn

from hypa.physics.lti import LTIModel, StateSpace
from hypa.physics.parameters import ParameterSpec, PhysicalParameters


def local_name(prefix: str, name: str) -> str:
    """The parameter name of a block-local parameter: ``<block>/<name>`` (``""``: ``name``)."""
    return f"{prefix}/{name}" if prefix else name


class FirstOrderLag(LTIModel):
    """τ ẏ = u - y: unit static gain, time constant ``tau_s`` [s] (actuator bandwidth, compliance).

    One state, the output itself, so the output shares the state's name and scaling. Started
    in equilibrium with its first input (``initial_state: steady`` in a model YAML) it needs
    no measured state. The parameter is the block's own, ``<block>/tau_s``; its nominal 0.1 s
    is a placeholder a model sets (``parameters: {tau_s: ...}``).
    """

    state_names = ("lagged",)
    input_names = ("input",)
    output_names = ("lagged",)

    def __init__(self, prefix: str = "") -> None:
        self.parameters = (ParameterSpec(local_name(prefix, "tau_s"), 0.1, "s"),)

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        tau = p[self.parameter_names[0]]
        rate = (-1.0 / tau).reshape(1, 1)
        one = torch.ones(1, 1, dtype=tau.dtype, device=tau.device)
        return StateSpace(rate, -rate, one, tau.new_zeros(1, 1))


class GainLag(LTIModel):
    """τ ẏ = k u - y: a gain ``gain`` [-] (signed) reached through a first-order lag ``tau_s`` [s].

    An unmodeled input proportional to a modeled one, with its actuator's bandwidth (a rear
    steering that follows the front angle). Parameters are the block's own; started
    ``steady`` it needs no measured state.
    """

    state_names = ("lagged",)
    input_names = ("input",)
    output_names = ("lagged",)

    def __init__(self, prefix: str = "") -> None:
        self.parameters = (ParameterSpec(local_name(prefix, "gain"), 1.0, "-", positive=False),
                           ParameterSpec(local_name(prefix, "tau_s"), 0.1, "s"))

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        gain, tau = (p[n] for n in self.parameter_names)
        rate = (-1.0 / tau).reshape(1, 1)
        one = torch.ones(1, 1, dtype=tau.dtype, device=tau.device)
        return StateSpace(rate, (gain / tau).reshape(1, 1), one, tau.new_zeros(1, 1))


class LeadLag(LTIModel):
    """A gain with a transient part, through an actuator lag: ``y = G(s) u`` with

        G(s) = (k + (k - k_t) τ_t s) / ((1 + τ_t s) (1 + τ s))

    from the command ``c = k u - k_t (u - l)``, ``τ_t l̇ = u - l`` and ``τ ẏ = c - y``: right after
    a change of u the output moves by ``k - k_t``, then settles at the gain ``k`` over ``τ_t``.
    With ``transient`` k_t > k the first response has the opposite sign (a non-minimum-phase
    zero: the phase-reversal rear steering of four-wheel-steered cars); with k_t = 0 it is
    ``GainLag``. Parameters, the block's own: ``gain`` [-] and ``transient`` [-] (both signed),
    ``transient_tau_s`` and ``tau_s`` [s]. Its two states are the low-passed input and the
    output; started ``steady`` (both equal to their equilibrium) it needs no measured state.
    """

    state_names = ("lowpassed", "lagged")
    input_names = ("input",)
    output_names = ("lagged",)

    def __init__(self, prefix: str = "") -> None:
        self.parameters = (ParameterSpec(local_name(prefix, "gain"), 1.0, "-", positive=False),
                           ParameterSpec(local_name(prefix, "transient"), 0.0, "-", positive=False),
                           ParameterSpec(local_name(prefix, "transient_tau_s"), 0.3, "s"),
                           ParameterSpec(local_name(prefix, "tau_s"), 0.1, "s"))

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        gain, transient, tau_t, tau = (p[n] for n in self.parameter_names)
        zero = tau.new_zeros(())
        a = torch.stack([torch.stack([-1.0 / tau_t, zero]), torch.stack([transient / tau, -1.0 / tau])])
        b = torch.stack([1.0 / tau_t, (gain - transient) / tau]).reshape(2, 1)
        c = torch.stack([zero, torch.ones_like(tau)]).reshape(1, 2)
        return StateSpace(a, b, c, tau.new_zeros(1, 1))


class StaticGain(LTIModel):
    """y = k u: a gain ``gain`` [-] (signed), no states (what ``hypa.explain`` writes for a
    block it explains as a static gain)."""

    state_names: tuple[str, ...] = ()
    input_names = ("input",)
    output_names = ("output",)

    def __init__(self, prefix: str = "") -> None:
        self.parameters = (ParameterSpec(local_name(prefix, "gain"), 1.0, "-", positive=False),)

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        gain = p[self.parameter_names[0]]
        return StateSpace(gain.new_zeros(0, 0), gain.new_zeros(0, 1), gain.new_zeros(1, 0), gain.reshape(1, 1))


class SecondOrder(LTIModel):
    """y = k (1 + T s) / (1 + 2ζ s/ω + s²/ω²) u, ω = 2π ``natural_frequency_hz``: a gain ``gain``
    [-] with a zero ``zero_s`` T [s] (both signed) through two poles of damping ``damping`` ζ [-]
    (what ``hypa.explain`` writes for a block it explains as a second-order form). Two states,
    the low-passed input and its rate; started ``steady`` it needs no measured state."""

    state_names = ("filtered", "filtered_rate")
    input_names = ("input",)
    output_names = ("output",)

    def __init__(self, prefix: str = "") -> None:
        self.parameters = (ParameterSpec(local_name(prefix, "gain"), 1.0, "-", positive=False),
                           ParameterSpec(local_name(prefix, "zero_s"), 0.0, "s", positive=False),
                           ParameterSpec(local_name(prefix, "natural_frequency_hz"), 1.0, "Hz"),
                           ParameterSpec(local_name(prefix, "damping"), 0.7, "-"))

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        gain, zero_s, frequency, damping = (p[n] for n in self.parameter_names)
        w = 2.0 * math.pi * frequency
        nil, one = w.new_zeros(()), w.new_ones(())
        a = torch.stack([torch.stack([nil, one]), torch.stack([-w * w, -2.0 * damping * w])])
        b = torch.stack([nil, w * w]).reshape(2, 1)
        c = torch.stack([gain, gain * zero_s]).reshape(1, 2)
        return StateSpace(a, b, c, w.new_zeros(1, 1))


class DeadTime(nn.Module):
    """y(t) = u(t - delay_s) on the sample grid: dead time between a command and its effect.

    A dead time is not a finite-dimensional LTI system, so it is a shift, not a state space:
    with delay = (k + f) dt, y_n = (1 - f) u_{n-k} + f u_{n-k-1}. That is exact for an input
    linear between samples, the first-order hold's assumption, and differentiable in the delay
    through f. Before the window's first sample the input is held at that sample (the same
    steady start as a lag's). Channels are shifted independently; scaling is unchanged.
    """

    def __init__(self, parameters: PhysicalParameters, name: str, dt: float) -> None:
        super().__init__()
        if name not in parameters.names:
            raise ValueError(f"DeadTime needs the parameter {name!r}")
        if not dt > 0:
            raise ValueError(f"sample time dt must be positive, got {dt}")
        self.parameters_, self.name, self.dt = parameters, name, dt

    def delay_s(self) -> Tensor:
        return self.parameters_.value(self.name)

    def forward(self, u: Tensor) -> Tensor:
        """u (B, T, m) -> delayed u (B, T, m); gradients reach the delay where it is trainable."""
        samples = self.delay_s().to(u.dtype) / self.dt
        whole = int(math.floor(float(samples.detach())))
        frac = samples - whole
        pad = u[:, :1].expand(-1, whole + 1, -1)
        padded = torch.cat([pad, u], dim=1)  # padded[j] = u[j - whole - 1], held before the start
        length = u.shape[1]
        newer = padded[:, 1 : length + 1]  # u_{n - whole}
        older = padded[:, :length]  # u_{n - whole - 1}
        return newer + frac * (older - newer)

    def extra_repr(self) -> str:
        return f"{self.name}={float(self.delay_s().detach()):.4g} s, dt={self.dt:g} s"


class Saturation(nn.Module):
    """y = u / (1 + |u / L|^p)^(1/p), p = 6: a signal that cannot exceed ±L (an actuator's range).

    Linear to within 0.3 % up to |u| = L/2, 0.89 L at |u| = L, L beyond: close to a hard clip,
    yet differentiable in the limit L (the block's parameter ``limit``, in the signal's unit)
    wherever the signal comes near it. (A tanh is too soft for a clip: fitted to one, its limit
    comes out twice the clip level, to keep the linear range linear.)

    The block reads and writes normalized signals û = (u - μ) / σ, the outputs on their inputs'
    scale; the limit acts on the physical value u = μ + σ û (``scales``: (μ, σ) per channel).
    """

    SHARPNESS = 6.0  # p

    def __init__(self, parameters: PhysicalParameters, name: str, scales: Sequence[tuple[float, float]]) -> None:
        super().__init__()
        if name not in parameters.names:
            raise ValueError(f"Saturation needs the parameter {name!r}")
        self.parameters_, self.name = parameters, name
        self.register_buffer("mean", torch.tensor([float(m) for m, _ in scales]))
        self.register_buffer("std", torch.tensor([float(s) for _, s in scales]))

    def limit(self) -> Tensor:
        return self.parameters_.value(self.name)

    def forward(self, u: Tensor) -> Tensor:
        """u (B, T, m) normalized -> limited u (B, T, m) normalized; differentiable in the limit."""
        limit = self.limit().to(u.dtype)
        mean, std = self.mean.to(u.dtype), self.std.to(u.dtype)
        physical = mean + std * u
        ratio = torch.clamp(physical.abs() / limit, max=1e4)  # beyond: the limit itself to float precision
        limited = physical / (1.0 + ratio**self.SHARPNESS) ** (1.0 / self.SHARPNESS)
        return (limited - mean) / std

    def extra_repr(self) -> str:
        return f"{self.name}={float(self.limit().detach()):.4g}, p={self.SHARPNESS:g}"
