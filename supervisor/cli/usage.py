"""Command-line usage errors (exit status 2), shared by every command's module."""


class UsageError(Exception):
    """A command-line argument that cannot be used (exit status 2)."""
