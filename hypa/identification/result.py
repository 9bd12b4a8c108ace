"""What an identification found, and how it got there: the estimates with ± 1σ, the correlations,
convergence and warnings, as one line, markdown (``identification.md``) and JSON (``run.json``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hypa.reporting import markdown as md


@dataclass(frozen=True)
class Estimate:
    """One identified parameter [``unit``]: its start, its value and ± 1σ (``None``: undetermined)."""

    name: str
    unit: str
    initial: float
    value: float
    std: float | None
    bounds: tuple[float, float] | None = None


@dataclass
class Identification:
    """What the identification found, and how it got there (:mod:`hypa.identification.output_error`)."""

    estimates: tuple[Estimate, ...]
    correlation: list[list[float]]  # (p, p), NaN where a parameter is undetermined
    converged: bool
    message: str  # scipy's (or the time limit's) reason for stopping
    iterations: int  # Jacobians evaluated: accepted steps + 1
    evaluations: int  # model runs for residuals (Jacobian probes not counted)
    final_step: float  # the last accepted step, largest over parameters, in the fit's coordinates
    error_initial: float  # the cost V at the start: mean over outputs of 1 - R² on the fitted stretches
    error_final: float
    stretches: int
    samples: int  # predicted samples per output
    seconds: float
    warnings: tuple[str, ...] = field(default_factory=tuple)
    shooting: str = "single"  # single: one free run per record; multiple: stretches joined by continuity
    continuity_defect: float = 0.0  # RMS of the junctions' state defects at the end [state std] (multiple)
    correlation_times: dict[str, float] = field(default_factory=dict)  # [samples] per parameter (see identify)
    capped: str | None = None  # the cap it stopped at, not converged: max_evaluations or max_seconds

    def values(self) -> dict[str, float]:
        return {e.name: e.value for e in self.estimates}

    def to_dict(self) -> dict:
        """The JSON form (``run.json``'s ``identification``)."""
        return {"converged": self.converged, "message": self.message, "iterations": self.iterations,
                "evaluations": self.evaluations, "final_step": self.final_step,
                "error": {"initial": self.error_initial, "final": self.error_final},
                "stretches": self.stretches, "samples": self.samples, "seconds": self.seconds,
                "shooting": self.shooting, "continuity_defect": self.continuity_defect,
                "correlation_time_samples": self.correlation_times,
                "parameters": {e.name: {"unit": e.unit, "initial": e.initial, "value": e.value, "std": e.std}
                               for e in self.estimates},
                "correlation": {"names": [e.name for e in self.estimates], "matrix": self.correlation},
                "warnings": list(self.warnings), "capped": self.capped}

    def summary(self) -> str:
        """One line: the error before and after, convergence, and how many warnings."""
        state = ("converged" if self.converged
                 else f"stopped at the cap of identification.{self.capped} (not converged)" if self.capped
                 else "did NOT converge")
        runs = f"{self.stretches} free run(s)" if self.shooting == "single" else (
            f"{self.stretches} stretches by multiple shooting "
            f"(continuity defects {self.continuity_defect:.2g} state std)")
        return (f"identified {len(self.estimates)} parameter(s) on {runs}: output error "
                f"{100 * self.error_initial:.3g} % -> {100 * self.error_final:.3g} % of the output variance, "
                f"{state} after {self.iterations} iteration(s), {self.seconds:.1f} s"
                + (f"; {len(self.warnings)} warning(s)" if self.warnings else ""))

    def _tau(self, name: str) -> str:
        tau = self.correlation_times.get(name)
        return "–" if tau is None else f"{tau:.3g}"

    def markdown(self) -> str:
        """The report: the estimates with ± 1σ, the correlations, convergence and warnings."""
        lines = ["## Identification", "", self.summary() + f" ({self.message}; last step {self.final_step:.2g}).", "",
                 ("± 1σ counts the output errors as correlated over τ samples (the errors weighted by each "
                 "parameter's sensitivity), not as independent."), "",
                 *md.table(["parameter", "start", "identified", "± 1σ", "unit", "τ [samples]"],
                           [[e.name, f"{e.initial:.4g}", f"{e.value:.4g}",
                             "undetermined" if e.std is None else f"{e.std:.3g}", e.unit, self._tau(e.name)]
                            for e in self.estimates])]
        if len(self.estimates) > 1:
            names = [e.name for e in self.estimates]
            lines += ["", "Correlations of the estimates:", "",
                      *md.table(["", *names], [[name, *("–" if math.isnan(v) else f"{v:+.2f}" for v in row)]
                                               for name, row in zip(names, self.correlation)])]
        if self.warnings:
            lines += ["", "Warnings:", ""] + [f"- {w}" for w in self.warnings]
        return "\n".join(lines) + "\n"
