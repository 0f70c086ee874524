"""The one error type users see: a message and a hint, printed as one line with exit code 2."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class LabError(Exception):
    """Bad input or state the user can fix; anything else is a bug and keeps its traceback."""

    exit_code = 2

    def __init__(self, message: str, hint: str | None = None):
        super().__init__(message)
        self.message = message
        self.hint = hint

    def __str__(self) -> str:
        return f"{self.message} ({self.hint})" if self.hint else self.message


class LabValueError(LabError, ValueError):
    """A bad value: also Python's ValueError, which a library's caller (gymnasium's clients)
    catches, as gymnasium's own envs raise it."""


class LabTypeError(LabError, TypeError):
    """A value of the wrong type: also Python's TypeError, as gymnasium's own envs raise it."""


class TrainingDiverged(LabError):
    """Training cannot go on (the policy emits non-finite actions); the run dir keeps its last
    good checkpoint. Exit code 3 tells it apart from bad input."""

    exit_code = 3


class Interrupted(LabError):
    """SIGINT or SIGTERM before there was a run to save; exits 128 + the signal's number."""

    def __init__(self, message: str, exit_code: int):
        super().__init__(message)
        self.exit_code = exit_code


def one_line(text: str) -> str:
    """`text` with what is not printable escaped (a newline, or a control character from a
    file's key, which a terminal or `splitlines` takes for a line break): an error stays one
    line whatever it quotes."""
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii")
                   for ch in text)


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type's name where it has none): what one
    line of error output can quote."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def unknown_name(kind: str, name: str, known: Iterable[str]) -> LabError:
    """An error for a name that is not among `known`, suggesting the closest one."""
    known = sorted(known)
    close = difflib.get_close_matches(name, known, n=1)
    hint = f"did you mean '{close[0]}'? " if close else ""
    hint += f"known {kind}s: {', '.join(known) if known else 'none'}"
    return LabError(f"unknown {kind} '{name}'", hint)
