"""Diagnosis of any system: what the nominal physics gets wrong, the named causes, the gain.

    from hypa.diagnosis import Diagnosis, Problem, diagnose_system, load_catalogue, name_causes
    problem = Problem(dm, physical_values)              # the data and the fixed settings
    search = name_causes(nominal_spec, problem)          # the greedy search over the catalogue
    result = diagnose_system(nominal_spec, problem, out)  # a Diagnosis, written as diagnosis.md / .json
    result = Diagnosis.from_json(out / "diagnosis.json")  # read back

A candidate cause is an edit of the nominal hypa model (:mod:`hypa.diagnosis.edits`), listed by
the YAML catalogues (:mod:`hypa.diagnosis.catalogue`), fitted and scored with the one physics
engine (:mod:`hypa.diagnosis.finding`), raced round by round (:mod:`hypa.diagnosis.race`),
cross-validated over folds (:mod:`hypa.diagnosis.cross_validation`) and named by a greedy
search (:mod:`hypa.diagnosis.search`); what remains is tested for structure
(:mod:`hypa.diagnosis.structure`).
"""

from hypa.diagnosis.api import diagnose_system
from hypa.diagnosis.catalogue import CatalogueError, Entry, load_catalogue
from hypa.diagnosis.edits import Candidate
from hypa.diagnosis.finding import Finding
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.result import Diagnosis
from hypa.diagnosis.search import Search, name_causes

__all__ = ["Candidate", "CatalogueError", "Diagnosis", "Entry", "Finding", "Problem", "Search", "diagnose_system",
           "load_catalogue", "name_causes"]
