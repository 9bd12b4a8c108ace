"""The nominal vehicle physics simulated on measured data, and how far off it is
(``python -m hypa.simulate``).

The physics (steering-wheel angle -> front (and fixed-ratio rear) wheel angle -> linear single
track) runs two ways on each validation record: windowed, 100 steps from each measured initial
state as in training (the lifted form, eq. 11), and free-running over the whole record from
its first sample (windows chained through their last state).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import torch

from hypa.errors import UserError
from hypa.physics import LTIBlock
from hypa.vehicle.display import DEG, DISPLAY_UNITS
from hypa.vehicle.physics import SingleTrack, SteeringGain, VehicleParameters, vehicle_parameters

log = logging.getLogger(__name__)

STATES = ("yaw_rate", "side_slip")
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


def fit_metrics(measured: np.ndarray, simulated: np.ndarray) -> dict[str, float]:
    """RMSE, mean error, R² = 1 - SSE/SST and NRMSE = RMSE/σ(measured) of one channel."""
    error = simulated - measured
    rmse = float(np.sqrt(np.mean(error**2)))
    sst = float(np.sum((measured - measured.mean()) ** 2))
    return {"rmse": rmse, "mean_error": float(error.mean()), "r2": 1.0 - float(np.sum(error**2)) / sst,
            "nrmse": rmse / float(measured.std())}


def _windowed(dm, vehicle: VehicleParameters, hold: str, rear: str) -> dict[str, dict[str, float]]:
    """Metrics over all validation windows (N steps from each measured initial state)."""
    norm, measured, simulated = dm.normalization, [], []
    swa, states = dm.input_names.index("steering_wheel_angle"), [dm.output_names.index(s) for s in STATES]
    for batch in dm.val_dataloader():
        u = norm.denormalize(batch["u"].double(), dm.input_names).numpy()[..., swa]
        y = norm.denormalize(batch["y"].double(), dm.output_names).numpy()[..., states]
        simulated.append(simulate_vehicle(vehicle, u, y[:, 0], dm.dt, hold, rear)[:, 1:])
        measured.append(y[:, 1:])
    measured, simulated = np.concatenate(measured), np.concatenate(simulated)
    return {s: fit_metrics(measured[..., i].ravel(), simulated[..., i].ravel()) for i, s in enumerate(STATES)}


def report(results: dict, hold: str, rear: str) -> str:
    lines = [f"nominal physics (hold={hold}, rear_steering={rear}) against the validation data:",
             f"{'':<26}{'channel':<12}{'RMSE':>14}{'mean err':>14}{'R2':>8}{'NRMSE':>8}"]
    for label, metrics in results.items():
        for channel, m in metrics.items():
            unit, k = DISPLAY_UNITS[channel], DEG
            lines.append(f"{label:<26}{channel:<12}{m['rmse'] * k:>8.3f} {unit:<5}{m['mean_error'] * k:>8.3f} "
                         f"{unit:<5}{m['r2']:>8.3f}{m['nrmse']:>8.3f}")
    return "\n".join(lines)


def simulate_records(dm, vehicle: VehicleParameters, hold: str, rear: str, out: Path, plot: bool = True) -> dict:
    """Windowed and free-run metrics of the nominal physics on ``dm``'s validation records
    (``simulation.json`` and, with ``plot``, a figure per record in ``out``); prints the report."""
    from hypa.plots import time_series

    if "steering_wheel_angle" not in dm.input_names or not set(STATES) <= set(dm.output_names):
        raise UserError(f"hypa.simulate runs the vehicle's single track: the data need the input "
                        f"steering_wheel_angle and the outputs {', '.join(STATES)}; these have the inputs "
                        f"{list(dm.input_names)} and the outputs {list(dm.output_names)}")
    dm.setup()
    results = {"windowed (100 steps)": _windowed(dm, vehicle, hold, rear)}
    for record in dm.records("val"):
        swa, y = record["steering_wheel_angle"], record.stack(STATES)
        sim = simulate_vehicle(vehicle, swa[None], y[None, 0], dm.dt, hold, rear)[0]
        results[f"free-run {record.name}"] = {s: fit_metrics(y[:, i], sim[:, i]) for i, s in enumerate(STATES)}
        if plot:
            fig = time_series(record.time, {s: y[:, i] for i, s in enumerate(STATES)},
                              {"physics": {s: sim[:, i] for i, s in enumerate(STATES)}},
                              units=DISPLAY_UNITS, scale={s: DEG for s in STATES},
                              title=f"nominal physics free-running over {record.name}")
            fig.savefig(out / f"free_run_{Path(record.name).stem}.png", dpi=110)
            log.info("figure: %s", out / f"free_run_{Path(record.name).stem}.png")
    (out / "simulation.json").write_text(json.dumps(results, indent=2))
    print(report(results, hold, rear))
    return results
