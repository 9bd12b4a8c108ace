"""How results are shown: numbers with their units, Markdown tables and figures.

- :mod:`hypa.reporting.markdown`: every report's tables and rounded numbers;
- :mod:`hypa.reporting.figures`: figures without pyplot's global state.
"""
