"""The one exception type of the data pipeline (it lives with the other user errors in
:mod:`hypa.core.errors`, where the units raise it too)."""

from hypa.core.errors import DataError

__all__ = ["DataError"]
