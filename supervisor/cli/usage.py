"""Command-line usage errors and the exit statuses every command shares."""

from supervisor.errors import OperatorError

EXIT_REFUSED = 1  # the service (or the OS) said no; the reason is printed
EXIT_USAGE = 2  # a bad argument or setup: nothing was done
EXIT_UNREACHABLE = 3  # the service cannot be reached


class UsageError(OperatorError):
    """A command-line argument that cannot be used (exit status 2)."""
