"""An independent reference for the vehicle's composition: the steering gains and the single track
as ``LTIBlock``s wired by hand (no ``ComposedModel``), so tests can check the composed models and
the evaluation against it."""

from __future__ import annotations

import numpy as np
import torch

from hypa.physics import LTIBlock
from hypa.vehicle.physics import SingleTrack, SteeringGain, VehicleParameters, vehicle_parameters

REAR_STEERING = ("fixed", "none")


def simulate_vehicle(
    vehicle: VehicleParameters,
    steering_wheel_angle: np.ndarray,
    initial_state: np.ndarray,
    dt: float,
    hold: str = "zoh",
    rear_steering: str = "fixed",
    horizon: int = 100,
) -> np.ndarray:
    """Free-running nominal physics in SI units.

    steering_wheel_angle: (B, L) [rad]; initial_state: (B, 2) [yaw_rate rad/s, side_slip rad].
    ``rear_steering``: ``fixed`` (δr = rws_ratio δf) or ``none`` (front steering only).
    Returns (B, L, 2) states with sample 0 = ``initial_state``.
    """
    if rear_steering not in REAR_STEERING:
        raise ValueError(f"rear_steering must be one of {REAR_STEERING}, got {rear_steering!r}")
    params = vehicle_parameters(vehicle)
    with_rear = rear_steering == "fixed"
    track = LTIBlock(SingleTrack(rear_steering=with_rear), params, dt, horizon, hold=hold)
    track.check_stable()
    swa = torch.as_tensor(np.asarray(steering_wheel_angle, dtype=np.float64))[..., None]  # (B, L, 1)
    axles = ("front", "rear") if with_rear else ("front",)
    wheel_angles = torch.cat([LTIBlock(SteeringGain(a), params, dt, horizon)(None, swa) for a in axles], dim=-1)
    if hold == "zoh":
        wheel_angles = wheel_angles[:, :-1]  # the last sample only matters to a first-order hold
    x0 = torch.as_tensor(np.asarray(initial_state, dtype=np.float64))
    with torch.no_grad():
        states = track(x0, wheel_angles)  # (B, L-1, 2)
    return torch.cat([x0[:, None], states], dim=1).numpy()
