"""The ``ERROR:`` and ``WARNING:`` lines of every command, on stderr: a result on stdout redirected
into a file never hides one. Their text quotes files (names, values), so it is escaped for the
terminal (:func:`escape.terminal`: one line, no ESC or bidi override of a file's reaching the
terminal)."""

from __future__ import annotations

import sys

from flatlandia.plumbing import escape


def error(text: str) -> None:
    """An ``ERROR:`` line, on stderr."""
    print(f"ERROR: {escape.terminal(text)}", file=sys.stderr)


def warning(text: str) -> None:
    """A ``WARNING:`` line, on stderr beside the errors."""
    print(f"WARNING: {escape.terminal(text)}", file=sys.stderr)
