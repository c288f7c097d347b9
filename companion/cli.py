"""One error policy for every console script: a user's mistake is one line and exit code 2.

What the user typed or pointed at (an option, a file, a line of a file, a scenario name) is
wrong: one line on stderr, ``PROG: what, where`` (the file, line or option), exit status 2,
nothing written. Anything else is a bug in this program and keeps its traceback. Ctrl-C is
neither: exit status 130 (128 + SIGINT) after one line.

    >>> parser = ArgumentParser(prog="fcmpc-x")        # argparse mistakes: one line, exit 2
    >>> def body(args) -> int:
    ...     raise UsageError("--runs 0: at least 1")
    >>> run_main("fcmpc-x", lambda: body(None))          # prints "fcmpc-x: --runs 0: at least 1"
    2

The exceptions that count as user errors: :class:`UsageError` (raised by the scripts for
options), :class:`companion.params.ParamError` (a ``.parm`` file or a ``--param``, with file and
line), the ``OSError`` s of a path the user named (missing, a directory, no permission), and
whatever more a script names in ``user_errors`` (``sitl.scenario.ScenarioError`` for the
scripts that take ``--scenario``). This module is importable from ``companion``, ``sitl`` and
``scripts`` alike (it imports nothing outside ``companion``).
"""
from __future__ import annotations

import argparse
import sys
from typing import Callable, NoReturn

from companion.params import ParamError, validate

__all__ = ["EXIT_USAGE", "EXIT_INTERRUPTED", "USER_ERRORS", "UsageError", "ArgumentParser", "one_line",
           "param_items", "positive_int", "run_main", "user_error"]

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130          # 128 + SIGINT, what a shell reports for Ctrl-C


class UsageError(Exception):
    """A mistake in what the user asked for; the message names the option, file or line."""


USER_ERRORS: tuple[type[BaseException], ...] = (UsageError, ParamError, FileNotFoundError, IsADirectoryError,
                                                NotADirectoryError, PermissionError)


def one_line(err: BaseException) -> str:
    """The error as one line: ``file: reason`` for OSErrors, newlines folded otherwise."""
    if isinstance(err, OSError) and err.filename is not None and err.strerror:
        text = f"{err.filename}: {err.strerror}"
    else:
        text = str(err) or type(err).__name__
    return " ".join(text.split())


def user_error(prog: str, err: BaseException | str) -> int:
    """Print ``PROG: message`` on stderr; returns :data:`EXIT_USAGE` for ``return user_error(...)``."""
    text = err if isinstance(err, str) else one_line(err)
    print(f"{prog}: {text}", file=sys.stderr, flush=True)
    return EXIT_USAGE


class ArgumentParser(argparse.ArgumentParser):
    """argparse with the one-line policy: ``PROG: error: MESSAGE (see PROG --help)``, exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def run_main(prog: str, body: Callable[[], int], user_errors: tuple[type[BaseException], ...] = ()) -> int:
    """Call ``body()``; a user error -> one line and 2, Ctrl-C -> one line and 130, a bug -> traceback."""
    try:
        return body()
    except USER_ERRORS + tuple(user_errors) as err:
        return user_error(prog, err)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED


def positive_int(text: str) -> int:
    """An argparse ``type``: a whole number >= 1 (argparse's one-line error names it so)."""
    value = int(text)
    if value < 1:
        raise ValueError(text)
    return value


positive_int.__name__ = "integer >= 1"     # argparse names the type in its one-line error


def param_items(items: list[str], option: str = "--param") -> dict[str, float | int]:
    """``NAME=VALUE`` items of a repeatable option, each checked against the parameter registry;
    a :class:`UsageError` names the option and the bad item."""
    values: dict[str, float | int] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise UsageError(f"{option} {item!r}: expected NAME=VALUE")
        try:
            values[name.strip().upper()] = validate(name.strip(), value.strip())
        except ParamError as err:
            raise UsageError(f"{option} {item}: {err}") from None
    return values
