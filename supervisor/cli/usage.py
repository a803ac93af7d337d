"""Command-line usage errors (exit status 2), shared by every command's module."""

from supervisor.errors import OperatorError


class UsageError(OperatorError):
    """A command-line argument that cannot be used (exit status 2)."""
