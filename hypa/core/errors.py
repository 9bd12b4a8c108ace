"""One-line errors for the entry points: a user's mistake is not a bug, so it gets no traceback.

``@hydra_command("hypa train", "train")`` in place of ``@hydra.main`` (or ``@user_errors`` on a
command without Hydra) turns the errors that describe bad input
(data, model configuration, a user's system, physics that cannot run, a missing run folder or
file, a bad checkpoint, a configuration Hydra cannot compose, an output folder that cannot be
written or a full disk) into ``hypa train: error: <message>`` (one line) on stderr and exit
status 1, wherever they happen: in hypa's code or in Hydra's own set-up of the run folder.
Anything else is a bug and keeps its traceback; ``HYDRA_FULL_ERROR=1`` (or ``HYPA_FULL_ERROR=1``)
keeps the traceback for user errors too. Ctrl-C ends a command with ``hypa train: interrupted`` and
exit status 130 (as a shell reports SIGINT), without a traceback unless those ask for it.

A bad value of an override is reported in the words of the setting to fix: a value of the wrong
type, or a misspelt key, while Hydra composes the typed configuration (:mod:`hypa.commands.config`;
:func:`one_line` words OmegaConf's error), a value out of its range when the command reads that
configuration (:func:`checked`, in the schemas' ``__post_init__``); :func:`settings` turns the plain ``ValueError`` /
``TypeError`` that a library (Lightning, a network's constructor, the test bench) raises for the
user's values into a :class:`UserError` named after the settings. Plain ``ValueError``s
elsewhere stay bugs.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import math
import os
import sys
import traceback
from collections.abc import Callable, Collection, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from hypa.conf import CONF  # the configuration tree inside the package

F = TypeVar("F", bound=Callable[..., Any])
T = TypeVar("T")


class UserError(ValueError):
    """Bad input that the message explains (e.g. a benchmark model that failed to train)."""


def user_error_types() -> tuple[type[BaseException], ...]:
    """Exceptions that describe the user's input, never a bug: reported in one line.

    hypa's own are all a :class:`UserError` (the data's ``DataError``, the model
    configuration's ``ModelSpecError``, a user's system's ``SystemContractError``, physics that
    cannot run: ``UnstablePhysicsError``, ``SchedulingError``, ...), so this module imports none
    of them.
    """
    from hydra.errors import (
        CompactHydraException,
        ConfigCompositionException,
        MissingConfigException,
        OverrideParseException,
        SearchPathException,
    )
    from omegaconf.errors import MissingMandatoryValue

    # The OSErrors about a path the user gave (a missing run folder, a folder that cannot be
    # written), a required setting (``???``) left out, e.g. hypa evaluate without run=, and a
    # configuration Hydra cannot compose (a misspelt key or group).
    return (UserError, FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError,
            MissingMandatoryValue, CompactHydraException, ConfigCompositionException, MissingConfigException,
            OverrideParseException, SearchPathException)


# What the machine says about the user's folders rather than about hypa: a disk or quota that is
# full, a file over the size limit, a read-only file system, no permission.
_OPERATOR_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM})


def is_user_error(error: BaseException) -> bool:
    """Whether ``error`` describes the user's input or machine (one line) rather than a bug."""
    if isinstance(error, user_error_types()):
        return True
    return isinstance(error, OSError) and error.errno in _OPERATOR_ERRNOS


def full_error_requested() -> bool:
    """The user asked for tracebacks of user errors too (``HYDRA_FULL_ERROR=1`` or ``HYPA_FULL_ERROR=1``).

    :func:`user_errors` sets ``HYDRA_FULL_ERROR=1`` for Hydra itself (so that Hydra hands its errors
    on instead of printing them) and keeps the user's own wish in ``HYPA_FULL_ERROR``, which the
    commands hypa starts (the benchmark's, the diagnosis's training) inherit.
    """
    wish = os.environ.get("HYPA_FULL_ERROR")
    return (wish if wish is not None else os.environ.get("HYDRA_FULL_ERROR")) == "1"


def one_line(error: BaseException) -> str:
    """The error's message on one line (OmegaConf's and Lightning's messages span several)."""
    from omegaconf.errors import MissingMandatoryValue

    if isinstance(error, MissingMandatoryValue) and getattr(error, "full_key", None):
        return f"{error.full_key} is required: give {error.full_key}=..."
    composing = _schema_message(error)
    if composing is not None:
        return composing
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return "".join(line + ("" if i == len(lines) - 1 else " " if line.endswith(":") else "; ")
                   for i, line in enumerate(lines)) or type(error).__name__


_CONVERSIONS = {"Integer": "an integer", "Float": "a number", "String": "a string", "Boolean": "true or false",
                "bool": "true or false"}


def _schema_message(error: BaseException) -> str | None:
    """What a typed configuration (:mod:`hypa.commands.config`) refused while Hydra composed, in the
    words of a setting checked later (``trainer.max_epochs=abc is not an integer``), or a misspelt key
    with the keys there are; ``None`` for any other error."""
    import dataclasses
    import re

    from hydra.errors import ConfigCompositionException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, ValidationError

    cause = (error.__cause__ or error.__context__) if isinstance(error, ConfigCompositionException) else error
    key = getattr(cause, "full_key", None)
    if not key:
        return None
    source = re.match(r"In '([^']+)': ", str(error))  # a config file of the defaults list, e.g. a user's model
    where = f" (in {source.group(1)}.yaml)" if source else ""
    if isinstance(cause, ValidationError):
        match = re.match(r"Value '(.*?)'(?: of type '\w+')? (?:could not be converted to (\w+)|is not a valid (bool))",
                         str(getattr(cause, "msg", "")))
        if match is None:
            return None
        expected = _CONVERSIONS.get(match.group(2) or match.group(3), "of its type")
        give = "" if expected == "true or false" else f"; give {key}=<{expected.split()[-1]}>"
        return f"{key}={match.group(1)} is not {expected}{give}{where}"
    if isinstance(cause, (ConfigAttributeError, ConfigKeyError)) and "not in" in str(getattr(cause, "msg", "")):
        schema = getattr(cause, "object_type", None)
        node = key.rpartition(".")[0]
        if not dataclasses.is_dataclass(schema):
            return None
        known = ", ".join(f.name for f in dataclasses.fields(schema))
        return f"{key}: no such setting; {node or 'the configuration'} has {known}{where}"
    return None


class DataError(UserError):
    """Measured data or the data configuration is unusable.

    The message names the file, the column and the row where that applies, and says what
    was expected. A ``UserError`` (so a ``ValueError``) so that callers unaware of hypa still catch it sensibly.
    """


def user_errors(command: str) -> Callable[[F], F]:
    """Decorate a command's ``main``, above ``@hydra.main``: a user error ends it with one line and
    exit status 1, Ctrl-C with ``<command>: interrupted`` and exit status 130 (see the module docstring)."""
    def decorate(main: F) -> F:
        @functools.wraps(main)
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            full = full_error_requested()
            os.environ["HYPA_FULL_ERROR"] = "1" if full else "0"
            os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra raises instead of printing its own report
            try:
                return main(*args, **kwargs)
            except KeyboardInterrupt:  # Ctrl-C: the user's wish, not a bug
                if full:
                    raise
                _interrupted(command)
            except SystemExit as exit_:
                # Lightning ends a fit, validation or prediction that Ctrl-C stopped with its own exit status 1
                if full or exit_.code != 1 or not isinstance(exit_.__context__, KeyboardInterrupt):
                    raise
                _interrupted(command)
            except Exception as error:
                if full or not (is_user_error(error) or _raised_composing(error)):
                    raise
                print(f"{command}: error: {one_line(error)}{_hint(error)}", file=sys.stderr, flush=True)
                sys.exit(1)

        return wrapped  # type: ignore[return-value]

    return decorate


INTERRUPTED = 130  # the shell's status of a command ended by SIGINT (128 + 2)


def _interrupted(command: str) -> None:
    """Ctrl-C: one line ``<command>: interrupted`` on stderr and exit status 130, no traceback. A
    second Ctrl-C while it ends is ignored (it would print the traceback this line replaces)."""
    import signal

    with contextlib.suppress(ValueError):  # not the main thread: nothing to ignore there
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    print(f"{command}: interrupted", file=sys.stderr, flush=True)
    sys.exit(INTERRUPTED)


def _raised_composing(error: BaseException) -> bool:
    """Raised while Hydra composed the configuration from the user's overrides (OmegaConf failing on
    a value where the schema has a typed node, e.g. ``data.splits={train:[a]}``), not by a job."""
    frames = traceback.extract_tb(error.__traceback__)
    return any(f.name == "compose_config" and "hydra" in f.filename for f in frames)


def _hint(error: BaseException) -> str:
    """What to do about an error whose own message does not say it."""
    from hydra.errors import OverrideParseException

    if isinstance(error, OverrideParseException) and "=" in str(error).split(";")[0]:
        return " (a value that holds '=' is quoted: key='a=b', a list's items too: key=['a=b'])"
    if _raised_composing(error) and not is_user_error(error):
        return " (composing the configuration from the overrides)"
    return ""



def hydra_command(command: str, config_name: str, config_path: str | Path = CONF,
                  before: Callable[[], None] | None = None) -> Callable[[Callable[[Any], Any]], Callable[..., int]]:
    """``@hydra_command("hypa train", "train")`` on a command's job ``main(cfg)``: the command's
    ``main(argv=None) -> 0`` (the shape of every command, :mod:`hypa.commands.cli`), which composes
    ``config_name`` with the overrides ``argv`` (``sys.argv[1:]`` when None) through ``@hydra.main``
    and runs the job, with one-line user errors both inside the job (hypa's code: Hydra never sees
    them) and around it (Hydra's own work: composing the configuration, creating and writing the run
    folder). ``main.job(cfg)`` runs the job on a configuration already composed (its return value:
    what a sweeper minimises). ``config_path``: the package's ``conf/`` (absolute, so a command runs
    the same whether it is imported or run as ``python -m``). ``before``: what Hydra needs before it
    composes (the commands' schemas and resolvers, :func:`hypa.commands.config.register_configs`),
    run by ``main`` first (a launcher's worker, joblib's or submitit's, gets both with Hydra's state)."""
    import hydra

    def decorate(job: Callable[[Any], Any]) -> Callable[..., int]:
        guarded_job = user_errors(command)(job)
        composed = user_errors(command)(hydra.main(config_path=str(config_path), config_name=config_name,
                                                   version_base="1.3")(guarded_job))

        def main(argv: Sequence[str] | None = None) -> int:
            if argv is not None:
                sys.argv = [sys.argv[0], *argv]
            if before is not None:
                before()
            composed()
            return 0

        main.__doc__, main.__module__ = job.__doc__, job.__module__
        main.job = guarded_job  # type: ignore[attr-defined]
        return main

    return decorate


_KIND_NAMES = {int: "an integer", float: "a number", str: "a string"}


def checked(key: str, value: Any, kind: Callable[[Any], T], choices: Collection[T] | None = None,
            optional: bool = False, minimum: float | None = None, positive: bool = False) -> T:
    """``value``, the setting ``key`` (dotted, e.g. ``trainer.max_epochs``), as ``kind``: what the typed
    configurations (:mod:`hypa.commands.config`) check their values with.

    A value that is not one (``trainer.max_epochs=abc``), a number that is not finite
    (``optimizer.lr=nan``), one below ``minimum`` or, with ``positive``, not above zero
    (``optimizer.lr=-1``), or one not among ``choices`` is the user's error and names the override
    to fix. ``optional``: ``None`` (``null``) is allowed and returned as is.
    """
    if value is None and optional:
        return None  # type: ignore[return-value]
    try:
        if kind is int and isinstance(value, float) and not value.is_integer():
            raise ValueError
        if kind in (int, float) and isinstance(value, bool):  # True is an int to Python, not to a user
            raise ValueError
        converted = kind(value)
    except (TypeError, ValueError, OverflowError):
        expected = _KIND_NAMES.get(kind, getattr(kind, "__name__", str(kind)))  # type: ignore[call-overload]
        raise UserError(f"{key}={value} is not {expected}; give {key}=<{expected.split()[-1]}>") from None
    if isinstance(converted, float) and not math.isfinite(converted):
        raise UserError(f"{key}={_shown(value)} is not a finite number")
    if positive and not converted > 0:  # type: ignore[operator]
        raise UserError(f"{key}={_shown(value)} must be > 0")
    if minimum is not None and converted < minimum:  # type: ignore[operator]
        raise UserError(f"{key}={_shown(value)} must be >= {minimum:g}")
    if choices is not None and converted not in choices:
        raise UserError(f"{key}={_shown(value)} is not one of {', '.join(map(str, choices))}")
    return converted


def _shown(value: Any) -> str:
    """A value as the user wrote it: a float field holds ``-1`` as ``-1.0``, shown ``-1``."""
    return f"{value:g}" if isinstance(value, float) else str(value)


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
