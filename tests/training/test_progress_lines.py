"""Progress where the output is not a terminal: epoch lines instead of Lightning's bar (issue 45)."""

import io
from pathlib import Path

import lightning as L
import pytest
import torch
from torch.utils.data import DataLoader, TensorDataset

from hypa.training.progress import EpochLines, wants_lines

from test_train import TINY, run_train


class Line(L.LightningModule):
    """y = w x, learnt: a loss that falls epoch after epoch."""

    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(1))

    def step(self, batch: tuple[torch.Tensor, torch.Tensor], name: str) -> torch.Tensor:
        x, y = batch
        loss = torch.mean((self.w * x - y) ** 2)
        self.log(name, loss, on_step=name == "train/loss", on_epoch=True)
        return loss

    def training_step(self, batch, _):
        return self.step(batch, "train/loss")

    def validation_step(self, batch, _):
        self.step(batch, "val/loss")

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def fit(tmp_path: Path, every_s: float, epochs: int = 4) -> list[str]:
    x = torch.linspace(-1, 1, 32).unsqueeze(1)
    data = DataLoader(TensorDataset(x, 2 * x), batch_size=8)
    stream = io.StringIO()
    trainer = L.Trainer(max_epochs=epochs, callbacks=[EpochLines(every_s, stream)], enable_progress_bar=False,
                        logger=False, enable_checkpointing=False, enable_model_summary=False,
                        default_root_dir=tmp_path, num_sanity_val_steps=0)
    trainer.fit(Line(), data, data)
    return stream.getvalue().splitlines()


def test_a_line_per_epoch_with_the_losses_the_best_and_the_time(tmp_path: Path) -> None:
    lines = fit(tmp_path, every_s=0)
    assert [line.split(":")[0] for line in lines] == ["epoch 1/4", "epoch 2/4", "epoch 3/4", "epoch 4/4"]
    assert "train/loss " in lines[0] and "val/loss " in lines[0] and "(best " in lines[0]
    assert lines[-1].split("(best ")[1].startswith(lines[-1].split("val/loss ")[1].split(" ")[0])  # still falling
    assert " an epoch, at most " in lines[0] and "more" in lines[0]
    assert "at most" not in lines[-1]  # nothing left of the budget


def test_lines_are_thinned_to_the_cadence_but_the_first_and_last_always_print(tmp_path: Path) -> None:
    lines = fit(tmp_path, every_s=3600.0, epochs=5)
    assert [line.split(":")[0] for line in lines] == ["epoch 1/5", "epoch 5/5"]


def test_a_terminal_gets_the_bar_a_file_gets_lines() -> None:
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    assert not wants_lines(Terminal()) and wants_lines(io.StringIO())
    with pytest.raises(ValueError, match="every_s"):
        EpochLines(-1.0)


def test_hypa_train_into_a_pipe_prints_each_stage_s_epochs(tmp_path: Path, hypa_cache: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """V2 trains its two stages; with the bar asked for and no terminal, each stage's epochs are lines
    (the first and the last of each stage always, whatever the cadence)."""
    overrides = [o for o in TINY if o != "trainer.enable_progress_bar=false"]
    run_train(tmp_path, ["model=v2", "ann=lstm", *overrides, "trainer.max_epochs=2", "trainer.enable_progress_bar=true",
                         "early_stopping.patience=5"])
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("stage ")]
    assert [line.split(":")[0] for line in lines] == [
        "stage 1/2 (rear_steering), epoch 1/2", "stage 1/2 (rear_steering), epoch 2/2",
        "stage 2/2 (correction), epoch 1/2", "stage 2/2 (correction), epoch 2/2"], lines
