"""What a model needs to know of its data (:class:`DataSignature`), and nothing else.

A model reads no files: it takes the names of the measured channels in data order, their
training-set statistics (paper, Eq. 2), the sample time and the window layout. The data module
produces them (``HypaDataModule.signature``); a model is built from them
(``ComposedModel.from_data``, ``HybridModule.from_data``), so no caller copies them one by one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hypa.data.errors import DataError
from hypa.data.normalization import Normalization
from hypa.data.records import Record
from hypa.data.windows import model_arrays

Scale = tuple[float, float]  # (mean, std) in SI units


@dataclass(frozen=True, eq=False)
class DataSignature:
    """The measured channels, their statistics and the sample layout a model is built on.

    Args:
        input_names / output_names: measured inputs and outputs (targets), in data order.
        normalization: training-set statistics covering inputs, outputs and scheduling signals.
        dt: sample time [s] of the model.
        window: predicted samples N per window (the default lifted horizon).
        past: P, samples before each window's start that may start the model.
        eval_names: SI evaluation channels of the validation batches (compared, never trained on).
        scheduling_names: measured scheduling signals (SI, in the batches' ``s``).
    """

    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    normalization: Normalization
    dt: float
    window: int
    past: int = 0
    eval_names: tuple[str, ...] = ()
    scheduling_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for key in ("input_names", "output_names", "eval_names", "scheduling_names"):
            object.__setattr__(self, key, tuple(getattr(self, key)))
        if not isinstance(self.normalization, Normalization):
            object.__setattr__(self, "normalization", Normalization.from_state_dict(self.normalization))
        missing = [n for n in (*self.input_names, *self.output_names, *self.scheduling_names)
                   if n not in self.normalization.names]
        if missing:
            raise DataError(f"the normalization has no statistics for {missing} "
                            f"(it covers {list(self.normalization.names)})")
        if not float(self.dt) > 0 or int(self.window) < 1 or int(self.past) < 0:
            raise DataError(f"a data signature needs dt > 0 [s], window >= 1 and past >= 0; got dt={self.dt}, "
                            f"window={self.window}, past={self.past}")
        object.__setattr__(self, "dt", float(self.dt))
        object.__setattr__(self, "window", int(self.window))
        object.__setattr__(self, "past", int(self.past))

    @staticmethod
    def of(data: Any) -> DataSignature:
        """``data`` itself if it is a signature, else its ``signature`` (a ``HypaDataModule``'s)."""
        return data if isinstance(data, DataSignature) else data.signature

    def arrays(self, record: Record) -> dict[str, np.ndarray]:
        """``record`` as the model reads it (:func:`hypa.data.windows.model_arrays`): ``u``, ``y``
        normalized, ``s`` scheduling in SI units, float64 (T, channels)."""
        return model_arrays(record, self.normalization, self.input_names, self.output_names, self.scheduling_names)

    def scale(self, names: Sequence[str]) -> dict[str, Scale]:
        """(mean, std) in SI units of each of ``names``, from the training-set statistics."""
        norm = self.normalization.subset(list(names))
        return {n: (float(m), float(s)) for n, m, s in zip(names, norm.mean.tolist(), norm.std.tolist())}
