"""dataset=NAME brings its own default models: hypa diagnose takes conf/model/<dataset>_nominal.yaml,
hypa simulate <dataset>_physical.yaml (hypa diagnose dataset=racecar once failed on the
vehicle test bench's nominal model); model=M still chooses any other."""


import pytest

from conftest import compose_config


@pytest.mark.parametrize("command, overrides, model", [
    ("diagnose", [], "vehicle_nominal"),
    ("diagnose", ["dataset=files", "data.dir=/data"], "vehicle_nominal"),
    ("diagnose", ["dataset=racecar"], "racecar_nominal"),
    ("diagnose", ["dataset=emps"], "emps_nominal"),
    ("diagnose", ["dataset=silverbox"], "silverbox_physical"),
    ("diagnose", ["dataset=racecar", "model=racecar_physical"], "racecar_physical"),
    ("simulate", [], "physical"),
    ("simulate", ["dataset=racecar"], "racecar_physical"),
    ("simulate", ["dataset=emps"], "emps_physical"),
    ("simulate", ["dataset=silverbox"], "silverbox_physical"),
])
def test_a_data_set_brings_its_default_model(command: str, overrides: list[str], model: str) -> None:
    cfg = compose_config(command, overrides)
    assert cfg.model.name == model
