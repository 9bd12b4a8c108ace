"""The test bench's truth: nonlinear single-track model with active rear-wheel steering.

States at constant speed v [m/s]: yaw rate r [rad/s], side slip beta [rad], the lagged
axle slip angles alpha_f, alpha_r [rad], the rear actuator angle delta_r [rad] and the
roll mode's lateral acceleration a_roll [m/s^2] with its rate:

    beta'    = (Fyf + Fyr) / (m v) - r
    r'       = (lf Fyf - lr Fyr) / Izz
    alpha_f' = (delta_f - beta - lf r / v - alpha_f) v / sigma_f     (relaxation)
    alpha_r' = (delta_r - beta + lr r / v - alpha_r) v / sigma_r
    delta_r' = clip((clip(delta_r,cmd) - delta_r) / tau, +-rate)     (RWS actuator)
    a_roll'' = w^2 (a_y - a_roll) - 2 zeta w a_roll'                 (body roll)

with the axle forces Fy = F(alpha, dFz) of :func:`axle_characteristic` (two wheels, load
dFz moved from the inner to the outer one in proportion to a_roll) and the lateral
acceleration a_y = v (beta' + r) = (Fyf + Fyr) / m. With linear axles, no load transfer,
no relaxation and no rear steering this is exactly the linear single-track model of the
paper (Sec. 5). Integration is classic RK4 at the sample rate with the inputs interpolated
linearly within a step; the loop runs on Python floats because that beats per-step numpy.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from hypa.paper.testbench.config import (
    LoadTransferConfig,
    RearSteeringConfig,
    RelaxationConfig,
    SteeringConfig,
    TireConfig,
)
from hypa.vehicle import VehicleParameters

GRAVITY = 9.81  # [m/s^2]


@dataclass(frozen=True)
class TruthTrajectory:
    """Noise-free truth at the sample instants (SI units, one value per sample)."""

    front_wheel_angle: np.ndarray  # [rad] after steering ratio, dead time and lag
    rear_wheel_angle: np.ndarray  # [rad] actual actuator angle
    yaw_rate: np.ndarray  # [rad/s]
    side_slip: np.ndarray  # [rad]
    lateral_acceleration: np.ndarray  # [m/s^2]


def static_axle_loads(vehicle: VehicleParameters) -> tuple[float, float]:
    """Static vertical axle loads (m g lr / L, m g lf / L) [N]."""
    weight = vehicle.mass * GRAVITY
    return weight * vehicle.lr / vehicle.wheelbase, weight * vehicle.lf / vehicle.wheelbase


def axle_characteristic(
    alpha: np.ndarray | float,
    cornering_stiffness: float,
    vertical_load: float,
    tires: TireConfig,
    load_transfer: LoadTransferConfig | None = None,
    transfer: float = 0.0,
) -> np.ndarray:
    """Lateral axle force Fy [N] of the slip angle alpha [rad]: the sum of its two wheels.

    Each wheel: magic formula Fy = D sin(C atan(B a - E (B a - atan(B a)))) with B = K / (C D)
    (linear Fy = K a when the tyres are disabled). With ``load_transfer`` enabled the wheels
    carry Fz0 +- ``transfer`` [N] (Fz0 = half the axle's ``vertical_load``) and D, K follow
    the load as :class:`~hypa.paper.testbench.config.LoadTransferConfig` describes; without it, or
    at zero transfer, D = mu Fz and the slope at zero slip is ``cornering_stiffness``.
    (The integration loop inlines the same formula for speed.)
    """
    alpha = np.asarray(alpha, dtype=float)
    half = 0.5 * vertical_load
    loads = (half + transfer, half - transfer) if load_transfer is not None and load_transfer.enabled else (half, half)
    total, wheel = np.zeros_like(alpha), _wheel_law(tires, load_transfer)
    for load in loads:
        d, k = wheel(load, half, 0.5 * cornering_stiffness)
        if not tires.enabled:
            total = total + k * alpha
            continue
        x = k / (tires.shape_c * d) * alpha
        total = total + d * np.sin(tires.shape_c * np.arctan(x - tires.curvature_e * (x - np.arctan(x))))
    return total


def _wheel_law(
    tires: TireConfig, load_transfer: LoadTransferConfig | None
) -> Callable[[float, float, float], tuple[float, float]]:
    """``wheel(load, static_load, stiffness)``: peak force D [N] and cornering stiffness K [N/rad]
    of one wheel at its vertical load [N] (static load and stiffness at it: half the axle's),
    its constants computed once (the integration loop calls it four times per RK4 stage)."""
    mu = tires.mu
    if load_transfer is None or not load_transfer.enabled:
        return lambda load, static_load, stiffness: (mu * load, stiffness)
    p, gradient = load_transfer.stiffness_load_peak, load_transfer.mu_load_gradient
    norm = math.sin(2.0 * math.atan(1.0 / p))
    sin, atan = math.sin, math.atan

    def wheel(load: float, static_load: float, stiffness: float) -> tuple[float, float]:
        x = max(load, 0.01 * static_load) / static_load  # a lifted wheel keeps 1 % (no division by 0)
        return mu * (1.0 + gradient * (x - 1.0)) * x * static_load, stiffness * sin(2.0 * atan(x / p)) / norm

    return wheel


def feedforward_ratio(speed: float, rear_steering: RearSteeringConfig) -> float:
    """Speed-scheduled rear / front wheel angle ratio k(v) [-] of the ECU table."""
    return float(np.interp(speed, rear_steering.table_speed_mps, rear_steering.table_ratio))


def rear_steering_command(
    front_wheel_angle: np.ndarray | float,
    yaw_rate: np.ndarray | float,
    speed: float,
    rear_steering: RearSteeringConfig,
    lowpassed_front: np.ndarray | float | None = None,
) -> np.ndarray:
    """The ECU's angle-limited command delta_r,cmd [rad].

    delta_r,cmd = strength (k(v) (1 + g tanh(|r| / r_ref)) delta_f,ECU + k_r r
    - k_t (delta_f,ECU - lowpassed_front)) of the ECU's front wheel angle delta_f,ECU [rad],
    its first-order low-pass with tau_t ``lowpassed_front`` [rad] (None: the phase-reversal
    term is left out) and the yaw rate r [rad/s], clipped to the angle limit. With g < 0 the
    in-phase ratio falls as the car turns harder, which offsets part of the tyres' growing
    understeer; the yaw-rate feedback (in-phase for k_r > 0) damps the yaw motion.
    (The integration loop inlines the same law for speed.)
    """
    ratio = rear_steering.strength * feedforward_ratio(speed, rear_steering)
    r = np.asarray(yaw_rate, dtype=float)
    front = np.asarray(front_wheel_angle, dtype=float)
    modulation = 1.0 + rear_steering.yaw_rate_ratio_gain * np.tanh(
        np.abs(r) / rear_steering.yaw_rate_ref
    )
    command = ratio * modulation * front + rear_steering.strength * rear_steering.yaw_rate_feedback_s * r
    if lowpassed_front is not None:
        command = command - rear_steering.strength * rear_steering.transient_ratio * (front - lowpassed_front)
    return np.clip(command, -rear_steering.angle_limit, rear_steering.angle_limit)


def front_wheel_angle(
    steering_wheel_angle: np.ndarray,
    sample_rate_hz: float,
    steering_ratio: float,
    steering: SteeringConfig,
) -> np.ndarray:
    """delta_f [rad]: steering-wheel angle [rad] / ratio, delayed by a dead time and lagged.

    The dead time shifts by linear interpolation (fractional samples allowed). The lag
    tau delta_f' = u - delta_f is discretized exactly for inputs linear between samples:
    delta_f[k+1] = a delta_f[k] + b0 u[k+1] + b1 u[k], a = exp(-h / tau).
    """
    u = np.asarray(steering_wheel_angle, dtype=float) / steering_ratio
    h = 1.0 / sample_rate_hz
    if steering.delay_s > 0.0:
        t = np.arange(len(u)) * h
        u = np.interp(t - steering.delay_s, t, u, left=u[0])
    if steering.lag_tau_s > 0.0:
        a = math.exp(-h / steering.lag_tau_s)
        b0 = 1.0 - steering.lag_tau_s / h * (1.0 - a)
        b1 = steering.lag_tau_s / h * (1.0 - a) - a
        u = lfilter([b0, b1], [1.0, -a], u, zi=[(1.0 - b0) * u[0]])[0]
    return u


def simulate_truth(
    steering_wheel_angle: np.ndarray,
    sample_rate_hz: float,
    vehicle: VehicleParameters,
    tires: TireConfig,
    relaxation: RelaxationConfig,
    rear_steering: RearSteeringConfig,
    steering: SteeringConfig,
    load_transfer: LoadTransferConfig | None = None,
) -> TruthTrajectory:
    """Integrate the truth from rest (all states 0) for a steering-wheel angle [rad].

    ``load_transfer`` None: no load transfer (each wheel carries half its axle's load).
    """
    front = front_wheel_angle(
        steering_wheel_angle, sample_rate_hz, vehicle.steering_ratio, steering
    )
    ecu_front = np.asarray(steering_wheel_angle, dtype=float) / vehicle.steering_ratio
    rhs = _right_hand_side(vehicle, tires, relaxation, rear_steering, load_transfer)
    yaw, slip, accel, rear = _rk4(rhs, front.tolist(), ecu_front.tolist(), 1.0 / sample_rate_hz)
    return TruthTrajectory(front, np.array(rear), np.array(yaw), np.array(slip), np.array(accel))


def _right_hand_side(
    vehicle: VehicleParameters,
    tires: TireConfig,
    relaxation: RelaxationConfig,
    rear_steering: RearSteeringConfig,
    load_transfer: LoadTransferConfig | None = None,
) -> Callable[..., tuple[float, ...]]:
    """State derivatives and a_y as one flat closure over floats.

    It inlines :func:`axle_characteristic` and :func:`rear_steering_command`: calls and
    numpy scalars would make the ~800k-step default data several times slower.
    """
    v, lf, lr = vehicle.velocity, vehicle.lf, vehicle.lr
    lf_v, lr_v = lf / v, lr / v
    inv_mv, inv_m, inv_izz = 1.0 / (vehicle.mass * v), 1.0 / vehicle.mass, 1.0 / vehicle.izz
    cf, cr = vehicle.cf, vehicle.cr
    magic = tires.enabled
    load_f, load_r = static_axle_loads(vehicle)
    d_f, d_r = tires.mu * load_f, tires.mu * load_r
    shape, curvature = tires.shape_c, tires.curvature_e
    b_f, b_r = cf / (shape * d_f), cr / (shape * d_r)
    relax = relaxation.enabled
    rate_f = v / relaxation.front_length_m if relax else 0.0  # 1 / tau [1/s]
    rate_r = v / relaxation.rear_length_m if relax else 0.0
    rws = rear_steering.enabled
    ratio = rear_steering.strength * feedforward_ratio(v, rear_steering)
    gain, r_ref = rear_steering.yaw_rate_ratio_gain, rear_steering.yaw_rate_ref
    feedback = rear_steering.strength * rear_steering.yaw_rate_feedback_s
    limit, rate_limit = rear_steering.angle_limit, rear_steering.rate_limit
    inv_tau = 1.0 / rear_steering.actuator_tau_s
    transient = rear_steering.strength * rear_steering.transient_ratio
    inv_transient_tau = 1.0 / rear_steering.transient_tau_s
    sin, atan, tanh = math.sin, math.atan, math.tanh

    transfer = load_transfer is not None and load_transfer.enabled
    if transfer:
        lt = load_transfer
        omega = 2.0 * math.pi * lt.roll_frequency_hz
        omega2, damping = omega * omega, 2.0 * lt.roll_damping * omega
        # load moved per m/s^2 of a_roll [N s^2/m]: the axle's share of m h a / track
        per_f = lt.front_roll_share * vehicle.mass * lt.cg_height_m / lt.track_front_m
        per_r = (1.0 - lt.front_roll_share) * vehicle.mass * lt.cg_height_m / lt.track_rear_m

        wheel = _wheel_law(tires, lt)

        def axle(alpha, static, stiffness, shift):
            force = 0.0
            for load in (static + shift, static - shift):
                d, k = wheel(load, static, stiffness)
                if magic:
                    x = k / (shape * d) * alpha
                    force += d * sin(shape * atan(x - curvature * (x - atan(x))))
                else:
                    force += k * alpha
            return force

        half_f, half_r, c_f, c_r = 0.5 * load_f, 0.5 * load_r, 0.5 * cf, 0.5 * cr

    def rhs(r, beta, alpha_f, alpha_r, delta_r, a_roll, a_roll_rate, lagged_ecu, delta_f, delta_f_ecu):
        kin_f = delta_f - beta - lf_v * r  # kinematic slip angles
        kin_r = delta_r - beta + lr_v * r
        if relax:
            d_alpha_f = (kin_f - alpha_f) * rate_f
            d_alpha_r = (kin_r - alpha_r) * rate_r
        else:
            alpha_f, alpha_r, d_alpha_f, d_alpha_r = kin_f, kin_r, 0.0, 0.0
        if transfer:
            fyf = axle(alpha_f, half_f, c_f, per_f * a_roll)
            fyr = axle(alpha_r, half_r, c_r, per_r * a_roll)
        elif magic:
            x = b_f * alpha_f
            fyf = d_f * sin(shape * atan(x - curvature * (x - atan(x))))
            x = b_r * alpha_r
            fyr = d_r * sin(shape * atan(x - curvature * (x - atan(x))))
        else:
            fyf, fyr = cf * alpha_f, cr * alpha_r
        d_delta_r = 0.0
        d_lagged = (delta_f_ecu - lagged_ecu) * inv_transient_tau
        if rws:
            cmd = ratio * (1.0 + gain * tanh(abs(r) / r_ref)) * delta_f_ecu + feedback * r
            cmd -= transient * (delta_f_ecu - lagged_ecu)  # counter-phase while the steer changes
            cmd = limit if cmd > limit else (max(cmd, -limit))
            d_delta_r = (cmd - delta_r) * inv_tau
            if d_delta_r > rate_limit:
                d_delta_r = rate_limit
            elif d_delta_r < -rate_limit:
                d_delta_r = -rate_limit
        force = fyf + fyr
        a_y = force * inv_m
        d_roll_rate = (omega2 * (a_y - a_roll) - damping * a_roll_rate) if transfer else 0.0
        return (
            (lf * fyf - lr * fyr) * inv_izz,
            force * inv_mv - r,
            d_alpha_f,
            d_alpha_r,
            d_delta_r,
            a_roll_rate,
            d_roll_rate,
            d_lagged,
            a_y,
        )

    return rhs


def _rk4(rhs, front: list, ecu: list, h: float):
    """Classic RK4 from rest; returns yaw rate, side slip, a_y and rear angle per sample.

    The inputs are interpolated linearly within a step (midpoint = mean of the samples).
    """
    n = len(front)
    yaw, slip, accel, rear = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
    state = (0.0,) * 8
    h2, h6 = 0.5 * h, h / 6.0
    u1, e1 = front[0], ecu[0]
    for k in range(n):
        u0, e0 = u1, e1
        k1 = rhs(*state, u0, e0)
        yaw[k], slip[k], accel[k], rear[k] = state[0], state[1], k1[8], state[4]
        if k == n - 1:
            break
        u1, e1 = front[k + 1], ecu[k + 1]
        um, em = 0.5 * (u0 + u1), 0.5 * (e0 + e1)
        k2 = rhs(*[x + h2 * d for x, d in zip(state, k1)], um, em)
        k3 = rhs(*[x + h2 * d for x, d in zip(state, k2)], um, em)
        k4 = rhs(*[x + h * d for x, d in zip(state, k3)], u1, e1)
        state = tuple(x + h6 * (a + 2.0 * (b + c) + d) for x, a, b, c, d in zip(state, k1, k2, k3, k4))
    return yaw, slip, accel, rear
