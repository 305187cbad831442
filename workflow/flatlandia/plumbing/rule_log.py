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


class _LogFile(logging.FileHandler):
    """The rule's log file; a write that finds the disk full is remembered (``full``), not printed
    with a traceback at every line: the rule ends with one ERROR line (:func:`run`)."""

    full: OSError | None = None

    def handleError(self, record: logging.LogRecord) -> None:
        from flatlandia.plumbing.files import full_disk_error

        err = full_disk_error(sys.exc_info()[1])
        if err is None:
            super().handleError(record)
        elif self.full is None:
            self.full = err


def _log_full(logger: logging.Logger) -> tuple[str, OSError] | None:
    """(the log file, its error) when a line could not be written to the rule's log for want of room."""
    for h in logger.handlers:
        if isinstance(h, _LogFile) and h.full is not None:
            return h.baseFilename, h.full
    return None


def disk_full_line(err: OSError, fallback: str) -> str:
    """The one line a run out of room ends with (after ``ERROR: ``): the file, what happened, what to do."""
    from flatlandia.plumbing.files import FULL_ERRNOS

    where = err.filename or fallback
    return (
        f"{where}: {FULL_ERRNOS.get(err.errno, 'no space left on device')}; nothing half-written is kept: "
        "free some space (or run in a folder on a larger disk: snakemake -d <folder>), then rerun the same command"
    )


def setup(log_path: str | Path | None, name: str = "flatlandia") -> logging.Logger:
    """Log to ``log_path`` (and stderr when none is given); return the logger."""
    logger = logging.getLogger(name)
    logger.handlers.clear()
    logger.setLevel(logging.INFO)
    if log_path:
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        open(log_path, "w").close()  # start empty, then append: native code appends to it too
        handler: logging.Handler = _LogFile(log_path, mode="a")
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

    While it runs, the writers of :mod:`flatlandia.plumbing.files` write only inside
    :func:`write_roots`. An :class:`InputError` is written to the rule's log and to stderr as ``ERROR: <file>: <problem>``
    and the script exits 1, so Snakemake reports the rule failed; so is a write that found the disk
    full or the quota used up (``ERROR: <file>: no space left on device; ...``; the atomic writers of
    :mod:`flatlandia.plumbing.files` name the output and have removed their temporary). Any other error is
    logged with its traceback and raised.
    """
    from flatlandia.plumbing import escape, files, provenance
    from flatlandia.plumbing.errors import InputError
    from flatlandia.plumbing.files import full_disk_error

    logger = setup(smk.log[0] if len(smk.log) else None)
    provenance.started()
    try:
        with files.write_roots(*write_roots(smk)):
            main(smk, logger)
            logger.info("provenance: %s", provenance.write_record(smk))
    except InputError as e:
        logger.error("%s", e)
        print(f"ERROR: {escape.terminal(e)}", file=sys.stderr)  # Snakemake shows it: no raw controls
        raise SystemExit(1) from None
    except Exception as e:
        full = full_disk_error(e)
        if full is None:
            logger.exception("rule failed")
            raise
        _end_out_of_room(logger, disk_full_line(full, _unnamed_write(logger, smk)))
    log_full = _log_full(logger)
    if log_full:  # the outputs are whole, their log is not: the disk is full for the next rule anyway
        _end_out_of_room(logger, disk_full_line(log_full[1], log_full[0]))


def write_roots(smk) -> list[Path]:
    """Where a rule script may write (flatlandia.plumbing.files.write_roots): the working folder's
    results/, resources/ and logs/, and the folders of the job's own outputs and log (a fetch flag
    beside a data folder outside the working folder); a path built from a hostile input elsewhere is refused."""
    from flatlandia.plumbing.files import RUN_FOLDERS

    declared = [*(getattr(smk, "output", None) or []), *(getattr(smk, "log", None) or [])]
    return [Path.cwd() / f for f in RUN_FOLDERS] + [Path(p).absolute().parent for p in declared]


def _unnamed_write(logger: logging.Logger, smk) -> str:
    """Which file an out-of-room error without a file name was about: the atomic writers name
    theirs, so the log (a progress bar writes to it directly) when its disk is full, else the
    rule's first output."""
    from flatlandia.plumbing.files import disk_full

    log_full = _log_full(logger)
    if log_full:
        return log_full[0]
    log = [h.baseFilename for h in logger.handlers if isinstance(h, _LogFile)]
    if log and disk_full(Path(log[0]).parent):
        return log[0]
    outputs = list(getattr(smk, "output", None) or [])
    return str(outputs[0]) if outputs else "the run folder"


def _end_out_of_room(logger: logging.Logger, line: str) -> None:
    """A write ran out of room: one ERROR line, exit 1 (the log, if it has room, also names the
    writer's own error, without a traceback: Snakemake shows the log of a failed rule)."""
    logger.error("%s", line)
    first, seen = sys.exc_info()[1], set()
    while first is not None and (first.__cause__ or first.__context__) is not None and id(first) not in seen:
        seen.add(id(first))
        first = first.__cause__ or first.__context__
    if first is not None:
        logger.info("the writer's error: %s: %s", type(first).__name__, first)
    print(f"ERROR: {line}", file=sys.stderr)
    raise SystemExit(1) from None


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
