"""The command line's argument parser: one-line errors, human units, no abbreviations.

Standard library only (every command builds this parser before anything else runs).
"""

from __future__ import annotations

import argparse
import difflib
import math
import re
import sys
import textwrap
from typing import Any, NoReturn

from supervisor.cli.usage import EXIT_USAGE

PROG = "uavbar-supervisor"
# argparse's own wording of the two typos a "did you mean" answers.
INVALID_CHOICE = re.compile(r"invalid choice: '([^']*)' \(choose from (.*)\)")
UNRECOGNIZED = re.compile(r"unrecognized arguments: (.*)")
QUOTED = re.compile(r"'([^']*)'")


class HelpFormatter(argparse.HelpFormatter):
    """Paragraphs of descriptions and epilogs wrapped to the terminal, except indented
    lines (examples), which are kept as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        paragraphs = []
        for paragraph in text.split("\n\n"):
            lines = paragraph.splitlines()
            if any(line.startswith(" ") for line in lines):
                paragraphs.append("\n".join(indent + line for line in lines))
            else:
                paragraphs.append(
                    textwrap.fill(
                        " ".join(lines), width, initial_indent=indent, subsequent_indent=indent
                    )
                )
        return "\n\n".join(paragraphs)


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line (the usage is in ``--help``) and
    which takes no abbreviated options: ``--yaw`` must never be read as ``--yaw-deg``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        hint = self._did_you_mean(message)
        print(f"{self.prog}: {message}{hint} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(EXIT_USAGE)

    def _did_you_mean(self, message: str) -> str:
        """``; did you mean 'status'?`` for a mistyped command or option, else nothing."""
        choice = INVALID_CHOICE.search(message)
        if choice is not None:
            typed, choices = choice.group(1), QUOTED.findall(choice.group(2))
        else:
            unknown = UNRECOGNIZED.search(message)
            if unknown is None:
                return ""
            typed, choices = unknown.group(1).split()[0], sorted(_option_strings(self))
        close = difflib.get_close_matches(typed, choices, n=1)
        return f"; did you mean '{close[0]}'?" if close else ""


def _option_strings(parser: argparse.ArgumentParser) -> set[str]:
    """Every option ``parser`` and its commands take (argparse reports an option unknown
    to a command from the top-level parser, which knows only its own)."""
    options = set(parser._option_string_actions)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for command in action.choices.values():
                options |= _option_strings(command)
    return options


def finite_float(text: str) -> float:
    """An argument that is a finite number (JSON has no NaN or infinity)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def positive_float(text: str) -> float:
    """An argument that is a finite number > 0."""
    value = finite_float(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return value


def non_negative_float(text: str) -> float:
    """An argument that is a finite number >= 0."""
    value = finite_float(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return value


class VersionAction(argparse.Action):
    """``--version``: the installed distribution's version (looked up only when asked)."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, *_: Any) -> None:
        from importlib.metadata import PackageNotFoundError, version

        try:
            number = version(PROG)
        except PackageNotFoundError:
            number = "(not installed: running from a source tree)"
        print(f"{PROG} {number}")
        parser.exit()
