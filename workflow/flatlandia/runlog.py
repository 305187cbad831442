"""Logging for rule scripts: everything (including tqdm progress) goes to the rule's log."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")


def setup(log_path: str | Path | None, name: str = "flatlandia") -> logging.Logger:
    """Log to ``log_path`` (and stderr when none is given); return the logger."""
    logger = logging.getLogger(name)
    logger.handlers.clear()
    logger.setLevel(logging.INFO)
    if log_path:
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        open(log_path, "w").close()  # start empty, then append: native code appends to it too
        handler: logging.Handler = logging.FileHandler(log_path, mode="a")
    else:
        handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    logger.addHandler(handler)
    return logger


def progress(logger: logging.Logger, desc: str):
    """A tqdm wrapper writing its bar into the logger's file (or stderr)."""
    stream = sys.stderr
    for h in logger.handlers:
        if isinstance(h, logging.FileHandler):
            stream = h.stream
            break

    def wrap(items: Iterable[T]) -> Iterable[T]:
        return tqdm(items, desc=desc, file=stream, mininterval=1.0, ascii=True)

    return wrap


def run(main, smk) -> None:
    """Run a rule script's ``main(smk, logger)``; bad input ends it with one clear line.

    An :class:`InputError` (or any error) is written to the rule's log and to stderr as
    ``ERROR: <file>: <problem>`` and the script exits 1, so Snakemake reports the rule failed.
    """
    from flatlandia import provenance
    from flatlandia.errors import InputError

    logger = setup(smk.log[0] if len(smk.log) else None)
    provenance.started()
    try:
        main(smk, logger)
        logger.info("provenance: %s", provenance.write_record(smk))
    except InputError as e:
        logger.error("%s", e)
        print(f"ERROR: {e}", file=sys.stderr)
        raise SystemExit(1) from None
    except Exception:
        logger.exception("rule failed")
        raise


@contextlib.contextmanager
def native_output_to(log_path: str | Path | None):
    """Send what compiled libraries (COLMAP's glog) print on fds 1 and 2 into the rule's log."""
    if not log_path:
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with open(log_path, "ab", buffering=0) as f:
        os.dup2(f.fileno(), 1)
        os.dup2(f.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
