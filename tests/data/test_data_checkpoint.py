"""Through Lightning: a checkpoint carries the training scaling to new data."""

from __future__ import annotations

import lightning as L
import torch

from hypa.data import HypaDataModule
from hypa.paper.testbench.sensors import TESTBENCH_CHANNELS

from data_helpers import make_data_dir


class _Linear(L.LightningModule):
    """Smallest model that eats the batch format: y_hat = u @ W."""

    def __init__(self) -> None:
        super().__init__()
        self.layer = torch.nn.Linear(1, 2)

    def training_step(self, batch, batch_idx):
        assert set(batch) == {"u", "y", "s"}  # nothing for evaluation in a training batch
        return torch.nn.functional.mse_loss(self.layer(batch["u"]), batch["y"])

    def validation_step(self, batch, batch_idx):
        self.log("val/loss", torch.nn.functional.mse_loss(self.layer(batch["u"]), batch["y"]))

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.01)


def _trainer(tmp_path) -> L.Trainer:
    return L.Trainer(max_epochs=1, limit_train_batches=2, limit_val_batches=1, logger=False,
                     enable_checkpointing=False, enable_progress_bar=False,
                     enable_model_summary=False, accelerator="cpu", default_root_dir=tmp_path)


def test_checkpoint_restores_the_normalization_into_a_new_datamodule(tmp_path):
    options = {"window": 20, "stride": 5, "eval_stride": 10, "batch_size": 4}
    train_dir = make_data_dir(tmp_path / "a", duration_s=4.0, train_offset=2.0)
    dm = HypaDataModule(train_dir, TESTBENCH_CHANNELS, **options)
    model = _Linear()
    trainer = _trainer(tmp_path)
    trainer.fit(model, datamodule=dm)
    checkpoint = tmp_path / "last.ckpt"
    trainer.save_checkpoint(checkpoint)
    stored = torch.load(checkpoint, weights_only=True)["HypaDataModule"]
    assert stored["normalization"] == dm.normalization.state_dict()

    new_dir = make_data_dir(tmp_path / "b", duration_s=4.0, train_offset=-5.0)
    fresh = HypaDataModule(new_dir, TESTBENCH_CHANNELS, **options)
    _trainer(tmp_path).validate(model, datamodule=fresh, ckpt_path=checkpoint, verbose=False)
    assert fresh.normalization == dm.normalization
    window = fresh.dataset("val")[0]["u"]
    si = fresh.records("val")[0].stack(fresh.input_names)[:21]
    expected = dm.normalization.normalize(torch.from_numpy(si), fresh.input_names).float()
    torch.testing.assert_close(window, expected)
