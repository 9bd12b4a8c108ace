"""Networks, callbacks and the logger are ``_target_`` configs built by ``hydra.utils.instantiate``:
a user's own network (a ``SequenceBlock`` subclass by import path) and callback plug in from the
command line, and a bad one is one line."""

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cli_helpers import hypa_run
from conftest import ROOT
from data_helpers import make_dc_motor_data

EXAMPLE = ROOT / "examples" / "user_system"

NETWORK = textwrap.dedent('''
    import torch
    from torch import nn

    from hypa.ann import SequenceBlock


    class TinyGRU(SequenceBlock):
        """A network of the user's own: a GRU and a linear head."""

        def __init__(self, d_in: int, d_out: int, width: int = 8, *, zero_init: bool = False) -> None:
            super().__init__(d_in, d_out, zero_init=zero_init)
            self.gru = nn.GRU(d_in, width, batch_first=True)
            self.head = self._make_head(width)

        def forward(self, x, state=None):
            self._check_input(x)
            h, state = self.gru(x, state)
            return self.head(h), state

        def default_state(self, batch, device, dtype):
            return torch.zeros(1, batch, self.gru.hidden_size, device=device, dtype=dtype)
''')


def _train(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess:
    """One epoch of ``model=blackbox`` on the DC motor's data, with the user's config folder: the
    example's (dataset, system) plus ``ann/tiny_gru.yaml``, the user's network."""
    data = tmp_path / "data"
    data.mkdir(parents=True, exist_ok=True)
    env = make_dc_motor_data(data, 8)
    (tmp_path / "mynets.py").write_text(NETWORK)
    conf = tmp_path / "conf"
    shutil.copytree(EXAMPLE / "conf", conf, dirs_exist_ok=True)
    (conf / "ann").mkdir(exist_ok=True)
    (conf / "ann" / "tiny_gru.yaml").write_text("# @package ann\nname: tiny_gru\n_target_: mynets.TinyGRU\nwidth: 4\n")
    env = {**env, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(EXAMPLE), env.get("PYTHONPATH", "")])}
    return hypa_run(["train", "--config-dir", str(conf), "dataset=dc_motor", "model=blackbox", f"data.dir={data}",
                     "trainer.max_epochs=1", "trainer.limit_train_batches=3", "trainer.enable_progress_bar=false",
                     "figures.enabled=false", f"hydra.run.dir={tmp_path / 'run'}", *overrides], env=env)


def test_a_users_network_and_callback_plug_in_by_target(tmp_path):
    result = _train(tmp_path, "ann=tiny_gru",
                    "+callbacks.lr={_target_:lightning.pytorch.callbacks.LearningRateMonitor}")
    assert result.returncode == 0, result.stderr[-3000:]
    sys.path.insert(0, str(tmp_path))
    try:
        from hypa.evaluation.runs import load_run

        run = load_run(tmp_path / "run", trust=["mynets.TinyGRU"])
    finally:
        sys.path.remove(str(tmp_path))
    assert run.module.hparams.ann_name == "mynets.TinyGRU"
    networks = [m for m in run.module.model.modules() if type(m).__name__ == "TinyGRU"]
    assert networks and networks[0].gru.hidden_size == 4
    assert (tmp_path / "run" / "tensorboard").is_dir()  # the instantiated logger writes into the run folder


@pytest.mark.parametrize("overrides", [
    ("ann._target_=mynets.NoSuchNet",),
    pytest.param(("ann=tiny_gru", "ann.widht=3"), marks=pytest.mark.slow),
    pytest.param(("+callbacks.x={_target_:builtins.dict}",), marks=pytest.mark.slow),
    pytest.param(("logger._target_=nope.Logger",), marks=pytest.mark.slow),
], ids=["network", "hyperparameter", "callback", "logger"])
def test_a_bad_target_is_one_line(tmp_path, overrides):
    result = _train(tmp_path, *overrides)
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert result.returncode == 1, (overrides, result.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith("hypa train: error:"), (overrides, result.stderr[-2000:])
