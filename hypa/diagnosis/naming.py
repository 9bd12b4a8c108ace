"""Step 2 of the diagnosis: name the cause(s) of the physics' error from a fixed catalogue.

Every candidate of :mod:`hypa.diagnosis.candidates` is fitted on the training records and
scored on the validation records by the held-out error of its free run,

    E(m) = Σ_val records Σ_k Σ_c w_c (ŷ_c,k - y_c,k)²,    w_c = 1 / var(y_c on train)   [-]

Greedy search: starting from the nominal model (error E0), fit every cause on top of the
current model (error E_cur), take the one with the largest penalized gain, adopt it if it is
significant, re-test the rest on top of it, and stop at the first best candidate that is not
(a weaker candidate is never adopted in place of a better one that failed). A candidate with
k parameters and held-out error E_c is **significant** if

1. its penalized gain  g = (E_cur - E_c) / E_cur - 0.02 k ≥ 0.05: after paying 2 % of the
   remaining error per parameter it still removes ≥ 5 % of it. The penalty decides between
   candidates that explain the same error (the ZOH's half-sample lag looks like a 16 ms dead
   time: ``discretization``, 0 parameters, beats ``input_delay``, 1), and the 5 % floor keeps
   crumbs of an imperfectly modelled first cause from being named as a second one;
2. its improvement beats noise: the per-sample loss differences d_k = loss_cur,k - loss_c,k,
   averaged over 1 s blocks (32 samples at 32 Hz, ~3x the yaw dynamics' memory, so block
   means are nearly independent), are centred above 0 by a one-sided Wilcoxon signed-rank
   test at p ≤ 0.01. A candidate that only fits noise scatters the block differences
   symmetrically around a value ≤ 0 (the test's null). Ranks, not a t statistic, because a
   real effect can be sporadic: saturation improves only the blocks with large |a_y|, and
   those few large values inflate the standard deviation of a t test (Diebold-Mariano)
   while every block that improves a little still counts for the rank test;
3. it explains ≥ 1 % of the baseline error E0 (only binds after a first adoption).

``none`` when no candidate passes on the nominal model: the physics explains the held-out
data as well as any catalogue extension can, i.e. down to the noise. The reported score of a
cause is the share of E0 it explains: (E_cur - E_c) / E0 at its adoption (the scores of the
named causes add up to the share the adopted model explains).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import wilcoxon

from hypa.data import Record
from hypa.diagnosis.candidates import catalogue
from hypa.diagnosis.model import STATES, ModelSpec, simulate_batch
from hypa.physics import VehicleParameters

PENALTY_PER_PARAMETER = 0.02  # [share of the remaining held-out error]
MIN_GAIN = 0.05  # [share of the remaining held-out error], after the penalty
MAX_P = 0.01  # one-sided p of the signed-rank test
MIN_SCORE = 0.01  # [share of the baseline held-out error]
BLOCK_S = 1.0  # [s] block length of the test
MAX_CAUSES = 4


@dataclass
class Diagnosis:
    """The named cause (``none`` if nothing is significant), its estimate, all significant
    causes (most important first) and every candidate's score, estimate and evidence."""

    cause: str
    estimate: dict
    causes: list[str]
    candidates: list[dict] = field(default_factory=list)
    baseline_error: float = 0.0  # E0 [-]

    def to_dict(self) -> dict:
        return {"cause": self.cause, "estimate": self.estimate, "causes": list(self.causes),
                "candidates": [dict(c) for c in self.candidates]}


def channel_weights(records: Sequence[Record]) -> np.ndarray:
    """w_c = 1 / var(y_c) over all records (2,) [1/unit²]."""
    y = np.concatenate([r.stack(STATES) for r in records])
    return 1.0 / np.var(y, axis=0)


def sample_losses(spec: ModelSpec, records: Sequence[Record], dt: float, weights: np.ndarray) -> list[np.ndarray]:
    """Σ_c w_c (ŷ_c,k - y_c,k)² per sample of each record's free run."""
    return [((simulate_batch([spec], r["steering_wheel_angle"], r.stack(STATES)[0], dt)[0]
              - r.stack(STATES)) ** 2) @ weights for r in records]


def improvement_p(before: list[np.ndarray], after: list[np.ndarray], block: int) -> float:
    """One-sided Wilcoxon signed-rank p of "the per-block loss differences are centred above 0"."""
    means = np.array([d[i:i + block].mean() for b, a in zip(before, after) for d in [b - a]
                      for i in range(0, len(d) - block + 1, block)])
    if means.size < 2 or not np.any(means):  # an unchanged model (e.g. a fitted delay of 0)
        return 1.0
    return float(wilcoxon(means, alternative="greater").pvalue)


def name_causes(train_records: Sequence[Record], val_records: Sequence[Record], vehicle: VehicleParameters,
                dt: float, hold: str = "zoh", rear_steering: str = "none") -> Diagnosis:
    """Name what the nominal physics gets wrong (see the module docstring for the rule).

    ``vehicle``: nominal parameters; ``dt`` [s]: sample time of the records; ``hold``: the
    nominal ``zoh`` / ``foh``; ``rear_steering``: ``none`` or ``fixed`` (δr = rws_ratio δf).
    """
    if rear_steering not in ("none", "fixed"):
        raise ValueError(f"rear_steering must be 'none' or 'fixed', got {rear_steering!r}")
    weights = channel_weights(train_records)
    block = max(2, int(round(BLOCK_S / dt)))
    current = ModelSpec(vehicle, hold=hold, rear_ratio=vehicle.rws_ratio if rear_steering == "fixed" else 0.0)
    losses = sample_losses(current, val_records, dt, weights)
    e0 = e_cur = float(sum(loss.sum() for loss in losses))
    adopted: list[dict] = []
    rejected: dict[str, dict] = {}
    for _ in range(MAX_CAUSES):
        tested = []
        for candidate in catalogue(current, dt, weights):
            if any(a["cause"] == candidate.cause for a in adopted):
                continue
            estimate = candidate.fit(train_records)
            assert candidate.spec is not None
            after = sample_losses(candidate.spec, val_records, dt, weights)
            e_c = float(sum(loss.sum() for loss in after))
            gain = (e_cur - e_c) / e_cur - PENALTY_PER_PARAMETER * candidate.n_params
            p = improvement_p(losses, after, block)
            row = {"cause": candidate.cause, "score": (e_cur - e_c) / e0, "estimate": estimate,
                   "evidence": (f"{candidate.summary()} explains {100 * (e_cur - e_c) / e0:.1f} % of the nominal "
                                f"held-out error ({100 * gain:.1f} % of the remaining error after the "
                                f"parameter penalty, p = {p:.1g})")}
            tested.append((gain, p, row, candidate.spec, after, e_c))
        for _, _, row, *_ in tested:
            rejected[row["cause"]] = row
        gain, p, row, spec, after, e_c = max(tested, key=lambda x: x[0])
        if gain < MIN_GAIN or p > MAX_P or row["score"] < MIN_SCORE:
            break
        current, losses, e_cur = spec, after, e_c
        adopted.append(row)
        rejected.pop(row["cause"])
    others = sorted(rejected.values(), key=lambda r: -r["score"])
    if not adopted:
        nrmse = np.sqrt(e0 / sum(len(r) for r in val_records) / len(STATES))
        none = {"cause": "none", "score": 0.0, "estimate": {},
                "evidence": (f"the nominal physics reaches a held-out NRMSE of {nrmse:.3f} and no catalogue "
                             "cause removes a significant share of its error")}
        return Diagnosis("none", {}, [], [none, *others], e0)
    return Diagnosis(adopted[0]["cause"], adopted[0]["estimate"], [a["cause"] for a in adopted],
                     [*adopted, *others], e0)
