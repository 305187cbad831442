"""One error type for bad input, so every rule fails with the file and the problem named."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Raised when an input file is missing, unreadable or semantically wrong."""

    def __init__(self, path: str | Path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
