"""Figures without pyplot: importing hypa chooses no matplotlib backend, and its figures save headless."""

import os
import subprocess
import sys

import numpy as np

from hypa.reporting.figures import subplots, time_series


def test_importing_hypa_leaves_the_matplotlib_backend_alone(tmp_path):
    """A notebook's or a GUI's backend is its own: no hypa module picks one on import, and a
    figure hypa makes is saved to PNG without one (on a machine without a screen)."""
    code = (
        "import matplotlib\n"
        "import hypa, hypa.reporting.figures, hypa.evaluation.figures, hypa.explain.figures\n"
        "import hypa.diagnosis.api, hypa.training\n"
        "assert matplotlib.rcParams._get_backend_or_none() is None, matplotlib.rcParams._get_backend_or_none()\n"
        "import numpy as np\n"
        "from hypa.reporting.figures import time_series\n"
        f"time_series(np.arange(5.0), {{'y': np.zeros(5)}}, {{'m': {{'y': np.ones(5)}}}})"
        f".savefig({str(tmp_path / 'f.png')!r})\n"
        "assert matplotlib.rcParams._get_backend_or_none() is None\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MPLBACKEND", "DISPLAY")}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, timeout=120)
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_figures_are_not_kept_by_pyplot():
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    _fig, axes = subplots(2, 1, figsize=(4, 3))
    fig2 = time_series(np.arange(3.0), {"y": np.zeros(3)}, {"m": {"y": np.ones(3)}}, units={"y": "m"})
    assert len(axes) == 2 and fig2.axes and plt.get_fignums() == before
