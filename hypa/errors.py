"""One-line errors for the entry points: a user's mistake is not a bug, so it gets no traceback.

``@user_errors("hypa.train")`` under ``@hydra.main`` turns the errors that describe bad input
(data, model configuration, a user's system, physics that cannot run, a missing run folder or
file, a bad checkpoint) into ``hypa.train: error: <message>`` (one line) on stderr and exit
status 1. Anything else is a bug and keeps its traceback; ``HYDRA_FULL_ERROR=1`` keeps the
traceback for user errors too.

A bad value of an override is reported where the value is used: :func:`setting` reads one
typed value of the configuration, :func:`settings` turns the plain ``ValueError`` /
``TypeError`` that a library (Lightning, a network's constructor, the test bench) raises for the
user's values into a :class:`UserError` named after the settings. Plain ``ValueError``s
elsewhere stay bugs.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])
T = TypeVar("T")


class UserError(ValueError):
    """Bad input that the message explains (e.g. a benchmark model that failed to train)."""


def user_error_types() -> tuple[type[BaseException], ...]:
    """Exceptions that describe the user's input, never a bug: reported in one line."""
    from omegaconf.errors import MissingMandatoryValue

    from hypa.data.errors import DataError
    from hypa.models.spec import ModelSpecError
    from hypa.physics import SchedulingError, UnstablePhysicsError
    from hypa.physics.contract import SystemContractError

    # The OSErrors about a path the user gave (a missing run folder, a folder that cannot be
    # written) and a required setting (``???``) left out, e.g. hypa.evaluate without run=.
    return (UserError, DataError, ModelSpecError, SystemContractError, UnstablePhysicsError, SchedulingError,
            FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError, MissingMandatoryValue)


def one_line(error: BaseException) -> str:
    """The error's message on one line (OmegaConf's and Lightning's messages span several)."""
    from omegaconf.errors import MissingMandatoryValue

    if isinstance(error, MissingMandatoryValue) and getattr(error, "full_key", None):
        return f"{error.full_key} is required: give {error.full_key}=..."
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return "".join(line + ("" if i == len(lines) - 1 else " " if line.endswith(":") else "; ")
                   for i, line in enumerate(lines)) or type(error).__name__


def user_errors(command: str) -> Callable[[F], F]:
    def decorate(main: F) -> F:
        @functools.wraps(main)
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            try:
                return main(*args, **kwargs)
            except user_error_types() as error:
                if os.environ.get("HYDRA_FULL_ERROR") == "1":
                    raise
                print(f"{command}: error: {one_line(error)}", file=sys.stderr, flush=True)
                sys.exit(1)

        return wrapped  # type: ignore[return-value]

    return decorate


_KIND_NAMES = {int: "an integer", float: "a number", str: "a string"}


def setting(cfg: Any, key: str, kind: Callable[[Any], T], choices: Collection[T] | None = None,
            optional: bool = False) -> T:
    """The value at ``key`` (dotted, e.g. ``trainer.max_epochs``) of the configuration as ``kind``.

    A value that is not one (``trainer.max_epochs=abc``), or not among ``choices``, is the
    user's error and names the override to fix. ``optional``: ``None`` (``null``) is allowed
    and returned as is.
    """
    from omegaconf import OmegaConf

    value = OmegaConf.select(cfg, key, throw_on_missing=True)  # `???` left out: MissingMandatoryValue
    if value is None and optional:
        return None  # type: ignore[return-value]
    try:
        if kind is int and isinstance(value, float) and not value.is_integer():
            raise ValueError
        if kind in (int, float) and isinstance(value, bool):  # True is an int to Python, not to a user
            raise ValueError
        converted = kind(value)
    except (TypeError, ValueError):
        expected = _KIND_NAMES.get(kind, getattr(kind, "__name__", str(kind)))  # type: ignore[call-overload]
        raise UserError(f"{key}={value} is not {expected}; give {key}=<{expected.split()[-1]}>") from None
    if choices is not None and converted not in choices:
        raise UserError(f"{key}={value} is not one of {', '.join(map(str, choices))}")
    return converted


@contextmanager
def settings(what: str) -> Iterator[None]:
    """Build something from the user's settings ``what`` (``trainer``, ``ann=lstm``, ``testbench``).

    The plain ``ValueError`` / ``TypeError`` that the code behind it raises for the values it
    was given (an accelerator that does not exist, a network size < 1, a keyword Lightning
    does not know) and OmegaConf's validation errors become a :class:`UserError` that names
    the settings; hypa's own user errors pass unchanged. Use it only around a call whose
    arguments are the user's values, so that a bug elsewhere keeps its traceback.
    """
    from omegaconf.errors import ValidationError

    try:
        yield
    except user_error_types():
        raise
    except ValidationError as error:  # "Value 'abc' ... could not be converted to Float" + its key
        key = f"{what}.{error.full_key}" if getattr(error, "full_key", None) else what
        message = str(getattr(error, "msg", None) or error).splitlines()[0]  # the rest repeats the key
        raise UserError(f"{key}: {message}") from error
    except (ValueError, TypeError) as error:
        raise UserError(f"{what}: {one_line(error)}") from error
