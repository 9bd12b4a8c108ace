"""Step 3 of the diagnosis: apply the named causes to the nominal physics and measure the gain.

Every catalogue cause is a knob of :class:`~hypa.diagnosis.model.ModelSpec`, so the extended
model is the nominal spec with each adopted cause's (jointly re-fitted) estimate turned on;
the fast numpy model simulates it. The gain compares nominal and extended free runs over the
validation records (held out from the fit), per state, overall, and where |a_y| is large.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hypa.data import Record
from hypa.diagnosis.model import STATES, ModelSpec, simulate_batch, wheel_angles
from hypa.diagnosis.naming import Diagnosis
from hypa.evaluation.metrics import state_metrics
from hypa.evaluation.transfer import TransferEstimate, h1_estimate


def apply_cause(spec: ModelSpec, cause: str, estimate: Mapping) -> ModelSpec:
    """``spec`` with one catalogue cause's estimate (SI units, as ``name_causes`` reports it) on."""
    if cause == "parameter_mismatch":
        return spec.with_vehicle(**{estimate["parameter"]: float(estimate["value"])})
    if cause == "input_delay":
        return spec.replace(delay_s=float(estimate["delay_s"]))
    if cause == "unmodeled_lag":
        return spec.replace(lag_tau_s=float(estimate["tau_s"]))
    if cause == "sensor_offset":
        return spec.with_offset(estimate["channel"], float(estimate["offset"]))
    if cause == "discretization":
        return spec.replace(hold=str(estimate.get("hold", "foh")))
    if cause == "saturation":
        return spec.replace(mu=float(estimate["mu"]))
    if cause == "unmodeled_input":
        return spec.replace(rear_ratio=float(estimate["ratio"]), rear_tau_s=float(estimate["tau_s"]))
    raise ValueError(f"unknown cause {cause!r}")


def extended_spec(nominal: ModelSpec, diagnosis: Diagnosis) -> ModelSpec:
    """The nominal spec with every named cause of ``diagnosis`` applied (``nominal`` for ``none``)."""
    spec = nominal
    for row in diagnosis.named:
        spec = apply_cause(spec, row["cause"], row["estimate"])
    return spec


@dataclass(frozen=True)
class FreeRuns:
    """Measured and simulated validation data joined end to end (records in order)."""

    time: np.ndarray  # (T,) [s], restarting at each record
    steering_wheel_angle: np.ndarray  # (T,) [rad]
    measured: np.ndarray  # (T, 2) [rad/s, rad]
    simulated: dict[str, np.ndarray]  # model name -> (T, 2)
    abs_ay: np.ndarray  # (T,) measured |lateral acceleration| [m/s²]
    record_ends: np.ndarray  # (R,) index after each record's last sample


def free_runs(models: Mapping[str, ModelSpec], records: Sequence[Record], dt: float, velocity: float) -> FreeRuns:
    """Free-run each model over each record from its first measured state.

    |a_y| comes from ``lateral_acceleration`` or, lacking it, v (β̇ + r) of the measured states.
    """
    names, specs = list(models), list(models.values())
    time, swa, measured, ay, ends = [], [], [], [], []
    sims: list[np.ndarray] = []
    for record in records:
        y = record.stack(STATES)
        sims.append(simulate_batch(specs, record["steering_wheel_angle"], y[0], dt))  # (K, L, 2)
        time.append(np.arange(len(record)) * dt)
        swa.append(record["steering_wheel_angle"])
        measured.append(y)
        ay.append(record["lateral_acceleration"] if "lateral_acceleration" in record
                  else velocity * (np.gradient(y[:, 1], dt) + y[:, 0]))
        ends.append(sum(len(t) for t in time))
    joined = np.concatenate(sims, axis=1)
    return FreeRuns(np.concatenate(time), np.concatenate(swa), np.concatenate(measured),
                    {n: joined[i] for i, n in enumerate(names)}, np.abs(np.concatenate(ay)), np.asarray(ends))


def gain_metrics(runs: FreeRuns, high_ay: float, ay_edges: Sequence[float]) -> dict:
    """Per model: ``state_metrics`` over all samples and over |a_y| ≥ ``high_ay`` [m/s²] (None if
    fewer than 32 such samples), and the RMSE per state in each |a_y| bin of ``ay_edges``."""
    edges = np.asarray(ay_edges, dtype=float)
    bins = np.digitize(runs.abs_ay, edges[1:-1])
    high = runs.abs_ay >= high_ay
    result: dict = {"high_ay_threshold": float(high_ay), "high_ay_samples": int(high.sum()),
                    "ay_edges": [float(e) for e in edges], "models": {}}
    for name, sim in runs.simulated.items():
        entry = {"all": state_metrics(sim, runs.measured, STATES),
                 "high_ay": state_metrics(sim[high], runs.measured[high], STATES) if high.sum() >= 32 else None,
                 "ay_bin_rmse": {}}
        for i, state in enumerate(STATES):
            sq = (sim[:, i] - runs.measured[:, i]) ** 2
            entry["ay_bin_rmse"][state] = [float(np.sqrt(sq[bins == b].mean())) if np.any(bins == b) else None
                                           for b in range(edges.size - 1)]
        result["models"][name] = entry
    return result


def relative_change(before: dict, after: dict) -> dict:
    """(after - before) / before of the MSE per state and overall: -0.4 = 40 % less squared error."""
    return {state: (after[state]["mse"] - before[state]["mse"]) / before[state]["mse"]
            for state in before if before[state]["mse"] > 0}


def transfer_functions(runs: FreeRuns, dt: float) -> dict[str, TransferEstimate]:
    """H1 δsw -> yaw rate of the measurement and of each model's free run on the same input
    (Welch segments of ≤ 16 s, ≥ 8 per data set, as in step 1)."""
    segment = min(16.0, runs.time.size * dt / 8)
    u = runs.steering_wheel_angle
    estimates = {"measured": h1_estimate(u, runs.measured[:, 0], 1.0 / dt, segment_s=segment)}
    for name, sim in runs.simulated.items():
        estimates[name] = h1_estimate(u, sim[:, 0], 1.0 / dt, segment_s=segment)
    return estimates


def recovered_rear_angle(spec: ModelSpec, record: Record, dt: float) -> np.ndarray:
    """The rear-wheel angle δr [rad] the extended model applies over ``record``."""
    return wheel_angles(spec, record["steering_wheel_angle"], dt)[:, 1]


def rear_angle_agreement(recovered: np.ndarray, measured: np.ndarray) -> dict[str, float]:
    """Correlation [-] and RMSE [rad] of the recovered against the measured rear-wheel angle."""
    rmse = float(np.sqrt(np.mean((recovered - measured) ** 2)))
    if np.std(recovered) == 0 or np.std(measured) == 0:
        return {"correlation": float("nan"), "rmse": rmse}
    return {"correlation": float(np.corrcoef(recovered, measured)[0, 1]), "rmse": rmse}
