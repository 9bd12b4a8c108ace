"""An FMU as physics (``hypa.physics.fmu``): read through its model description, run on a data grid by model
exchange (hypa integrates) or co-simulation (it steps itself), against fmpy's own simulation and exact references."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from hypa.physics.fmu import FMUError, FMUSimulator, read_fmu  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")


@pytest.fixture(scope="module")
def native(tmp_path_factory, hypa_cache) -> Path:
    """hypa's own native.fmu of a tiny physical run (format=c): a discrete-time FMU, co-simulation and model
    exchange, with no continuous states."""
    from test_export import TINY, _train

    from cli_helpers import hypa_run

    folder = _train(tmp_path_factory, "physical", ["model=physical", *TINY, "identification.max_seconds=5"])
    out = tmp_path_factory.mktemp("export")
    result = hypa_run(["export", f"run={folder}", "format=c", f"hydra.run.dir={out}"])
    assert result.returncode == 0, result.stderr[-3000:]
    return out


def test_hypa_s_own_native_fmu_read_back_gives_the_free_run(native) -> None:
    """A physics class exported as native.fmu and run as an FMU (co-simulation: it has no continuous states)
    from its initial state gives hypa's float64 free run of the reference record."""
    description = json.loads((native / "export.json").read_text())
    fmu = read_fmu(native / "native.fmu")
    assert fmu.input_names == tuple(s["name"] for s in description["inputs"])
    assert fmu.output_names == ("yaw_rate", "side_slip") and not fmu.states
    assert fmu.interface() == "co_simulation"  # discrete: it steps itself
    units = {p.name: p.unit for p in fmu.parameters}
    assert units["initial_state[1]"] == "rad/s"
    table = np.genfromtxt(native / "reference_float64.csv", delimiter=",", names=True)
    first = description["reference"]["first_sample"]
    u = np.stack([table[n][first:] for n in fmu.input_names], -1)
    expected = np.stack([table[n][first:] for n in fmu.output_names], -1)
    start = {f"initial_state[{i + 1}]": v for i, v in enumerate(description["c"]["initial_state"])}
    simulator = FMUSimulator(fmu)
    try:
        run = simulator.run(start, fmu.input_names, u, float(table["time"][first]), description["dt"])
        again = simulator.run(start, fmu.input_names, u[:50], float(table["time"][first]), description["dt"])
    finally:
        simulator.close()
    std = np.array([description["checks"]["c"]["outputs"][n]["std"] for n in fmu.output_names])
    assert (np.abs(run.y - expected).max(0) / std < 1e-9).all()
    np.testing.assert_array_equal(again.y, run.y[:50])  # a second run on the same instance starts afresh
    assert run.x is None


def test_refusals_are_one_line(tmp_path, native) -> None:
    bomb = tmp_path / "bomb.fmu"
    bomb.write_bytes(b"not a zip")
    with pytest.raises(FMUError, match="not a zip archive"):
        read_fmu(bomb)
    with pytest.raises(FMUError, match="no such file"):
        read_fmu(tmp_path / "missing.fmu")
    fmu = read_fmu(native / "native.fmu")
    with pytest.raises(FMUError, match=r"\['nope'\] are not its Real parameters"):
        fmu.parameter_specs({"nope": 1.0})
    with pytest.raises(FMUError, match="interface=both is not one of"):
        fmu.interface("both")
