"""Step 1 of the diagnosis, as numbers: where and how the nominal physics misses the data.

The nominal physics (``hypa.simulate.simulate_vehicle``) free-runs over each record from its
first measured state; the residual is e = ŷ - y per state (yaw_rate [rad/s], side_slip [rad]).

* **error per channel**: mean(e), RMSE = √mean(e²), NRMSE = RMSE / std(y) [-];
* **error vs |a_y|**: RMSE of e in bins of the measured |lateral acceleration| [m/s²]; an
  error that grows with |a_y| points at saturation, a flat one at linear causes;
* **whiteness** (autocorrelation ρ_ee(τ), τ = 1..max_lag samples) and **independence**
  (cross-correlation ρ_ue(τ) of the steering-wheel angle u with e, τ = -max_lag..max_lag),
  each against the ~99 % band ±2.58 / √N (Ljung, System Identification, 16.6). The band is
  the large-N distribution of a sample correlation of *white* noise; it assumes a stationary
  residual and, for ρ_ue, that the residual is independent of u and at least one of the two
  is white. Our steering input is coloured (flat to ~1 Hz, 1/f² above), so even a correct
  model shows some ρ_ue outside the band when the residual is coloured too: read the
  fraction outside the band (~1 % for a perfect model and white noise) and the lag of the
  peak, not a single crossing. A peak of ρ_ue at a positive lag means the residual follows
  the input: missing input dynamics (delay, lag, a second actuator);
* **transfer function** δsw -> yaw rate: the H1 estimate from the measured data against the
  nominal model's analytic response, with the median gain ratio and phase difference over the
  coherent band (γ² ≥ 0.8; Welch segments of ≤ 16 s, at least 8 per record set).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hypa.data import Record
from hypa.diagnosis.model import STATES, continuous_matrices
from hypa.evaluation.transfer import TransferEstimate, frequency_response, h1_estimate
from hypa.vehicle import VehicleParameters
from hypa.simulate import simulate_vehicle

CONFIDENCE_Z = 2.58  # two-sided 99 % of a standard normal
AY_EDGES = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, np.inf)  # [m/s^2]
COHERENT = 0.8  # γ² above which the H1 estimate is trusted for the summary


@dataclass(frozen=True)
class Correlation:
    """Normalized correlation ρ(τ) at ``lags`` [samples], the ±``bound`` band and the share outside."""

    lags: np.ndarray
    rho: np.ndarray
    bound: float

    @property
    def outside(self) -> float:
        """Fraction of lags with |ρ| > bound (~1 % expected under the test's assumptions)."""
        return float(np.mean(np.abs(self.rho) > self.bound))

    @property
    def peak_lag(self) -> int:
        return int(self.lags[np.argmax(np.abs(self.rho))])


@dataclass(frozen=True)
class ResidualAnalysis:
    """Step 1 for a set of records (all arrays are per state unless named otherwise)."""

    channels: dict[str, dict[str, float]]  # state -> {"mean", "rmse", "nrmse"}
    ay_edges: np.ndarray  # (B+1,) [m/s^2]
    ay_rmse: dict[str, np.ndarray]  # state -> (B,) RMSE per |a_y| bin (NaN for an empty bin)
    ay_counts: np.ndarray  # (B,) samples per bin
    autocorrelation: dict[str, Correlation]
    cross_correlation: dict[str, Correlation]  # steering_wheel_angle vs each state's residual
    measured: TransferEstimate  # H1 δsw -> yaw rate [1/s]
    model: TransferEstimate  # analytic nominal response at the same frequencies
    gain_ratio: float  # median |H_measured| / |H_model| over the coherent band [-]
    phase_difference_deg: float  # median arg H_measured - arg H_model over the coherent band [deg]


def correlation(x: np.ndarray, y: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """ρ_xy(τ) = Σ_k x̃_k ỹ_{k+τ} / (N σ_x σ_y) of the mean-removed series (biased estimator)."""
    x, y = x - x.mean(), y - y.mean()
    n, scale = x.size, x.size * x.std() * y.std()
    if scale == 0:
        return np.zeros(lags.size)
    return np.array([np.dot(x[:n - t], y[t:]) if t >= 0 else np.dot(x[-t:], y[:n + t]) for t in lags]) / scale


def model_yaw_response(vehicle: VehicleParameters, frequency_hz: np.ndarray,
                       rear_steering: str = "none") -> np.ndarray:
    """Continuous nominal response δsw -> yaw rate [1/s]: δf = δsw / i_s (+ δr = rws_ratio δf)."""
    a, b = continuous_matrices(vehicle)
    rear = vehicle.rws_ratio if rear_steering == "fixed" else 0.0
    b_sw = (b[:, :1] + rear * b[:, 1:]) / vehicle.steering_ratio
    return frequency_response(a, b_sw, np.eye(2)[:1], np.zeros((1, 1)), frequency_hz)[:, 0, 0]


def analyze_residuals(records: Sequence[Record], vehicle: VehicleParameters, dt: float, hold: str = "zoh",
                      rear_steering: str = "none", max_lag: int = 64,
                      ay_edges: Sequence[float] = AY_EDGES) -> ResidualAnalysis:
    """Step 1 over ``records`` (decimated, SI); ``max_lag`` [samples] of the correlations.

    Records are analysed together: correlations and H1 run over the records joined end to
    end (each junction adds one short glitch, negligible over minutes of data). |a_y| comes
    from the ``lateral_acceleration`` channel, or, where a record lacks it, from
    v (β̇ + r) of the measured states.
    """
    measured, simulated, swa, ay = [], [], [], []
    for r in records:
        y = r.stack(STATES)
        u = r["steering_wheel_angle"]
        simulated.append(simulate_vehicle(vehicle, u[None], y[None, 0], dt, hold, rear_steering)[0])
        measured.append(y)
        swa.append(u)
        ay.append(r["lateral_acceleration"] if "lateral_acceleration" in r
                  else vehicle.velocity * (np.gradient(y[:, 1], dt) + y[:, 0]))
    y, y_sim, u, ay = (np.concatenate(v) for v in (measured, simulated, swa, ay))
    error = y_sim - y
    channels = {s: {"mean": float(error[:, i].mean()), "rmse": float(np.sqrt(np.mean(error[:, i] ** 2))),
                    "nrmse": float(np.sqrt(np.mean(error[:, i] ** 2)) / y[:, i].std())} for i, s in enumerate(STATES)}
    edges = np.asarray(ay_edges, dtype=float)
    bins = np.digitize(np.abs(ay), edges[1:-1])
    counts = np.bincount(bins, minlength=edges.size - 1)
    with np.errstate(invalid="ignore"):
        ay_rmse = {s: np.sqrt(np.bincount(bins, error[:, i] ** 2, minlength=edges.size - 1) / counts)
                   for i, s in enumerate(STATES)}
    bound = CONFIDENCE_Z / np.sqrt(error.shape[0])
    auto_lags, cross_lags = np.arange(1, max_lag + 1), np.arange(-max_lag, max_lag + 1)
    auto = {s: Correlation(auto_lags, correlation(error[:, i], error[:, i], auto_lags), bound)
            for i, s in enumerate(STATES)}
    cross = {s: Correlation(cross_lags, correlation(u, error[:, i], cross_lags), bound) for i, s in enumerate(STATES)}
    # ≥ ~15 Welch averages: with a handful, γ² is biased high and a bin without input power can look coherent
    h1 = h1_estimate(u, y[:, 0], 1.0 / dt, segment_s=min(16.0, u.size * dt / 8))
    model = TransferEstimate.analytic(h1.frequency_hz, model_yaw_response(vehicle, h1.frequency_hz, rear_steering))
    good = h1.coherence >= COHERENT
    relative = h1.response[good] / model.response[good] if good.any() else np.array([np.nan])
    ratio, phase = float(np.median(np.abs(relative))), float(np.degrees(np.median(np.angle(relative))))
    return ResidualAnalysis(channels, edges, ay_rmse, counts, auto, cross, h1, model, ratio, phase)
