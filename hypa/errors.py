"""One-line errors for the entry points: a user's mistake is not a bug, so it gets no traceback.

``@user_errors("hypa.train")`` under ``@hydra.main`` turns the errors that describe bad input
(data, model configuration, a user's system, physics that cannot run, a missing run folder) into
``hypa.train: error: <message>`` on stderr and exit status 1. Anything else is a bug and keeps its
traceback; ``HYDRA_FULL_ERROR=1`` keeps the traceback for user errors too.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


class UserError(ValueError):
    """Bad input that the message explains (e.g. a benchmark model that failed to train)."""


def user_error_types() -> tuple[type[BaseException], ...]:
    from hypa.data.errors import DataError
    from hypa.models.spec import ModelSpecError
    from hypa.physics import SchedulingError, UnstablePhysicsError
    from hypa.physics.contract import SystemContractError

    return (UserError, DataError, ModelSpecError, SystemContractError, UnstablePhysicsError, SchedulingError,
            FileNotFoundError)


def user_errors(command: str) -> Callable[[F], F]:
    def decorate(main: F) -> F:
        @functools.wraps(main)
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            try:
                return main(*args, **kwargs)
            except user_error_types() as error:
                if os.environ.get("HYDRA_FULL_ERROR") == "1":
                    raise
                print(f"{command}: error: {error}", file=sys.stderr, flush=True)
                sys.exit(1)

        return wrapped  # type: ignore[return-value]

    return decorate
