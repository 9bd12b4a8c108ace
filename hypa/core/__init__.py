"""The foundations every layer stands on, and which import nothing else of hypa.

- :mod:`hypa.core.errors`: one-line user errors and the commands' error handling;
- :mod:`hypa.core.trust`: the trust boundary (bounded reads, safe YAML, confined paths);
- :mod:`hypa.core.folders`: a folder held by one command (lock, no links inside, atomic writes);
- :mod:`hypa.core.metadata`: a run's provenance (``run.json``);
- :mod:`hypa.core.machine`: the memory this process may still allocate;
- :mod:`hypa.core.metrics`: the errors every report scores with (RMSE, R², mean ± std).
"""
