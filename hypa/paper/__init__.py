"""The paper's instance of hypa: what reproduces "HyPA-Net" on its own vehicle test bench.

- :mod:`hypa.paper.testbench`: the simulated vehicle test bench, the paper's data (``dataset=testbench``);
- :mod:`hypa.paper.table1`: the paper's Table 1 beside hypa's reproduction (``hypa reproduce``).

The generic library never imports this package. The data layer finds the test bench's data by
its entry point (``hypa.data_sources`` in pyproject.toml, :mod:`hypa.core.plugins`), as the physics finds the
vehicle's systems.
"""
