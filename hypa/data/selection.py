"""``select``: keep the stretches of each record where conditions on its channels hold.

A condition reads ``channel op number [unit]`` with ``op`` one of ``< <= > >=``, e.g.
``velocity > 5`` (SI units of the channel, here m/s) or ``velocity > 18 km/h``. All conditions
must hold at a sample. A record is cut into the stretches where they hold; each stretch
becomes its own record, so no window crosses a cut, and a stretch shorter than one window is
dropped.
"""

from __future__ import annotations

import difflib
import operator
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hypa.core.units import unit
from hypa.data.channels import ChannelSpec
from hypa.data.errors import DataError
from hypa.data.records import Record

_OPERATORS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}
_PATTERN = re.compile(
    r"^\s*(?P<channel>[A-Za-z_]\w*)\s*(?P<op><=|>=|<|>)\s*"
    r"(?P<value>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(?P<unit>\S.*?)?\s*$"
)


@dataclass(frozen=True)
class Condition:
    """``channel op value`` with ``value`` in the channel's SI unit."""

    channel: str
    op: str
    value: float
    text: str

    @classmethod
    def parse(cls, text: str, channels: Mapping[str, ChannelSpec]) -> Condition:
        """Parse ``text``; the channel must be declared and not evaluation-only."""
        match = _PATTERN.match(str(text))
        if match is None:
            raise DataError(
                f"select condition {text!r} is not of the form 'channel op number [unit]' "
                f"with op one of {' '.join(_OPERATORS)}, e.g. 'velocity > 5'"
            )
        name = match["channel"]
        if name not in channels:
            guess = difflib.get_close_matches(name, list(channels), n=1)
            hint = f" (did you mean {guess[0]!r}?)" if guess else ""
            raise DataError(
                f"select condition {text!r} names {name!r}, which is not a declared channel"
                f"{hint}; channels: {', '.join(channels)} (declare it, e.g. with role auxiliary)"
            )
        channel = channels[name]
        if channel.role == "evaluation":
            raise DataError(
                f"select condition {text!r} uses the evaluation channel {name!r}, which is never "
                f"read for training; declare the column again with role auxiliary"
            )
        value = float(match["value"])
        if match["unit"]:
            given = unit(match["unit"], name)
            if given.si != channel.unit:
                raise DataError(
                    f"select condition {text!r}: {given.name!r} is a unit of {given.dimension}, "
                    f"but {name!r} is in {channel.unit!r}"
                )
            value = value * given.factor + given.offset
        return cls(name, match["op"], value, str(text).strip())

    def holds(self, record: Record) -> np.ndarray:
        """Where the condition holds: (len(record),) bool."""
        return _OPERATORS[self.op](record[self.channel], self.value)

    def __str__(self) -> str:
        return self.text


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of True in ``mask`` (stop exclusive)."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def select(
    records: Sequence[Record], conditions: Sequence[Condition], min_length: int
) -> tuple[list[Record], int]:
    """The stretches of ``records`` where every condition holds and which hold at least
    ``min_length`` samples, each as a record; and the length of the longest stretch found
    (kept or not), for the error message when nothing is left."""
    if not conditions:
        return list(records), max((len(r) for r in records), default=0)
    kept: list[Record] = []
    longest = 0
    for record in records:
        mask = np.ones(len(record), dtype=bool)
        for condition in conditions:
            mask &= condition.holds(record)
        for start, stop in runs(mask):
            longest = max(longest, stop - start)
            if stop - start >= min_length:
                kept.append(record.piece(start, stop))
    return kept, longest
