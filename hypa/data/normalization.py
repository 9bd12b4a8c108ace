"""Per-channel normalization with statistics of the training split (paper, Eq. 2).

``x_hat = (x - mu) / sigma`` with ``mu`` and ``sigma`` the mean and the (population)
standard deviation of each channel over all decimated training samples. The same object
is stored with a trained model, so new data is always scaled like the training data.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeVar

import numpy as np
import torch

from hypa.data.errors import DataError
from hypa.data.records import Record

ArrayT = TypeVar("ArrayT", torch.Tensor, np.ndarray)

# A channel whose spread is below this fraction of its magnitude is constant up to rounding
# (a decimated constant wiggles by ~1e-16, so an exact ``sigma == 0`` test would miss it).
_CONSTANT_RELATIVE_STD = 1e-9


class Normalization:
    """Names, means and standard deviations of channels (SI units of each channel).

    ``mean`` and ``std`` are float64 tensors of shape (len(names),); :meth:`normalize` and
    :meth:`denormalize` act on the last axis of a tensor or array whose channels are
    ``names`` (or a given subset of them, in that order).
    """

    def __init__(
        self,
        names: Sequence[str],
        mean: Sequence[float] | np.ndarray | torch.Tensor,
        std: Sequence[float] | np.ndarray | torch.Tensor,
    ) -> None:
        self.names: tuple[str, ...] = tuple(names)
        self.mean = torch.as_tensor(np.asarray(mean, dtype=np.float64)).reshape(-1)
        self.std = torch.as_tensor(np.asarray(std, dtype=np.float64)).reshape(-1)
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"normalization channel names repeat: {self.names}")
        if not (self.mean.numel() == self.std.numel() == len(self.names)):
            raise ValueError(
                f"normalization needs one mean and one std per channel: {len(self.names)} "
                f"names, {self.mean.numel()} means, {self.std.numel()} stds"
            )
        bad = [n for n, s in zip(self.names, self.std.tolist()) if not (np.isfinite(s) and s > 0)]
        if bad or not torch.isfinite(self.mean).all():
            raise DataError(f"normalization statistics must be finite with std > 0; bad: {bad}")

    @classmethod
    def fit(cls, records: Sequence[Record], names: Sequence[str]) -> Normalization:
        """Mean and population std of each channel over all samples of ``records``.

        Raises :class:`DataError` for a channel that is constant (its sigma would be 0 and
        its normalized values undefined).
        """
        if not records:
            raise DataError("cannot fit a normalization without records")
        means, stds = [], []
        for name in names:
            values = np.concatenate([record[name] for record in records])
            mean, std = float(values.mean()), float(values.std())
            if std <= _CONSTANT_RELATIVE_STD * float(np.abs(values).max()):
                files = ", ".join(record.name for record in records)
                raise DataError(
                    f"channel {name!r} is constant ({mean:g}) over all training records "
                    f"({files}); its standard deviation is 0, so it cannot be normalized. "
                    f"Declare it with another role (e.g. auxiliary) or use data that excite it"
                )
            means.append(mean)
            stds.append(std)
        return cls(names, means, stds)

    def index(self, names: Sequence[str]) -> list[int]:
        """Positions of ``names`` among :attr:`names`."""
        missing = [name for name in names if name not in self.names]
        if missing:
            raise KeyError(f"no normalization statistics for {missing}; have {list(self.names)}")
        return [self.names.index(name) for name in names]

    def subset(self, names: Sequence[str]) -> Normalization:
        """The statistics of ``names`` only, in that order (e.g. states or inputs)."""
        idx = self.index(names)
        return Normalization(names, self.mean[idx], self.std[idx])

    def _stats(self, x: ArrayT, names: Sequence[str] | None) -> tuple[ArrayT, ArrayT]:
        idx = self.index(names) if names is not None else list(range(len(self.names)))
        if x.shape[-1] != len(idx):
            raise ValueError(f"last axis has {x.shape[-1]} channels, expected {len(idx)}")
        mean, std = self.mean[idx], self.std[idx]
        if isinstance(x, torch.Tensor):
            return mean.to(device=x.device, dtype=x.dtype), std.to(device=x.device, dtype=x.dtype)
        return mean.numpy(), std.numpy()

    def normalize(self, x: ArrayT, names: Sequence[str] | None = None) -> ArrayT:
        """SI values (..., len(names)) -> normalized ``(x - mean) / std``."""
        mean, std = self._stats(x, names)
        return (x - mean) / std

    def denormalize(self, x_hat: ArrayT, names: Sequence[str] | None = None) -> ArrayT:
        """Normalized values (..., len(names)) -> SI ``x_hat * std + mean``."""
        mean, std = self._stats(x_hat, names)
        return x_hat * std + mean

    def state_dict(self) -> dict[str, list]:
        """Plain lists of names and floats (safe for ``torch.load(weights_only=True)``, YAML)."""
        return {"names": list(self.names), "mean": self.mean.tolist(), "std": self.std.tolist()}

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Sequence]) -> Normalization:
        return cls(state["names"], state["mean"], state["std"])

    __hash__ = None  # equal by value (tensors): not hashable, as __eq__ alone already made it

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Normalization):
            return NotImplemented
        return (
            self.names == other.names
            and torch.equal(self.mean, other.mean)
            and torch.equal(self.std, other.std)
        )

    def __repr__(self) -> str:
        triples = zip(self.names, self.mean.tolist(), self.std.tolist())
        stats = ", ".join(f"{n}: {m:.4g} ± {s:.4g}" for n, m, s in triples)
        return f"Normalization({stats})"
