"""How results are shown: numbers with their units, Markdown tables and figures.

- :mod:`hypa.reporting.markdown`: every report's tables and rounded numbers;
- :mod:`hypa.reporting.plots`: figures without pyplot's global state.
"""
