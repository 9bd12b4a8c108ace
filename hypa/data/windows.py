"""Fixed-length windows over decimated records, as a torch ``Dataset``.

A window of ``N`` predicted steps spans ``N + 1`` consecutive samples of one record:
sample 0 holds the measured initial state, samples 1..N the targets; inputs are given at
all ``N + 1`` samples because a first-order-hold discretization needs ``u[k + 1]``.
Windows start every ``stride`` samples and never cross from one record into the next; a
tail shorter than ``stride`` after the last window start is not covered by any window
(whole records are available for free-running simulation instead).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from hypa.data.errors import DataError
from hypa.data.normalization import Normalization
from hypa.data.records import Record


def window_starts(length: int, window: int, stride: int) -> range:
    """Start indices of all windows of ``window + 1`` samples in ``length`` samples."""
    if window < 1 or stride < 1:
        raise ValueError(f"window and stride must be >= 1, got window={window}, stride={stride}")
    return range(0, max(length - window, 0), stride)


def check_record_length(record: Record, window: int, original_rate_hz: float) -> None:
    """A record must hold at least one window of ``window + 1`` samples after decimation."""
    needed = window + 1
    if len(record) < needed:
        rate = record.sample_rate_hz
        original = window * original_rate_hz / rate + 1  # samples n with ceil(n / q) >= N + 1
        raise DataError(
            f"{record.path}: record is too short: {len(record)} samples at {rate:g} Hz after "
            f"decimation (about {len(record) / rate:.3g} s), but one window needs "
            f"window + 1 = {needed} samples, i.e. at least {original:.0f} "
            f"samples at {original_rate_hz:g} Hz ({(needed - 1) / rate:.3g} s); use a longer "
            f"record or a smaller data.window"
        )


class WindowDataset(Dataset):
    """Windows of decimated SI records, normalized for the model.

    Each item is a dict of tensors: ``"u"`` (N+1, m) and ``"y"`` (N+1, p), normalized
    float32 inputs and states. With ``with_eval=True`` (val/test) also ``"eval"`` (N+1, e)
    float32 SI evaluation channels ``eval_names`` (e may be 0), ``"record"`` (index into
    ``records``) and ``"start"`` (sample index of window sample 0 in that record), int64.
    A training dataset is built with ``with_eval=False`` and holds no evaluation data at all.
    """

    def __init__(
        self,
        records: Sequence[Record],
        input_names: Sequence[str],
        state_names: Sequence[str],
        normalization: Normalization,
        window: int,
        stride: int,
        eval_names: Sequence[str] = (),
        with_eval: bool = False,
    ) -> None:
        super().__init__()
        if eval_names and not with_eval:
            raise ValueError("eval_names given for a dataset built without evaluation data")
        self.input_names = tuple(input_names)
        self.state_names = tuple(state_names)
        self.eval_names = tuple(eval_names)
        self.window = int(window)
        self.stride = int(stride)
        self.with_eval = with_eval
        # Normalize in float64 and round once to float32, so de-normalizing a window gives
        # the decimated SI values back to float32 precision.
        self._u = [self._normalized(r, self.input_names, normalization) for r in records]
        self._y = [self._normalized(r, self.state_names, normalization) for r in records]
        self._eval = (
            [torch.from_numpy(r.stack(self.eval_names).astype(np.float32)) for r in records]
            if with_eval
            else []
        )
        self.index: list[tuple[int, int]] = [
            (i, start)
            for i, record in enumerate(records)
            for start in window_starts(len(record), self.window, self.stride)
        ]

    @staticmethod
    def _normalized(
        record: Record, names: tuple[str, ...], normalization: Normalization
    ) -> torch.Tensor:
        values = normalization.normalize(record.stack(names), names)  # (T, channels) float64
        return torch.from_numpy(values.astype(np.float32))

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, item: int) -> dict[str, torch.Tensor]:
        record, start = self.index[item]
        span = slice(start, start + self.window + 1)
        sample = {"u": self._u[record][span], "y": self._y[record][span]}  # (N+1, m), (N+1, p)
        if self.with_eval:
            sample["eval"] = self._eval[record][span]  # (N+1, e), SI
            sample["record"] = torch.tensor(record, dtype=torch.int64)
            sample["start"] = torch.tensor(start, dtype=torch.int64)
        return sample
