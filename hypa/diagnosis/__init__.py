"""Diagnosis of any system: what the nominal physics gets wrong, the named causes, the gain.

    from hypa.diagnosis import Problem, diagnose_system, load_catalogue, name_causes
    problem = Problem(dm, physical_values)              # the data and the fixed settings
    search = name_causes(nominal_spec, problem)          # the greedy search over the catalogue
    result = diagnose_system(nominal_spec, problem, out)  # the report: diagnosis.md / .json

A candidate cause is an edit of the nominal hypa model (:mod:`hypa.diagnosis.edits`), listed by
the YAML catalogues (:mod:`hypa.diagnosis.catalogue`), fitted and scored with the one physics
engine (:mod:`hypa.diagnosis.engine`); what remains is tested for structure
(:mod:`hypa.diagnosis.structure`).
"""

from hypa.diagnosis.catalogue import CatalogueError, Entry, load_catalogue
from hypa.diagnosis.edits import Candidate
from hypa.diagnosis.engine import Finding, Problem, Search, name_causes
from hypa.diagnosis.system import diagnose_system

__all__ = ["Candidate", "CatalogueError", "Entry", "Finding", "Problem", "Search", "diagnose_system",
           "load_catalogue", "name_causes"]
