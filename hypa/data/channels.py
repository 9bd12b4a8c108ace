"""Channel declarations: a name, a role, where the values come from, and their units.

Roles:

* ``input``: a model input u (normalized in windows);
* ``output``: a measured output y, the training target (normalized in windows);
* ``scheduling``: a measured signal ρ the physics depends on per sample (SI in windows);
* ``evaluation``: read for val/test only, never part of a training record or batch;
* ``auxiliary``: read for ``select`` conditions; shown to a model only where it reads the channel
  (a diagnosed model's ``unread_channel``: the channel is then an input, :func:`hypa.data.from_config.read_as_inputs`),
  and offered to the diagnosis as a channel the model may miss (``HypaDataModule(auxiliary_inputs=True)``).

A channel is a file ``column`` (default: its name) or an ``expression`` over the file's columns
(:mod:`hypa.data.expressions`), in ``unit``; inside hypa it is SI (:mod:`hypa.core.units`).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from hypa.core.errors import UserError
from hypa.core.trust import check_name
from hypa.core.units import display_factor, unit
from hypa.data.errors import DataError
from hypa.data.expressions import Expression

ROLES: tuple[str, ...] = ("input", "output", "scheduling", "evaluation", "auxiliary")
MODEL_ROLES: tuple[str, ...] = ("input", "output", "scheduling")  # what a training batch holds


@dataclass(frozen=True)
class ChannelSpec:
    """A declared channel. ``file_unit`` is the unit in the file; :attr:`unit` is SI.

    Attributes resolved on construction: ``unit`` (the SI unit), ``factor`` (file -> SI),
    ``display_unit`` (the SI unit when not given) and ``display_factor`` (SI -> display,
    ``shown = SI * display_factor``). Raises :class:`DataError` for an unknown role or unit,
    a display unit of another dimension, or an invalid expression.
    """

    name: str
    role: str
    file_unit: str = "-"
    column: str | None = None
    display_unit: str | None = None
    expression: str | None = None
    unit: str = field(init=False)
    factor: float = field(init=False)
    offset: float = field(init=False)  # SI = file value * factor + offset (a temperature in degC or degF)
    display_factor: float = field(init=False)

    def __post_init__(self) -> None:
        try:
            check_name(self.name, "a channel's name")
        except UserError as error:
            raise DataError(str(error)) from None
        if self.role not in ROLES:
            guess = difflib.get_close_matches(str(self.role), ROLES, n=1)
            hint = f" (did you mean {guess[0]!r}?)" if guess else ""
            raise DataError(
                f"channel {self.name!r} has the unknown role {self.role!r}{hint}; roles: "
                f"{', '.join(ROLES)}"
            )
        if self.name == "time":
            raise DataError("'time' is the time base (data.time), not a channel; rename it")
        if self.column is not None and self.expression is not None:
            raise DataError(
                f"channel {self.name!r} has both a column ({self.column!r}) and an expression "
                f"({self.expression!r}); give one"
            )
        measured = unit(self.file_unit, self.name)
        factor = display_factor(self.file_unit, self.display_unit, self.name)
        object.__setattr__(self, "unit", measured.si)
        object.__setattr__(self, "factor", measured.factor)
        object.__setattr__(self, "offset", measured.offset)
        object.__setattr__(self, "display_unit", self.display_unit or measured.si)
        object.__setattr__(self, "display_factor", factor)
        if self.expression is not None:
            Expression(self.expression, self.name)  # a syntax error fails here, not in setup()

    @property
    def source(self) -> str:
        """The file column (``column`` or the name), or the expression."""
        return self.expression if self.expression is not None else (self.column or self.name)

    def file_names(self) -> tuple[str, ...]:
        """Column and scalar names of a file this channel reads."""
        if self.expression is not None:
            return Expression(self.expression, self.name).names
        return (self.column or self.name,)


def check_channels(channels: Iterable[ChannelSpec]) -> dict[str, ChannelSpec]:
    """Channels by name, checked as a whole: at least one input and one output, and no
    training channel reading a column that an evaluation channel declares."""
    checked: dict[str, ChannelSpec] = {}
    for channel in channels:
        if channel.name in checked:
            raise DataError(f"channel {channel.name!r} is declared twice")
        checked[channel.name] = channel
    for role in ("input", "output"):
        if not any(c.role == role for c in checked.values()):
            raise DataError(
                f"no {role} channel is declared; channels: "
                f"{', '.join(f'{n} ({c.role})' for n, c in checked.items()) or 'none'}"
            )
    evaluated = {name: c for name, c in checked.items() if c.role == "evaluation"}
    columns = {column: name for name, c in evaluated.items() for column in c.file_names()}
    for name, c in checked.items():
        if c.role == "evaluation":
            continue
        for column in c.file_names():
            if column in columns:
                owner = columns[column]
                raise DataError(
                    f"evaluation channel {owner!r} is used as {c.role} by channel {name!r} "
                    f"(it reads {column!r}); evaluation channels never reach a training batch"
                )
    return checked


def names_with_role(channels: Mapping[str, ChannelSpec], *roles: str) -> tuple[str, ...]:
    """Names of the channels with any of ``roles``, in declared order."""
    return tuple(name for name, c in channels.items() if c.role in roles)
