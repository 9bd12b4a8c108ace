"""The ``model`` node's schema (hypa.models.schema) is made from the spec's dataclasses (hypa.models.spec): one
definition of the keys, which Hydra checks while it composes and parse_model_spec checks on a plain mapping."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest
from hydra.errors import ConfigCompositionException

from hypa.core.errors import one_line
from hypa.models.schema import BlockConfig, ModelConfig, StageConfig, keys
from hypa.models.spec import BlockSpec, ModelSpec, StageSpec, parse_model_spec, spec_config

from conftest import ROOT, compose_config


def test_the_schema_has_the_specs_keys_a_blocks_name_being_its_key_in_blocks() -> None:
    assert keys(ModelConfig) == tuple(f.name for f in fields(ModelSpec))
    assert keys(StageConfig) == tuple(f.name for f in fields(StageSpec))
    assert keys(BlockConfig) == tuple(f.name for f in fields(BlockSpec) if f.name != "name")
    assert keys(BlockSpec) == keys(BlockConfig)  # the keys a block's mapping may have
    assert ModelConfig().name == "model" and ModelConfig().blocks == {} and ModelConfig().stages == []


@pytest.mark.parametrize("overrides, where", [
    (["model=v1", "model.blocks.rear_steering.inptus=[u]"], ""),  # an override
    (["hydra.searchpath=[file://{tmp}]", "model=mine"], " (in model/mine.yaml)"),  # a user's model YAML
])
def test_a_misspelt_block_key_fails_while_hydra_composes(overrides: list[str], where: str, tmp_path: Path) -> None:
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "mine.yaml").write_text(
        "name: mine\nblocks:\n  rear_steering:\n    kind: physics\n    system: first_order_lag\n"
        "    inptus: [u]\n    outputs: [y]\noutputs: [y]\n")
    with pytest.raises(ConfigCompositionException) as error:
        compose_config("train", [o.format(tmp=tmp_path) for o in overrides])
    assert one_line(error.value) == (f"model.blocks.rear_steering.inptus: no such setting; model.blocks.rear_steering "
                                     f"has {', '.join(keys(BlockSpec))}{where}")


def test_every_key_of_a_spec_is_written_and_read_back() -> None:
    """spec_config writes each key that is set (no list of its own), parse_model_spec reads it back."""
    config = {
        "name": "every_key", "outputs": ["y"], "hold": "foh", "parameters": {"k": 2.0},
        "sensor_offsets": {"y": 0.1}, "stages": [{"name": "one", "train": ["net"], "bypass": ["net"]}],
        "blocks": {
            "plant": {"kind": "physics", "system": "first_order_lag", "inputs": ["u", "v"], "outputs": ["x"],
                      "trainable": ["tau_s"], "scale_as": ["u"], "initial_state": ["y"],
                      "parameters": {"tau_s": "250 ms"}, "scheduling": {"tau_s": "speed"}, "observe": {"x": "y"},
                      "table": True, "curved": {"x": 3}, "limited": {"x": "upper"},
                      "depends": {"tau_s": {"by": "x", "kind": "state"}}, "modes": ["u"], "driven": ["v"]},
            "net": {"kind": "ann", "inputs": ["x"], "outputs": ["y"], "residual_of": ["x"], "initial_state": "y"},
            "sim": {"kind": "physics", "fmu": "car.fmu", "interface": "co_simulation", "rename": {"r": "z"},
                    "inputs": ["u"], "outputs": ["z"], "trainable": ["k"], "parameters": {"k": 1.5}},
        },
    }
    spec = parse_model_spec(config)
    written = spec_config(spec)
    fmu_keys = {"fmu", "interface", "rename"}
    assert set(written["blocks"]["plant"]) == set(keys(BlockSpec)) - {"residual_of"} - fmu_keys
    assert fmu_keys <= set(written["blocks"]["sim"]) and written["blocks"]["sim"]["kind"] == "fmu"
    assert set(written) == set(keys(ModelSpec))
    assert written["blocks"]["plant"]["parameters"] == {"tau_s": "250 ms"}  # as given
    assert parse_model_spec(written) == spec


def test_the_spec_and_the_schema_import_no_torch() -> None:
    """hypa.commands.config imports the schema: a command's start does not pay for torch there."""
    code = "import sys\nimport hypa.models.schema\nassert 'torch' not in sys.modules, 'torch imported'"
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                            check=False)
    assert result.returncode == 0, result.stderr[-2000:]
