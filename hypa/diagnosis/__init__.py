"""Diagnosis: what the nominal physics gets wrong (residuals, step 1) and why (naming, step 2).

    from hypa.diagnosis import analyze_residuals, name_causes
    step1 = analyze_residuals(dm.records("val"), vehicle, dm.dt, hold="zoh")
    diagnosis = name_causes(dm.records("train"), dm.records("val"), vehicle, dm.dt, hold="zoh")
    diagnosis.to_dict()   # {"cause", "estimate", "causes", "candidates": [{"cause", "score", "estimate", "evidence"}]}
"""

from hypa.diagnosis.candidates import CATALOGUE, Candidate
from hypa.diagnosis.model import ModelSpec, ay_threshold, simulate_batch
from hypa.diagnosis.naming import Diagnosis, name_causes
from hypa.diagnosis.residuals import ResidualAnalysis, analyze_residuals

CAUSES: tuple[str, ...] = ("none", *CATALOGUE)

__all__ = ["CATALOGUE", "CAUSES", "Candidate", "Diagnosis", "ModelSpec", "ResidualAnalysis", "analyze_residuals",
           "ay_threshold", "name_causes", "simulate_batch"]
