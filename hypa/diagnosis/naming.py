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
from hypa.diagnosis.candidates import CATALOGUE
from hypa.diagnosis.model import OFFSET_CHANNELS, STATES, ModelSpec, simulate_batch
from hypa.vehicle import VehicleParameters

PENALTY_PER_PARAMETER = 0.02  # [share of the remaining held-out error]
MIN_GAIN = 0.05  # [share of the remaining held-out error], after the penalty
MAX_P = 0.01  # one-sided p of the signed-rank test
MIN_SCORE = 0.01  # [share of the baseline held-out error]
BLOCK_S = 1.0  # [s] block length of the test
MAX_CAUSES = 4  # each round after a saturation is adopted runs the slow time loop: ~15 s more per round
POLISH_ROUNDS = 2  # more rounds for the reported estimates of several causes
JOINT_ROUNDS = 2  # coordinate-descent rounds over the adopted causes and the winner


@dataclass
class Diagnosis:
    """The named cause (``none`` if nothing is significant), its estimate, all significant
    causes (most important first) and every candidate's score, estimate and evidence."""

    cause: str
    estimate: dict
    causes: list[str]
    candidates: list[dict] = field(default_factory=list)
    baseline_error: float = 0.0  # E0 [-]

    @property
    def named(self) -> list[dict]:
        """The rows of the named causes, most important first (``sensor_offset`` once per channel)."""
        return [dict(c) for c in self.candidates[: len(self.causes)]]

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


def _refit_adopted(current: ModelSpec, adopted: list[dict], train_records: Sequence[Record], dt: float,
                   weights: np.ndarray, rounds: int) -> ModelSpec:
    """Coordinate descent over the adopted causes (each refit on top of the others, restricted to
    its parameter / channel); their rows get the refitted estimates."""
    for _ in range(rounds):
        for entry in adopted:
            refit = entry["kind"](current, dt, weights, entry["choice"])
            entry["row"]["estimate"] = refit.fit(train_records)
            entry["summary"] = refit.summary()
            current = refit.spec
    return current


def _row(cause: str, summary: str, e_cur: float, e_c: float, e0: float, gain: float, p: float) -> dict:
    return {"cause": cause, "score": (e_cur - e_c) / e0, "estimate": {},
            "evidence": summary + _tail(e_cur, e_c, e0, gain, p)}


def _tail(e_cur: float, e_c: float, e0: float, gain: float, p: float) -> str:
    return (f" explains {100 * (e_cur - e_c) / e0:.1f} % of the nominal held-out error "
            f"({100 * gain:.1f} % of the remaining error after the parameter penalty, p = {p:.1g})")


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

    def held_out(spec: ModelSpec, n_params: int) -> tuple[list[np.ndarray], float, float, float]:
        after = sample_losses(spec, val_records, dt, weights)
        e_c = float(sum(loss.sum() for loss in after))
        gain = (e_cur - e_c) / e_cur - PENALTY_PER_PARAMETER * n_params
        return after, e_c, gain, improvement_p(losses, after, block)

    def describe(candidate) -> str:
        text = candidate.summary()
        if candidate.cause == "parameter_mismatch":
            text += f" (nominal {getattr(vehicle, candidate.estimate['parameter']):.4g})"
        return text

    adopted: list[dict] = []  # {"row", "kind", "choice", "summary"} in order of adoption
    rows: dict[str, dict] = {}  # the latest test of every cause not adopted
    for _ in range(MAX_CAUSES):
        tested = []
        for cause, kind in CATALOGUE.items():
            biased = [a["choice"] for a in adopted if a["row"]["cause"] == "sensor_offset"]
            done = any(a["row"]["cause"] == cause for a in adopted) and not (
                cause == "sensor_offset" and len(biased) < len(OFFSET_CHANNELS))
            if done or (cause == "discretization" and current.hold == "foh"):
                continue
            candidate = kind(current, dt, weights, exclude=biased)
            candidate.fit(train_records)
            if cause == "discretization" and adopted:
                # The hold shifts the input by dt/2, which an adopted dead time or lag has absorbed
                # (a ZOH model fits a delay dt/2 short): the hold is only judged with them refitted.
                trial = [{**a, "row": dict(a["row"])} for a in adopted]
                candidate.spec = _refit_adopted(candidate.spec, trial, train_records, dt, weights, rounds=1)
            after, e_c, gain, p = held_out(candidate.spec, candidate.n_params)
            rows[cause] = {**_row(cause, describe(candidate), e_cur, e_c, e0, gain, p),
                           "estimate": candidate.estimate}
            tested.append((gain, candidate, after, e_c, p))
        if not tested:
            break
        gain, candidate, after, e_c, p = max(tested, key=lambda x: x[0])
        entry = {"row": rows[candidate.cause], "kind": type(candidate), "choice": candidate.choice(),
                 "summary": describe(candidate)}
        spec = candidate.spec
        if adopted and gain >= MIN_GAIN:
            # Refit the winner jointly with the adopted causes before testing it: a cause adopted
            # alone has absorbed part of the next one (a linear rear-steering ratio fitted on
            # saturating data is too low), so the next one alone is better at large |a_y| and
            # worse elsewhere, which can hide it from the rank test.
            trial = [{**a, "row": dict(a["row"])} for a in adopted] + [entry]
            spec = _refit_adopted(spec, trial, train_records, dt, weights, rounds=JOINT_ROUNDS)
            after, e_c, gain, p = held_out(spec, candidate.n_params)
            entry["row"] = {**_row(candidate.cause, entry["summary"], e_cur, e_c, e0, gain, p),
                            "estimate": trial[-1]["row"]["estimate"]}
        if gain < MIN_GAIN or p > MAX_P or entry["row"]["score"] < MIN_SCORE:
            break
        if adopted:
            for a, t in zip(adopted, trial):  # the joint fit's estimates are the better ones
                a["row"]["estimate"], a["summary"] = t["row"]["estimate"], t["summary"]
        rows.pop(candidate.cause)
        adopted.append({**entry, "tail": _tail(e_cur, e_c, e0, gain, p)})
        current, losses, e_cur = spec, after, e_c
    if len(adopted) > 1:  # polish the joint estimates (the held-out scores stay as tested)
        _refit_adopted(current, adopted, train_records, dt, weights, rounds=POLISH_ROUNDS)
    for a in adopted:
        a["row"]["evidence"] = a["summary"] + a["tail"]
    others = sorted(rows.values(), key=lambda r: -r["score"])
    named = [a["row"] for a in adopted]
    if not named:
        nrmse = np.sqrt(e0 / sum(len(r) for r in val_records) / len(STATES))
        none = {"cause": "none", "score": 0.0, "estimate": {},
                "evidence": (f"the nominal physics reaches a held-out NRMSE of {nrmse:.3f} and no catalogue "
                             "cause removes a significant share of its error")}
        return Diagnosis("none", {}, [], [none, *others], e0)
    return Diagnosis(named[0]["cause"], named[0]["estimate"], [r["cause"] for r in named], [*named, *others], e0)
