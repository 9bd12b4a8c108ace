"""The model family the diagnosis searches: nominal single track + one knob per catalogue cause.

A :class:`ModelSpec` is the nominal linear single-track physics (``hypa.physics.SingleTrack``,
states x = [yaw_rate r rad/s, side_slip β rad]) plus the knobs the candidate causes turn:

    u       = δsw_measured - b_sw                              (steering-wheel sensor offset) [rad]
    δf(t)   = lag_τ( u(t - d) ) / i_s                          (dead time d [s], first-order lag τ [s])
    δr      = k_r · lag_τr( u / i_s )                          (unmodeled rear steering: ratio, time constant)
    x_{k+1} = Φ x_k + Γ0 u_k + Γ1 u_{k+1} + (Γ0 + Γ1) ΔF(x_k, u_k) / c     (hold: Γ1 = 0 for ZOH)
    y       = x + [b_r, b_β]                                   (yaw-rate / side-slip sensor offsets)

ΔF is the force deficit of a saturating axle, F(s) - c s per axle, with the magic formula
F(s) = D sin(C atan(B s - E (B s - atan(B s)))), D = μ F_z (static axle load), B = c / (C D),
typical passenger-car shape C = 1.35, E = -0.5, and the axle slip s = δ - β - l r / v
(l = [lf, -lr]). Entering as the steering angle ΔF / c that would produce it, the deficit
reuses the exact discretization; holding it over a sample (evaluated at x_k) is the only
approximation, small because ΔF is a fraction of the force. μ = ∞ is the linear model, which
runs as four C-speed IIR filters (``scipy.signal.lfilter``); finite μ runs a time loop
vectorized over a batch of specs, so one pass tests a whole grid.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import brentq
from scipy.signal import lfilter

from hypa.physics import discretize
from hypa.vehicle import SingleTrack, VehicleParameters

GRAVITY = 9.81  # [m/s^2]
SHAPE_C, CURVATURE_E = 1.35, -0.5  # magic-formula shape of the saturating axle
STATES = ("yaw_rate", "side_slip")
OFFSET_CHANNELS = ("steering_wheel_angle", "yaw_rate", "side_slip")


@dataclass(frozen=True)
class ModelSpec:
    """Nominal physics plus the catalogue's knobs (SI units; defaults = the nominal model).

    ``offsets``: sensor biases [rad, rad/s, rad] of ``OFFSET_CHANNELS`` (measured - true).
    ``mu``: peak friction coefficient of the saturating axles [-], ``inf`` = linear axles.
    """

    vehicle: VehicleParameters
    hold: str = "zoh"
    delay_s: float = 0.0
    lag_tau_s: float = 0.0
    rear_ratio: float = 0.0
    rear_tau_s: float = 0.0
    mu: float = math.inf
    offsets: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def replace(self, **changes) -> ModelSpec:
        return dataclasses.replace(self, **changes)

    def with_vehicle(self, **changes: float) -> ModelSpec:
        return self.replace(vehicle=dataclasses.replace(self.vehicle, **changes))

    def with_offset(self, channel: str, value: float) -> ModelSpec:
        offsets = list(self.offsets)
        offsets[OFFSET_CHANNELS.index(channel)] = float(value)
        return self.replace(offsets=tuple(offsets))


def continuous_matrices(vehicle: VehicleParameters) -> tuple[np.ndarray, np.ndarray]:
    """A (2, 2) and B (2, 2) of the single track (inputs δf, δr) from ``hypa.physics``."""
    p = {k: torch.tensor(float(v), dtype=torch.float64) for k, v in vehicle.as_dict().items()}
    ss = SingleTrack(rear_steering=True).matrices(p)
    return ss.a.numpy(), ss.b.numpy()


def discrete_matrices(vehicle: VehicleParameters, dt: float, hold: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Φ, Γ0, Γ1 (each (2, 2)) of the hold (``hypa.physics.discretize``); Γ1 = 0 for ZOH."""
    a, b = continuous_matrices(vehicle)
    d = discretize(torch.from_numpy(a), torch.from_numpy(b), dt, hold)  # type: ignore[arg-type]
    taps = [t.numpy() for t in d.taps] + [np.zeros((2, 2))]
    return d.phi.numpy(), taps[0], taps[1]


def first_order_lag(u: np.ndarray, tau_s: float, dt: float, hold: str = "foh") -> np.ndarray:
    """τ ẏ = u - y, exact for u linear (``foh``) or constant (``zoh``) between samples, starting
    in equilibrium y0 = u0 (as the ``first_order_lag`` block of a hypa model)."""
    if tau_s <= 0.0:
        return u
    a = math.exp(-dt / tau_s)
    if hold == "zoh":  # y_{k+1} = a y_k + (1 - a) u_k
        return lfilter([0.0, 1.0 - a], [1.0, -a], u, zi=[u[0]])[0]
    b0 = 1.0 - tau_s / dt * (1.0 - a)
    b1 = tau_s / dt * (1.0 - a) - a
    return lfilter([b0, b1], [1.0, -a], u, zi=[(1.0 - b0) * u[0]])[0]


def wheel_angles(spec: ModelSpec, steering_wheel_angle: np.ndarray, dt: float) -> np.ndarray:
    """[δf, δr] (L, 2) [rad]. The dead time interpolates linearly (fractional samples)."""
    u = np.asarray(steering_wheel_angle, dtype=float) - spec.offsets[0]
    front = u / spec.vehicle.steering_ratio
    rear = spec.rear_ratio * first_order_lag(front, spec.rear_tau_s, dt, spec.hold)
    if spec.delay_s > 0.0:
        t = np.arange(front.size) * dt
        front = np.interp(t - spec.delay_s, t, front, left=front[0])
    return np.stack([first_order_lag(front, spec.lag_tau_s, dt, spec.hold), rear], axis=-1)


def _drive(phi_g0_g1, angles: np.ndarray) -> np.ndarray:
    """Γ0 u_k + Γ1 u_{k+1} (L, 2); the last input is repeated past the end."""
    _, g0, g1 = phi_g0_g1
    ahead = np.concatenate([angles[1:], angles[-1:]])
    return angles @ g0.T + ahead @ g1.T


def _linear(phi: np.ndarray, drive: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """x_{k+1} = Φ x_k + drive_k from x0 as IIR filters: y[n] = Φ y[n-1] + w[n], w = [x0, drive].

    Y(z) = (I - Φ z⁻¹)⁻¹ W(z) = adj(zI - Φ) z⁻¹ / (1 - tr Φ z⁻¹ + det Φ z⁻²) · W(z).
    """
    w = np.concatenate([x0[None], drive[:-1]])  # (L, 2)
    den = [1.0, -np.trace(phi), np.linalg.det(phi)]
    (p11, p12), (p21, p22) = phi
    r = lfilter([1.0, -p22], den, w[:, 0]) + lfilter([0.0, p12], den, w[:, 1])
    beta = lfilter([0.0, p21], den, w[:, 0]) + lfilter([1.0, -p11], den, w[:, 1])
    return np.stack([r, beta], axis=-1)


def axle_loads(vehicle: VehicleParameters) -> np.ndarray:
    """Static vertical loads [F_zf, F_zr] [N]."""
    weight = vehicle.mass * GRAVITY
    return weight * np.array([vehicle.lr, vehicle.lf]) / vehicle.wheelbase


def magic_formula(slip: np.ndarray, stiffness: np.ndarray, peak: np.ndarray) -> np.ndarray:
    """Axle force F(s) = D sin(C atan(B s - E (B s - atan(B s)))) [N], B = c / (C D)."""
    x = stiffness / (SHAPE_C * peak) * slip
    return peak * np.sin(SHAPE_C * np.arctan(x - CURVATURE_E * (x - np.arctan(x))))


def ay_threshold(mu: float, drop: float = 0.05) -> float:
    """Lateral acceleration [m/s²] at which an axle's force falls ``drop`` below linear.

    In a steady turn each axle carries F_y = F_z a_y / g, and F(s) / (c s) depends on x = B s
    only, so the threshold is the same for both axles: a_y* = g μ sin(C atan(φ(x*))) with
    sin(C atan(φ(x*))) / (C x*) = 1 - drop, φ(x) = x - E (x - atan x).
    """
    if not math.isfinite(mu):
        return math.inf
    phi = lambda x: x - CURVATURE_E * (x - math.atan(x))  # noqa: E731
    ratio = lambda x: math.sin(SHAPE_C * math.atan(phi(x))) / (SHAPE_C * x) - (1.0 - drop)  # noqa: E731
    x_star = brentq(ratio, 1e-6, 1.0)
    return GRAVITY * mu * math.sin(SHAPE_C * math.atan(phi(x_star)))


def simulate_batch(specs: Sequence[ModelSpec], steering_wheel_angle: np.ndarray, measured_x0: np.ndarray,
                   dt: float) -> np.ndarray:
    """Free-run every spec over one record: (K, L, 2) measured-scale states [rad/s, rad].

    The initial state is the measured first sample less the spec's sensor offsets.
    """
    specs = list(specs)
    mats = [discrete_matrices(s.vehicle, dt, s.hold) for s in specs]
    angles = np.stack([wheel_angles(s, steering_wheel_angle, dt) for s in specs])  # (K, L, 2)
    drive = np.stack([_drive(m, a) for m, a in zip(mats, angles)])  # (K, L, 2)
    out_offsets = np.array([s.offsets[1:] for s in specs])  # (K, 2)
    x0 = np.asarray(measured_x0, dtype=float)[None] - out_offsets
    if all(math.isinf(s.mu) for s in specs):
        states = np.stack([_linear(m[0], d, x) for m, d, x in zip(mats, drive, x0)])
    else:
        states = _saturating(specs, mats, angles, drive, x0)
    return states + out_offsets[:, None]


def _saturating(specs, mats, angles, drive, x0) -> np.ndarray:
    """The time loop with axle force deficits, vectorized over the K specs (see module doc)."""
    phi = np.stack([m[0] for m in mats])  # (K, 2, 2)
    hold_gain = np.stack([m[1] + m[2] for m in mats])  # (K, 2, 2): deficit held over the sample
    stiffness = np.array([[s.vehicle.cf, s.vehicle.cr] for s in specs])  # (K, 2)
    # A linear spec in a mixed batch gets a peak so high that its deficit is round-off.
    mu = np.array([s.mu if math.isfinite(s.mu) else 1e6 for s in specs])
    peak = mu[:, None] * np.stack([axle_loads(s.vehicle) for s in specs])  # (K, 2)
    arm = np.array([[s.vehicle.lf / s.vehicle.velocity, -s.vehicle.lr / s.vehicle.velocity] for s in specs])
    length = angles.shape[1]
    states = np.empty((len(specs), length, 2))
    x = x_prev = x0.copy()
    # The deficit acts over the whole sample, so it is evaluated at the sample's midpoint:
    # the state extrapolated half a step, the input interpolated.
    middle = 0.5 * (angles + np.concatenate([angles[:, 1:], angles[:, -1:]], axis=1))
    for k in range(length):
        states[:, k] = x
        x_mid = 1.5 * x - 0.5 * x_prev
        slip = middle[:, k] - x_mid[:, 1:2] - arm * x_mid[:, 0:1]  # (K, 2) per axle
        x_prev = x
        deficit = magic_formula(slip, stiffness, peak) / stiffness - slip
        x = np.einsum("kij,kj->ki", phi, x) + drive[:, k] + np.einsum("kij,kj->ki", hold_gain, deficit)
    return states
