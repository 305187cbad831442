"""Snakemake's scheduler re-evaluates once a second, not once a second per finished job.

Snakemake (9.x, measured on 9.27.1) ends every scheduling pass of a local run by starting a new
one-second timer that wakes the scheduler again (``JobScheduler._schedule_reevalutation``, armed
by the default job rate limit ``--max-jobs-per-timespan 100/1s``). A pass woken by a finished job
starts a timer too, and that timer's pass starts the next: every finished job adds a chain of
wake-ups that never ends. After K finished jobs the scheduler runs about K passes a second, each
walking every ready job (their params and resources reset, inputs checked, the job selector run),
so its own CPU grows with the square of the run's jobs, taken from the jobs on a 2-core machine.

:func:`install` (called when the Snakefile is read) keeps at most one wake-up pending: a pass that
finds a timer already armed starts none. The scheduler still wakes at least once a second while
jobs wait (what the rate limit needs) and on every finished job, as before; only the duplicate
wake-ups go. Should Snakemake change the method, nothing is wrapped and it behaves as without it.
Measured in ``docs/measurements.md`` ("The scheduler's own CPU").
"""

from __future__ import annotations

import threading


def _one_pending_timer(self, delay) -> None:
    """Arm the scheduler's wake-up unless one is armed already."""
    pending = getattr(self, "_flatlandia_wakeup", None)
    if pending is not None and pending.is_alive():
        return
    timer = threading.Timer(delay, self._open_jobs.release)
    timer.daemon = True  # never keeps a finished run's process alive
    self._flatlandia_wakeup = timer
    timer.start()


_one_pending_timer._flatlandia = True
#: Snakemake's own method, kept when replaced (the tests show what it did)
replaced = None


def install(workflow) -> bool:
    """In Snakemake's main process, replace the scheduler's re-evaluation timer (see the module's
    docstring); True when replaced (or already)."""
    if not getattr(workflow, "is_main_process", False):
        return False
    try:
        from snakemake.scheduling.job_scheduler import JobScheduler
    except ImportError:
        return False
    current = getattr(JobScheduler, "_schedule_reevalutation", None)
    if current is None:
        return False
    if getattr(current, "_flatlandia", False):
        return True
    global replaced
    replaced = current
    JobScheduler._schedule_reevalutation = _one_pending_timer
    return True
