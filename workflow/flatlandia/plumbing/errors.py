"""One error type for bad input, so every rule fails with the file and the problem named."""

from __future__ import annotations

from pathlib import Path

#: longest problem an error line carries: whatever a message quotes from a hostile file (a 100 MB
#: token, a 1 MB class name), the ERROR line stays readable (flatlandia.plumbing.validate.shown cuts quotes)
MAX_PROBLEM_CHARS = 4000


class InputError(ValueError):
    """Raised when an input file is missing, unreadable or semantically wrong. Its text is one line
    without control or invisible characters (escaped as ``escape.terminal`` writes them), whatever
    a message quotes: a library's own words about a hostile file (pyarrow's hold its bytes) included."""

    def __init__(self, path: str | Path, problem: str):
        from flatlandia.plumbing.escape import terminal  # light: the standard library only

        self.path = terminal(str(path)[:MAX_PROBLEM_CHARS])
        problem = str(problem)
        if len(problem) > MAX_PROBLEM_CHARS:
            problem = f"{problem[:MAX_PROBLEM_CHARS]}... (cut: {len(problem):,} characters)"
        self.problem = terminal(problem)
        super().__init__(f"{self.path}: {self.problem}")
