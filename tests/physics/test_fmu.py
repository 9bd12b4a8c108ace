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
    from cli_helpers import hypa_run
    from test_export import TINY, _train

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


FMU_MODEL = """# @package model
name: fmu_car
blocks:
  car:
    kind: physics
    fmu: car.fmu          # relative: the config directory's model/ folder
    inputs: [steering_wheel_angle]
    outputs: [yaw_rate, side_slip]
outputs: [yaw_rate, side_slip]
"""


def test_an_fmu_block_simulates_through_the_command_line(native, hypa_cache, tmp_path) -> None:
    """hypa simulate with a model whose physics is an FMU (hypa's own native.fmu of the physical run, named
    relative to the user's config directory): the free run over the validation data, the FMU's own start."""
    import os

    from cli_helpers import hypa_run

    conf = tmp_path / "conf"
    (conf / "model").mkdir(parents=True)
    shutil.copy(native / "native.fmu", conf / "model" / "car.fmu")
    (conf / "model" / "fmu_car.yaml").write_text(FMU_MODEL)
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    result = hypa_run(["simulate", "--config-dir", str(conf), "model=fmu_car", f"hydra.run.dir={tmp_path / 'sim'}"],
                      env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "the FMU (co simulation) starts from its own initialization" in result.stdout + result.stderr
    metrics = json.loads((tmp_path / "sim" / "simulation.json").read_text())
    free = next(v for k, v in metrics.items() if k.startswith("free-run"))
    assert free["yaw_rate"]["r2"] > 0.9  # the trained physical model, run as an FMU, on its own data


def test_an_fmu_in_a_model_file_is_code_run_only_when_trusted(native, tmp_path) -> None:
    """A model file is data: an FMU it names (a binary hypa would load) is refused unless trusted, by its path
    or a folder above it; a relative path is the file's folder's."""
    import yaml

    from hypa.core.errors import UserError
    from hypa.models.spec import read_model_file

    folder = tmp_path / "received"
    folder.mkdir()
    shutil.copy(native / "native.fmu", folder / "car.fmu")
    config = yaml.safe_load(FMU_MODEL.split("\n", 1)[1])
    (folder / "model.yaml").write_text(yaml.safe_dump(config))
    with pytest.raises(UserError, match=r"its block 'car' FMU is .*car\.fmu, code that is not built into hypa") as err:
        read_model_file(folder / "model.yaml")
    assert "\n" not in str(err.value) and "trust=[" in str(err.value)
    read = read_model_file(folder / "model.yaml", trust=[str(folder)])  # the folder above it
    assert read["blocks"]["car"]["fmu"] == str((folder / "car.fmu").resolve())
    read_model_file(folder / "model.yaml", trust=[str(folder / "car.fmu")])  # the file itself
    with pytest.raises(UserError, match="not built into hypa"):
        read_model_file(folder / "model.yaml", trust=[str(tmp_path / "elsewhere")])


def test_fmu_blocks_are_checked_when_parsed() -> None:
    from hypa.models.spec import ModelSpecError, parse_model_spec

    block = {"kind": "physics", "inputs": ["u"], "outputs": ["y"]}
    spec = lambda **extra: {"name": "m", "outputs": ["y"], "blocks": {"b": {**block, **extra}}}  # noqa: E731
    assert parse_model_spec(spec(fmu="a.fmu")).blocks[0].kind == "fmu"
    for extra, message in (({"fmu": "a.fmu", "system": "first_order_lag"}, "give fmu: or system:, not both"),
                           ({"fmu": "a.fmu", "interface": "both"}, "interface must be one of"),
                           ({"fmu": ""}, "needs fmu: <path"),
                           ({"system": "first_order_lag", "rename": {"a": "u"}}, "only FMU blocks take rename")):
        with pytest.raises(ModelSpecError, match=message):
            parse_model_spec(spec(**extra))
