"""The test bench's truth: nonlinear single-track model with active rear-wheel steering.

States at constant speed v [m/s]: yaw rate r [rad/s], side slip beta [rad], the lagged
axle slip angles alpha_f, alpha_r [rad] and the rear actuator angle delta_r [rad]:

    beta'    = (Fyf + Fyr) / (m v) - r
    r'       = (lf Fyf - lr Fyr) / Izz
    alpha_f' = (delta_f - beta - lf r / v - alpha_f) v / sigma_f     (relaxation)
    alpha_r' = (delta_r - beta + lr r / v - alpha_r) v / sigma_r
    delta_r' = clip((clip(delta_r,cmd) - delta_r) / tau, +-rate)     (RWS actuator)

with the axle forces Fy = F(alpha) of :func:`axle_characteristic` and the lateral
acceleration a_y = v (beta' + r) = (Fyf + Fyr) / m. With linear axles, no relaxation and
no rear steering this is exactly the linear single-track model of the paper (Sec. 5).
Integration is classic RK4 at the sample rate with the inputs interpolated linearly
within a step; the loop runs on Python floats because that beats per-step numpy here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from hypa.vehicle import VehicleParameters
from hypa.testbench.config import (
    RearSteeringConfig,
    RelaxationConfig,
    SteeringConfig,
    TireConfig,
)

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
    alpha: np.ndarray | float, cornering_stiffness: float, vertical_load: float, tires: TireConfig
) -> np.ndarray:
    """Lateral axle force Fy [N] of the slip angle alpha [rad].

    Magic formula Fy = D sin(C atan(B a - E (B a - atan(B a)))) with D = mu Fz and
    B = c / (C D), hence dFy/dalpha(0) = B C D = c; linear Fy = c alpha when disabled.
    (The integration loop inlines the same formula for speed.)
    """
    alpha = np.asarray(alpha, dtype=float)
    if not tires.enabled:
        return cornering_stiffness * alpha
    d = tires.mu * vertical_load
    x = cornering_stiffness / (tires.shape_c * d) * alpha
    return d * np.sin(tires.shape_c * np.arctan(x - tires.curvature_e * (x - np.arctan(x))))


def feedforward_ratio(speed: float, rear_steering: RearSteeringConfig) -> float:
    """Speed-scheduled rear / front wheel angle ratio k(v) [-] of the ECU table."""
    return float(np.interp(speed, rear_steering.table_speed_mps, rear_steering.table_ratio))


def rear_steering_command(
    front_wheel_angle: np.ndarray | float,
    yaw_rate: np.ndarray | float,
    speed: float,
    rear_steering: RearSteeringConfig,
) -> np.ndarray:
    """The ECU's angle-limited command delta_r,cmd [rad].

    delta_r,cmd = strength (k(v) (1 + g tanh(|r| / r_ref)) delta_f,ECU + k_r r) of the ECU's
    front wheel angle delta_f,ECU [rad] and the yaw rate r [rad/s], clipped to the angle
    limit. With g < 0 the in-phase ratio falls as the car turns harder, which offsets part
    of the tyres' growing understeer; the yaw-rate feedback (in-phase for k_r > 0) damps
    the yaw motion. (The integration loop inlines the same law for speed.)
    """
    ratio = rear_steering.strength * feedforward_ratio(speed, rear_steering)
    r = np.asarray(yaw_rate, dtype=float)
    modulation = 1.0 + rear_steering.yaw_rate_ratio_gain * np.tanh(
        np.abs(r) / rear_steering.yaw_rate_ref
    )
    command = ratio * modulation * np.asarray(front_wheel_angle, dtype=float)
    command = command + rear_steering.strength * rear_steering.yaw_rate_feedback_s * r
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
) -> TruthTrajectory:
    """Integrate the truth from rest (all states 0) for a steering-wheel angle [rad]."""
    front = front_wheel_angle(
        steering_wheel_angle, sample_rate_hz, vehicle.steering_ratio, steering
    )
    ecu_front = np.asarray(steering_wheel_angle, dtype=float) / vehicle.steering_ratio
    rhs = _right_hand_side(vehicle, tires, relaxation, rear_steering)
    yaw, slip, accel, rear = _rk4(rhs, front.tolist(), ecu_front.tolist(), 1.0 / sample_rate_hz)
    return TruthTrajectory(front, np.array(rear), np.array(yaw), np.array(slip), np.array(accel))


def _right_hand_side(
    vehicle: VehicleParameters,
    tires: TireConfig,
    relaxation: RelaxationConfig,
    rear_steering: RearSteeringConfig,
) -> Callable[..., tuple[float, float, float, float, float, float]]:
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
    sin, atan, tanh = math.sin, math.atan, math.tanh

    def rhs(r, beta, alpha_f, alpha_r, delta_r, delta_f, delta_f_ecu):
        kin_f = delta_f - beta - lf_v * r  # kinematic slip angles
        kin_r = delta_r - beta + lr_v * r
        if relax:
            d_alpha_f = (kin_f - alpha_f) * rate_f
            d_alpha_r = (kin_r - alpha_r) * rate_r
        else:
            alpha_f, alpha_r, d_alpha_f, d_alpha_r = kin_f, kin_r, 0.0, 0.0
        if magic:
            x = b_f * alpha_f
            fyf = d_f * sin(shape * atan(x - curvature * (x - atan(x))))
            x = b_r * alpha_r
            fyr = d_r * sin(shape * atan(x - curvature * (x - atan(x))))
        else:
            fyf, fyr = cf * alpha_f, cr * alpha_r
        d_delta_r = 0.0
        if rws:
            cmd = ratio * (1.0 + gain * tanh(abs(r) / r_ref)) * delta_f_ecu + feedback * r
            cmd = limit if cmd > limit else (-limit if cmd < -limit else cmd)
            d_delta_r = (cmd - delta_r) * inv_tau
            if d_delta_r > rate_limit:
                d_delta_r = rate_limit
            elif d_delta_r < -rate_limit:
                d_delta_r = -rate_limit
        force = fyf + fyr
        return (
            (lf * fyf - lr * fyr) * inv_izz,
            force * inv_mv - r,
            d_alpha_f,
            d_alpha_r,
            d_delta_r,
            force * inv_m,
        )

    return rhs


def _rk4(rhs, front: list, ecu: list, h: float):
    """Classic RK4 from rest; returns yaw rate, side slip, a_y and rear angle per sample.

    The inputs are interpolated linearly within a step (midpoint = mean of the samples).
    """
    n = len(front)
    yaw, slip, accel, rear = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
    r = beta = af = ar = dr = 0.0
    h2, h6 = 0.5 * h, h / 6.0
    u1, e1 = front[0], ecu[0]
    for k in range(n):
        u0, e0 = u1, e1
        r1, b1, f1, g1, d1, ay = rhs(r, beta, af, ar, dr, u0, e0)
        yaw[k], slip[k], accel[k], rear[k] = r, beta, ay, dr
        if k == n - 1:
            break
        u1, e1 = front[k + 1], ecu[k + 1]
        um, em = 0.5 * (u0 + u1), 0.5 * (e0 + e1)
        r2, b2, f2, g2, d2, _ = rhs(
            r + h2 * r1, beta + h2 * b1, af + h2 * f1, ar + h2 * g1, dr + h2 * d1, um, em
        )
        r3, b3, f3, g3, d3, _ = rhs(
            r + h2 * r2, beta + h2 * b2, af + h2 * f2, ar + h2 * g2, dr + h2 * d2, um, em
        )
        r4, b4, f4, g4, d4, _ = rhs(
            r + h * r3, beta + h * b3, af + h * f3, ar + h * g3, dr + h * d3, u1, e1
        )
        r += h6 * (r1 + 2.0 * (r2 + r3) + r4)
        beta += h6 * (b1 + 2.0 * (b2 + b3) + b4)
        af += h6 * (f1 + 2.0 * (f2 + f3) + f4)
        ar += h6 * (g1 + 2.0 * (g2 + g3) + g4)
        dr += h6 * (d1 + 2.0 * (d2 + d3) + d4)
    return yaw, slip, accel, rear
