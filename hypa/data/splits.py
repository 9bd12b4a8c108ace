"""Which samples of which files form the training, validation and test data.

Either the files of a folder (``train*``, ``val*``, ``test*``: one whole file per record), or
explicit pieces ``{file, start, stop}`` (an int is a sample index, a float a fraction of the
file's length, ``None`` its first / after its last sample; ``stop`` is exclusive). The test
data may be one list of pieces or named test sets, e.g. Silverbox's ``multisine``,
``arrow_full`` and ``arrow_no_extrapolation``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hypa.data.errors import DataError
from hypa.data.files import find_split_files

UNNAMED_TEST = "test"


@dataclass(frozen=True)
class Piece:
    """Samples ``start:stop`` of ``file`` (int: sample index, float: fraction, None: the end)."""

    file: str
    start: int | float | None = None
    stop: int | float | None = None

    def __post_init__(self) -> None:
        for name in ("start", "stop"):
            value = getattr(self, name)
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            if value is not None and not number:
                raise DataError(
                    f"piece {self}: {name} must be an int (sample index), a float (fraction of "
                    f"the file) or null, got {value!r}"
                )
            if isinstance(value, float) and not 0.0 <= value <= 1.0:
                raise DataError(f"piece {self}: a fractional {name} lies in [0, 1], got {value}")
            if isinstance(value, int) and value < 0:
                raise DataError(f"piece {self}: {name} must be >= 0, got {value}")
        same_kind = type(self.start) is type(self.stop) and self.start is not None
        if same_kind and self.start >= self.stop:
            raise DataError(f"piece {self}: is empty (start {self.start} >= stop {self.stop})")

    @property
    def whole(self) -> bool:
        return self.start is None and self.stop is None

    def bounds(self, length: int) -> tuple[int, int]:
        """``(start, stop)`` sample indices in a file of ``length`` samples."""
        start, stop = _index(self.start, length, 0), _index(self.stop, length, length)
        if stop > length:
            raise DataError(f"piece {self}: stop {stop} lies beyond the file's {length} samples")
        if start >= stop:
            raise DataError(f"piece {self}: is empty (samples {start}:{stop} of {length})")
        return start, stop

    def __str__(self) -> str:
        return f"{self.file}[{_text(self.start)}:{_text(self.stop)}]"


def _index(value: float | None, length: int, default: int) -> int:
    if value is None:
        return default
    if isinstance(value, float):
        return int(round(value * length))
    return int(value)


def _text(value: float | None) -> str:
    return "" if value is None else f"{value:g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True)
class SplitSpec:
    """Pieces of the training and validation data and of each named test set."""

    train: tuple[Piece, ...]
    val: tuple[Piece, ...]
    test: dict[str, tuple[Piece, ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for split in ("train", "val"):
            if not getattr(self, split):
                raise DataError(f"data.splits.{split} holds no piece; it needs at least one")
        for name, pieces in self.test.items():
            if not pieces:
                raise DataError(f"test set {name!r} holds no piece")

    @classmethod
    def of(
        cls,
        train: Sequence[Piece],
        val: Sequence[Piece],
        test: Sequence[Piece] | Mapping[str, Sequence[Piece]] | None = None,
    ) -> SplitSpec:
        """A spec from lists; an unnamed ``test`` list becomes the test set ``"test"``."""
        if test is None:
            sets = {}
        elif isinstance(test, Mapping):
            sets = {str(name): tuple(pieces) for name, pieces in test.items()}
        else:
            sets = {UNNAMED_TEST: tuple(test)}
        return cls(tuple(train), tuple(val), sets)

    @classmethod
    def from_folder(cls, data_dir: Path) -> SplitSpec:
        """Whole files: ``train*``, ``val*`` and ``test*`` (the test set ``"test"``)."""
        found = find_split_files(data_dir)
        pieces = {split: tuple(Piece(p.name) for p in paths) for split, paths in found.items()}
        test = {UNNAMED_TEST: pieces["test"]} if "test" in pieces else {}
        return cls(pieces["train"], pieces["val"], test)

    def files(self) -> list[str]:
        """Every file named, once, in order of appearance."""
        pieces = [*self.train, *self.val, *(p for ps in self.test.values() for p in ps)]
        return list(dict.fromkeys(p.file for p in pieces))
