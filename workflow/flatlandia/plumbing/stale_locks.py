"""Snakemake's lock of a working folder, when the run that held it was killed.

Snakemake locks a working folder for a run (``.snakemake/locks/<n>.input.lock`` and
``<n>.output.lock``: the files the run reads and writes) and removes the lock when the run ends,
whether it succeeds or fails. A run killed with SIGKILL (or a power loss) leaves its lock, and the
next run on the same files stops: "Directory cannot be locked ... It can be removed with the
--unlock argument". Unlocking blindly is unsafe (a run still going would have its files rebuilt
under it) and Snakemake's lock files do not say who holds them.

So each lock file this workflow's runs write gets an owner note beside it (``owner-<lock>.json``:
user, host, machine, boot, pid namespace, Snakemake's pid and start time, its process group,
whether it executes its jobs locally). Right before a later run takes its lock (never in a dry
run), a lock is removed when its note proves the run gone: the same user, host, boot (so the same
machine; a lock from before a restart of the same machine, by its machine id, is stale) and pid
namespace; the local executor; the process gone (or its pid now another process's); no
process left in its process group; no job script of this folder still running. A lock without
such proof (a run still going, one on another machine or of a cluster executor, another user's,
one of a version that left no note) is kept and Snakemake refuses as before, after one line that
says whose it is and what to do.

:func:`install` (called when the Snakefile is read) wraps Snakemake's ``FilePersistence.lock``
and ``_write_locks``; should they change, it wraps nothing and Snakemake behaves as without it.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import socket
import sys
from datetime import UTC, datetime
from pathlib import Path

#: Snakemake's lock files (as its FilePersistence._read_locks reads them)
LOCK_NAME = re.compile(r"^[0-9]+\.(input|output)\.lock$")
#: the owner note of lock file ``<lock>``, beside it (not a name Snakemake reads as a lock)
OWNER_PREFIX = "owner-"
_MAX_NOTE_BYTES = 65536


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read().strip() or None
    except OSError:
        return None


def _identity() -> dict:
    """What two processes must share for one to judge the other by its pid."""
    try:
        pidns = os.stat("/proc/self/ns/pid").st_ino
    except OSError:
        pidns = None
    return {
        "uid": os.getuid(),
        "host": socket.gethostname(),
        "machine": _read("/etc/machine-id"),
        "boot": _read("/proc/sys/kernel/random/boot_id"),
        "pidns": pidns,
    }


def _proc_stat(pid: int) -> tuple[str, int, int] | None:
    """(state, process group, start time in clock ticks since boot) of a process, None if gone."""
    text = _read(f"/proc/{pid}/stat")
    if text is None:
        return None
    fields = text[text.rfind(")") + 2 :].split()  # after "pid (comm) ": state is field 3 of stat(5)
    try:
        return fields[0], int(fields[2]), int(fields[19])
    except (IndexError, ValueError):
        return None


def _processes() -> list[int]:
    return [int(n) for n in os.listdir("/proc") if n.isdigit()] if os.path.isdir("/proc") else []


def _group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid``."""
    out = []
    for pid in _processes():
        st = _proc_stat(pid)
        if st is not None and st[1] == pgid and st[0] != "Z":
            out.append(pid)
    return out


def _job_scripts_running(folder: Path) -> list[int]:
    """Processes running a job script of the working folder ``folder`` (Snakemake writes the
    script of each ``script:`` job to ``.snakemake/scripts/`` there and runs it)."""
    scripts = tuple(
        {str(f / ".snakemake" / "scripts") + os.sep for f in (Path(os.path.abspath(folder)), folder.resolve())}
    )
    me = os.getpid()
    out = []
    for pid in _processes():
        if pid == me:
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                args = f.read().split(b"\0")
        except OSError:
            continue
        if any(a.decode(errors="replace").startswith(scripts) for a in args):
            st = _proc_stat(pid)
            if st is not None and st[0] != "Z":
                out.append(pid)
    return out


def owner_note(lockfile: Path) -> Path:
    return lockfile.with_name(OWNER_PREFIX + lockfile.name + ".json")


def claim(lockfile: Path, local: bool) -> None:
    """Write the owner note of ``lockfile``, just written by this process (Snakemake's main one)."""
    st = lockfile.stat()
    me = os.getpid()
    start = _proc_stat(me)
    note = {
        **_identity(),
        "pid": me,
        "start_ticks": start[2] if start else None,
        "pgid": os.getpgid(0) if os.getpgid(0) == me else None,  # its jobs share its group then
        "local": bool(local),
        "lock": lockfile.name,
        "lock_ino": st.st_ino,
        "lock_mtime_ns": st.st_mtime_ns,
        "lock_size": st.st_size,
        "started": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    path = owner_note(lockfile)
    tmp = path.with_name(f".{path.name}.{me}.tmp")
    tmp.write_text(json.dumps(note) + "\n")
    os.replace(tmp, path)


def _load_note(lockfile: Path) -> dict | None:
    path = owner_note(lockfile)
    try:
        if path.is_symlink() or path.stat().st_size > _MAX_NOTE_BYTES:
            return None
        note = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return note if isinstance(note, dict) else None


def _who(note: dict) -> str:
    started = str(note.get("started", "?")).replace("T", " ").replace("+00:00", " UTC")
    return f"Snakemake pid {note.get('pid')} on {note.get('host')}, started {started}"


def judge(lockfile: Path, folder: Path | None = None) -> tuple[bool, str]:
    """(stale, why): whether the run that wrote ``lockfile`` is provably gone, and in words whose
    lock it is. Any doubt keeps the lock."""
    folder = folder or lockfile.parent.parent.parent  # <folder>/.snakemake/locks/<lock>
    note = _load_note(lockfile)
    if note is None:
        return False, (
            "a run of unknown owner (its lock has no owner note: a run of an earlier version of the workflow, "
            "or one killed as it locked)"
        )
    try:
        st = lockfile.stat()
    except OSError:
        return False, "a run that ended meanwhile"
    binding = (note.get("lock"), note.get("lock_ino"), note.get("lock_mtime_ns"), note.get("lock_size"))
    if binding != (lockfile.name, st.st_ino, st.st_mtime_ns, st.st_size):
        return False, "a run of unknown owner (its owner note belongs to another lock file)"
    who = _who(note)
    me = _identity()
    if note.get("uid") != me["uid"]:
        return False, f"another user's run ({who})"
    if note.get("host") != me["host"]:
        return False, f"a run on another machine ({who})"
    if not note.get("local"):
        return False, f"a run with a cluster executor ({who}): its jobs may still be running"
    if me["boot"] is None or note.get("boot") != me["boot"]:  # not this boot of this machine: which, then?
        if me["boot"] and note.get("boot") and me["machine"] and note.get("machine") == me["machine"]:
            return True, f"a run from before this machine restarted ({who})"
        return False, f"a run on another machine, or one this machine cannot check ({who})"
    if _proc_stat(os.getpid()) is None:
        return False, f"a run this system cannot check (no /proc) ({who})"
    if note.get("pidns") != me["pidns"] or me["pidns"] is None:
        return False, f"a run in another container ({who})"
    pid, start = note.get("pid"), note.get("start_ticks")
    if not isinstance(pid, int) or pid <= 0:
        return False, f"a run of unknown owner (unreadable owner note: {who})"
    st_pid = _proc_stat(pid)
    if st_pid is not None and st_pid[0] != "Z" and (start is None or st_pid[2] == start):
        return False, f"a run still going ({who})"  # (its pid taken by another process: a later start time)
    pgid = note.get("pgid")
    if isinstance(pgid, int) and pgid > 0:
        left = [p for p in _group_members(pgid) if p != os.getpid()]
        if left:
            return False, f"a killed run whose process(es) {left[:5]} still run ({who})"
    jobs = _job_scripts_running(folder)
    if jobs:
        return False, f"a killed run, while job scripts of this folder still run (pid {jobs[:5]}) ({who})"
    return True, f"a run killed here ({who}; no process of it is left)"


def clear_stale(locks: Path, say=None) -> tuple[list[Path], list[str]]:
    """Remove the lock files in ``locks`` (``.snakemake/locks``) whose run is provably gone, with
    their owner notes. Returns (removed lock files, why each kept lock is kept)."""
    say = say or (lambda line: None)
    removed: list[Path] = []
    kept: list[str] = []
    if not locks.is_dir():
        return removed, kept
    gone: dict[str, None] = {}
    for lockfile in sorted(p for p in locks.iterdir() if LOCK_NAME.match(p.name)):
        if not lockfile.exists():
            continue  # removed meanwhile (by the run that held it, or another run's start)
        stale, why = judge(lockfile, locks.parent.parent)
        if not stale:
            kept.append(why)
            continue
        for path in (lockfile, owner_note(lockfile)):
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        removed.append(lockfile)
        gone[why] = None
    for why in gone:
        say(f"flatlandia: removed the lock of {why}; its unfinished jobs run again")
    return removed, kept


def refusal_line(kept: list[str]) -> str:
    """The one line said when Snakemake is about to refuse a lock that was kept."""
    whose = "; ".join(dict.fromkeys(kept))
    if all(w.startswith("a run still going") for w in kept):
        return (
            f"ERROR: this folder's files are in use by {whose}: wait for it to end (two runs on the same "
            "files would corrupt them), or run in a folder of its own: snakemake -d <folder> ..."
        )
    return (
        f"ERROR: this folder holds the lock of {whose}. If no other Snakemake run uses this folder, rerun the "
        "same command with --unlock added (it removes the lock and runs nothing), then once more without it"
    )


def install(workflow) -> bool:
    """In Snakemake's main process, wrap the lock of its file persistence (see the module's
    docstring); True when wrapped (or already)."""
    if not getattr(workflow, "is_main_process", False):
        return False  # a job of a cluster run (or a spawned job): the main process holds the lock
    try:
        from snakemake.persistence.file import FilePersistence
    except ImportError:
        return False
    lock, write_locks = getattr(FilePersistence, "lock", None), getattr(FilePersistence, "_write_locks", None)
    if lock is None or write_locks is None:
        return False
    if getattr(lock, "_flatlandia", False):
        return True

    @contextlib.contextmanager
    def flatlandia_lock(self):
        locks = Path(getattr(self, "_lockdir", Path(self.path) / "locks"))
        _, kept = clear_stale(locks, say=lambda line: print(line, file=sys.stderr))
        if kept and self.locked:
            print(refusal_line(kept), file=sys.stderr)
        with lock(self):
            yield

    def flatlandia_write_locks(self, lock_type, keys):
        from flatlandia.plumbing.files import FULL_ERRNOS

        try:
            write_locks(self, lock_type, keys)
        except OSError as e:
            if (
                e.errno in FULL_ERRNOS
            ):  # one line, as for a rule that finds the disk full (flatlandia.plumbing.rule_log)
                sys.exit(
                    f"ERROR: {self.path}: {FULL_ERRNOS[e.errno]} (Snakemake could not write its lock): free some "
                    "space, then rerun the same command"
                )
            raise
        path = getattr(self, "_lockfile", {}).get(lock_type)
        if path:
            dag = getattr(self, "dag", None)
            local = bool(getattr(getattr(dag, "workflow", None), "local_exec", False))
            with contextlib.suppress(OSError):  # without a note the lock is only ever removed by hand
                claim(Path(path), local)

    flatlandia_lock._flatlandia = True
    FilePersistence.lock = flatlandia_lock
    FilePersistence._write_locks = flatlandia_write_locks
    return True
