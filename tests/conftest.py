"""Shared fixtures: a short test-bench data set in a per-session cache (never the user's cache)."""

import os
from pathlib import Path

import pytest

SHORT_RECORDS = {
    "train_1": {"seed": 1, "stochastic_duration_s": 40.0, "break_frequency_hz": 1.0, "maneuvers": []},
    "train_2": {"seed": 2, "stochastic_duration_s": 40.0, "break_frequency_hz": 1.0, "maneuvers": []},
    "val": {"seed": 3, "stochastic_duration_s": 30.0, "break_frequency_hz": 0.8, "maneuvers": []},
}
# The same records as Hydra overrides, for tests that run the command line.
SHORT_OVERRIDES = [f"testbench.records.{name}.{key}={value}" for name, record in SHORT_RECORDS.items()
                   for key, value in record.items() if key != "maneuvers"]


@pytest.fixture(scope="session")
def hypa_cache(tmp_path_factory) -> Path:
    """A cache folder for generated data, shared by the whole test session."""
    path = tmp_path_factory.mktemp("hypa-cache")
    os.environ["HYPA_CACHE_DIR"] = str(path)
    return path


@pytest.fixture(autouse=True)
def _no_hydra_app_left_running():
    """A test that runs a command's ``main`` in this process leaves Hydra's run (its original working
    directory, its choices) set globally: the next test would read it (a relative ``data.dir`` taken
    from where that run started). Each test starts without one."""
    yield
    from hydra.core.hydra_config import HydraConfig

    HydraConfig.instance().cfg = None  # type: ignore[assignment]
