"""What fogfleet's two commands, ``fogfleet`` and ``kubectl fogfleet``, share: how an error
ends a command, decided here only (httpx style: exceptions translated in one place), and the
argparse types their options share.

Exit codes, the same for every subcommand of both:

    0  OK           the command did what it was asked
    1  FAILED       fogfleet could not do it: a cluster or Prometheus did not answer
                    (``DependencyUnavailable``), or another ``FogfleetError``
    2  BAD_INPUT    the input is wrong: a file, a field, a reference, a fleet or module that is
                    not there, a fleet no placement fits (``InvalidSpec`` and its kinds); also
                    argparse's own code for a bad option

An exception that is not a ``FogfleetError`` is a bug: it ends in a traceback, never as bad
input.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import TypeVar

from fogfleet.errors import FogfleetError, InvalidSpec

__all__ = ["BAD_INPUT", "FAILED", "OK", "exit_code", "positive", "run_command"]

OK = 0
FAILED = 1
BAD_INPUT = 2

Number = TypeVar("Number", int, float)


def exit_code(exc: FogfleetError) -> int:
    """The exit code of a command that ended with ``exc``."""
    return BAD_INPUT if isinstance(exc, InvalidSpec) else FAILED


def run_command(command: Callable[[], int]) -> int:
    """``command()``'s exit code; a ``FogfleetError`` it raises is printed on stderr as
    ``error: ...`` and ends it with its ``exit_code``. A closed pipe (``fogfleet render |
    head``) is no failure."""
    try:
        return command()
    except FogfleetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exit_code(exc)
    except BrokenPipeError:  # pragma: no cover - the reader left
        return OK


def positive(kind: Callable[[str], Number]) -> Callable[[str], Number]:
    """An argparse type: a number above zero (argparse then exits 2 naming the option)."""

    def parse(text: str) -> Number:
        value = kind(text)  # a ValueError: argparse says "invalid float value: 'x'"
        if not value > 0:  # also refuses nan
            raise argparse.ArgumentTypeError(f"must be greater than zero, not {text}")
        return value

    parse.__name__ = kind.__name__
    return parse
