"""flatlandia.plumbing.scheduler: Snakemake's scheduler keeps one wake-up pending, not one per finished job."""

from __future__ import annotations

import threading
import time
import types

from snakemake.scheduling.job_scheduler import JobScheduler

from flatlandia.plumbing import scheduler


def _fake_scheduler():
    return types.SimpleNamespace(_open_jobs=threading.Semaphore(0))


def _wakeups(sem: threading.Semaphore) -> int:
    n = 0
    while sem.acquire(blocking=False):
        n += 1
    return n


def test_install_replaces_the_reevaluation_timer_once():
    workflow = types.SimpleNamespace(is_main_process=True)
    assert scheduler.install(workflow)
    assert JobScheduler._schedule_reevalutation is scheduler._one_pending_timer
    assert scheduler.install(workflow)  # idempotent
    assert JobScheduler._schedule_reevalutation is scheduler._one_pending_timer


def test_a_job_of_a_cluster_run_changes_nothing():
    assert not scheduler.install(types.SimpleNamespace(is_main_process=False))


def test_many_passes_arm_one_wakeup():
    """Fifty passes in a row (as fifty finished jobs trigger) wake the scheduler once, not fifty
    times; once it has fired, the next pass arms the next one."""
    fake = _fake_scheduler()
    for _ in range(50):
        scheduler._one_pending_timer(fake, 0.05)
    time.sleep(0.3)
    assert _wakeups(fake._open_jobs) == 1
    scheduler._one_pending_timer(fake, 0.05)
    time.sleep(0.3)
    assert _wakeups(fake._open_jobs) == 1


def test_snakemakes_own_timer_multiplies_wakeups():
    """The behaviour replaced: Snakemake's method arms a timer per pass (so this test fails, and the
    fix can go, once Snakemake arms one)."""
    scheduler.install(types.SimpleNamespace(is_main_process=True))
    original = scheduler.replaced
    fake = _fake_scheduler()
    for _ in range(10):
        original(fake, 0.05)
    time.sleep(0.3)
    assert _wakeups(fake._open_jobs) == 10
