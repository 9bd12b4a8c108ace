"""Shared fixtures and constants: a short test-bench data set in a per-session cache (never the user's
cache), the repository's root, and the real data sets beside it.

The tests mirror hypa's layers (tests/core, tests/physics, ..., tests/commands, tests/docs). This file,
``data_helpers.py``, ``vehicle_reference.py`` and ``cli_helpers.py`` (``hypa_run``: a command run in the
test's process, in place of a ``python -m hypa`` child) stay at tests/, which is on ``sys.path`` with every
layer's folder (``pythonpath`` in pyproject.toml): ``from data_helpers import ...`` and a test module
reusing another's system (``from test_identification_tanks import SYSTEM``) work from any folder, in
any order, and in a file run alone.

A test that composes a command's configuration itself does it as the command does, the schemas and
resolvers registered first: :func:`compose_config` (nothing registers them on import, so a test file
passes alone too).

Tests marked ``shared_data`` read the real data sets in ../shared/data (beside the repository, see
``SHARED_DATA``). Without them such a test fails with one line saying where they belong; set
``HYPA_SKIP_SHARED_DATA=1`` to skip those tests instead (a machine that has no copy of the data).
"""

import os
import signal
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]  # the repository
SHARED_DATA = ROOT.parent / "shared" / "data"  # the real data sets, as conf/dataset/*.yaml name them

SHORT_RECORDS = {
    "train_1": {"seed": 1, "stochastic_duration_s": 40.0, "break_frequency_hz": 1.0, "maneuvers": []},
    "train_2": {"seed": 2, "stochastic_duration_s": 40.0, "break_frequency_hz": 1.0, "maneuvers": []},
    "val": {"seed": 3, "stochastic_duration_s": 30.0, "break_frequency_hz": 0.8, "maneuvers": []},
}
# The same records as Hydra overrides, for tests that run the command line.
SHORT_OVERRIDES = [f"testbench.records.{name}.{key}={value}" for name, record in SHORT_RECORDS.items()
                   for key, value in record.items() if key != "maneuvers"]


def compose_config(config_name: str | None, overrides: Sequence[str] = (), config_dir: Path | None = None,
                   **kwargs: Any) -> Any:
    """``hydra.compose`` of ``config_name`` over ``config_dir`` (the package's ``conf/`` by default) as a
    command composes it: after :func:`hypa.commands.config.register_configs` (the schemas and resolvers).
    ``kwargs``: further arguments of ``compose`` (``return_hydra_config=True``)."""
    from hydra import compose, initialize_config_dir

    from hypa.commands.config import register_configs
    from hypa.conf import CONF

    register_configs()
    with initialize_config_dir(config_dir=str(config_dir or CONF), version_base="1.3"):
        return compose(config_name=config_name, overrides=list(overrides), **kwargs)


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


@pytest.fixture(autouse=True)
def _ctrl_c_as_it_was():
    """A command run in this process that ends on a Ctrl-C ignores further ones (hypa.core.errors), and
    the diagnosis's workers hold SIGINT while they fork: each test leaves SIGINT's handler as it found
    it, and SIGINT unblocked, so neither reaches a process that a later test starts."""
    handler = signal.getsignal(signal.SIGINT)
    yield
    signal.signal(signal.SIGINT, handler)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A test marked ``shared_data`` (or ``shared_data("racecar")``, one data set's folder) fails in one
    line when ../shared/data lacks what it reads, or skips where ``HYPA_SKIP_SHARED_DATA=1`` asks to."""
    for marker in item.iter_markers("shared_data"):
        folder = SHARED_DATA.joinpath(*marker.args)
        if folder.is_dir():
            continue
        if os.environ.get("HYPA_SKIP_SHARED_DATA") == "1":
            pytest.skip(f"{folder} is missing (HYPA_SKIP_SHARED_DATA=1)")
        pytest.fail(f"the real data are missing: {folder} (../shared/data beside the repository); "
                    "put them there, or set HYPA_SKIP_SHARED_DATA=1 to skip the tests that read them", pytrace=False)
