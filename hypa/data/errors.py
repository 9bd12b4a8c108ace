"""The one exception type of the data pipeline."""

from hypa.core.errors import UserError


class DataError(UserError):
    """Measured data or the data configuration is unusable.

    The message names the file, the column and the row where that applies, and says what
    was expected. A ``UserError`` (so a ``ValueError``) so that callers unaware of hypa still catch it sensibly.
    """
