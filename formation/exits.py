"""Exit statuses of the ``formation`` command and the error that means "invalid input"."""

from __future__ import annotations

EXIT_OK, EXIT_ERROR, EXIT_INVALID = 0, 1, 2


class UsageError(ValueError):
    """Invalid input detected by a subcommand: exit status 2, one line."""
