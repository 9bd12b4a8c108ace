"""Fixed-length windows over records, as a torch ``Dataset``.

A window spans ``P + N + 1`` consecutive samples of one record: ``P = past`` samples before
the window start, the window start (sample P, "k" in the paper: the measured or estimated
initial state) and ``N = window`` predicted samples (the targets). Inputs and scheduling
signals are given at all samples because a first-order-hold discretization needs ``u[k + 1]``.
Windows start every ``stride`` samples and never cross from one record into the next (a cut
made by ``select`` or a split bound starts a new record); a tail shorter than ``stride`` after
the last window start is not covered by any window (whole records are available for
free-running simulation instead).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from hypa.data.errors import DataError
from hypa.data.normalization import Normalization
from hypa.data.records import Record


def model_arrays(record: Record, normalization: Normalization, input_names: Sequence[str],
                 output_names: Sequence[str], scheduling_names: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """One record as a model reads it, float64 (T, channels): ``u`` and ``y`` normalized inputs and
    outputs, ``s`` the scheduling signals in SI units. The one place a record becomes model inputs:
    the training windows, the free run (``hypa.models.rollout``) and the stretches of identification
    and diagnosis (``hypa.identification.stretches``) all cut from these."""
    def normalized(names: Sequence[str]) -> np.ndarray:
        names = tuple(names)
        return normalization.normalize(record.stack(names), names) if names else np.zeros((len(record), 0))

    return {"u": normalized(input_names), "y": normalized(output_names),
            "s": record.stack(tuple(scheduling_names)).astype(np.float64)}


def window_starts(length: int, span: int, stride: int) -> range:
    """Start indices of all windows of ``span + 1`` samples (``span = P + N``) in ``length``."""
    if span < 1 or stride < 1:
        raise ValueError(f"window and stride must be >= 1, got span={span}, stride={stride}")
    return range(0, max(length - span, 0), stride)


def check_record_length(
    record: Record, window: int, original_rate_hz: float, past: int = 0
) -> None:
    """A record must hold at least one window of ``past + window + 1`` samples."""
    needed = past + window + 1
    if len(record) < needed:
        rate = record.sample_rate_hz
        original = (needed - 1) * original_rate_hz / rate + 1  # samples n with ceil(n/q) >= needed
        raise DataError(
            f"{record.name}: record is too short: {len(record)} samples at {rate:g} Hz"
            f"{' after decimation' if rate != original_rate_hz else ''} (about "
            f"{len(record) / rate:.3g} s), but one window needs past + window + 1 = {needed} "
            f"samples, i.e. at least {original:.0f} samples at {original_rate_hz:g} Hz "
            f"({(needed - 1) / rate:.3g} s); use a longer record or a smaller data.window"
        )


class WindowDataset(Dataset):
    """Windows of SI records, normalized for the model.

    Each item is a dict of tensors over the window's ``P + N + 1`` samples: ``"u"`` (P+N+1, m)
    and ``"y"`` (P+N+1, p), normalized float32 inputs and outputs, and ``"s"`` (P+N+1, q)
    float32 scheduling signals in SI units (q may be 0). With ``with_eval=True`` (val/test)
    also ``"eval"`` (P+N+1, e) float32 SI evaluation channels ``eval_names`` (e may be 0),
    ``"record"`` (index into ``records``) and ``"start"`` (sample index of window sample 0,
    the first past sample, in that record), int64. A training dataset is built with
    ``with_eval=False`` and holds no evaluation data at all.
    """

    def __init__(
        self,
        records: Sequence[Record],
        input_names: Sequence[str],
        output_names: Sequence[str],
        normalization: Normalization,
        window: int,
        stride: int,
        scheduling_names: Sequence[str] = (),
        past: int = 0,
        eval_names: Sequence[str] = (),
        with_eval: bool = False,
    ) -> None:
        super().__init__()
        if eval_names and not with_eval:
            raise ValueError("eval_names given for a dataset built without evaluation data")
        self.input_names = tuple(input_names)
        self.output_names = tuple(output_names)
        self.scheduling_names = tuple(scheduling_names)
        self.eval_names = tuple(eval_names)
        self.window = int(window)
        self.past = int(past)
        self.stride = int(stride)
        self.with_eval = with_eval
        # Normalize in float64 and round once to float32, so de-normalizing a window gives
        # the SI values back to float32 precision.
        arrays = [model_arrays(r, normalization, self.input_names, self.output_names, self.scheduling_names)
                  for r in records]
        self._u, self._y, self._s = ([torch.from_numpy(a[k].astype(np.float32)) for a in arrays] for k in "uys")
        self._eval = [self._si(r, self.eval_names) for r in records] if with_eval else []
        span = self.past + self.window
        self.index: list[tuple[int, int]] = [
            (i, start)
            for i, record in enumerate(records)
            for start in window_starts(len(record), span, self.stride)
        ]

    @property
    def state_names(self) -> tuple[str, ...]:
        """Alias of :attr:`output_names` (older callers)."""
        return self.output_names

    @staticmethod
    def _si(record: Record, names: tuple[str, ...]) -> torch.Tensor:
        return torch.from_numpy(record.stack(names).astype(np.float32))  # (T, channels)

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, item: int) -> dict[str, torch.Tensor]:
        record, start = self.index[item]
        span = slice(start, start + self.past + self.window + 1)
        sample = {
            "u": self._u[record][span],  # (P+N+1, m)
            "y": self._y[record][span],  # (P+N+1, p)
            "s": self._s[record][span],  # (P+N+1, q), SI
        }
        if self.with_eval:
            sample["eval"] = self._eval[record][span]  # (P+N+1, e), SI
            sample["record"] = torch.tensor(record, dtype=torch.int64)
            sample["start"] = torch.tensor(start, dtype=torch.int64)
        return sample
