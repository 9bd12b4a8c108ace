"""Hydra's own views of a command's configuration work on every model: ``--cfg job --resolve``."""

import pytest
import yaml

from cli_helpers import hypa_run


@pytest.mark.parametrize("model", ["blackbox", "v2"])
def test_the_resolved_configuration_is_shown(model: str) -> None:
    """blackbox's signals come from the data set's channels (``${channels:...}``): resolved in place, they
    are the test bench's; this failed in OmegaConf ('list' is not a supported primitive type)."""
    result = hypa_run(["train", "--cfg", "job", "--resolve", f"model={model}"])
    assert result.returncode == 0, result.stderr[-2000:]
    shown = yaml.safe_load(result.stdout)
    assert shown["model"]["name"] == model and shown["model"]["outputs"] == ["yaw_rate", "side_slip"]
    if model == "blackbox":
        assert shown["model"]["blocks"]["network"]["inputs"] == ["steering_wheel_angle"]
