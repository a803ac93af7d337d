"""The project's exception root, split by who caused the error (as h11 splits local from
remote protocol errors): the operator (answer with the reason, change nothing), a remote
peer (a vehicle, the mocap source, the other process), or this program itself."""

from __future__ import annotations


class SupervisorError(Exception):
    """Any error the supervisor raises on purpose."""


class OperatorError(SupervisorError):
    """The operator asked for something malformed or impossible: a bad setpoint, setup,
    argument or request. Refused with the reason; nothing is left half-done."""


class RemoteError(SupervisorError):
    """A peer misbehaved or went away: a vehicle refused or did not answer, a channel to
    the other process closed."""


class LocalError(SupervisorError):
    """This program broke one of its own rules (a bug, not an input)."""
