"""Atomic writers for our artifacts, the one door every write goes through, and the temporaries a
killed run leaves behind.

Every writer checks its target first (:func:`check_target`: a regular file or a new name, never a
device, a link, a Python installation, a virtualenv, the source tree, a dot-folder, an input of the
command or an artifact of the run; inside the :func:`write_roots` when a rule or command sets them).
Every writer goes through a temporary file in the same folder and an atomic rename, so a
crash never leaves a half-written output behind; nor does a full disk, even under a writer that
does not report it (see :func:`disk_full`). A run killed mid-write leaves a temporary that the
next run's start removes (:func:`clean_stale_partials`). The readers of the published files are
:mod:`flatlandia.data.published`.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import json
import math
import os
import re
import shutil
import site
import socket
import stat
import sys
import sysconfig
import tempfile
from collections.abc import Iterable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd

# --------------------------------------------------------------------------- atomic writes
#
# Every temporary the workflow creates beside an output is named ``.<name>.partial-<host>-<pid>-<random>``
# (``<host>``: 8 hex digits of the host name's sha256; files keep the target's suffix after the random
# part) and a temporary folder also holds a PARTIAL_MARKER file naming its process and host. A run
# killed mid-write leaves such a temporary; :func:`clean_stale_partials` (the Snakefile's ``onstart``)
# removes those whose process is gone, and nothing else.

#: The file inside each temporary folder of the workflow: JSON {pid, host, created, for}.
PARTIAL_MARKER = ".flatlandia-partial"
_PARTIAL_NAME = re.compile(
    r"^\..*\.partial-(?P<host>[0-9a-f]{8})-(?P<pid>[0-9]{1,10})-[a-z0-9_]{8}(?P<suffix>.*)$", re.DOTALL
)
_MAX_MARKER_BYTES = 65536

# --------------------------------------------------------------------------- the write door
#
# Every writer of this module checks its target with check_target first. What it refuses (an
# InputError naming the path; ``problem`` reads after the path, so a command can say "--out: X <problem>"):
# an existing target that is not a regular file (not a folder, for a folder's writer), or is a link;
# a target under /dev, /proc, /sys; inside a Python installation (its prefixes, site-packages, the
# stdlib, the user site), a Python environment (a folder holding pyvenv.cfg or conda-meta above it),
# or the workflow's source tree (the flatlandia package, the checkout's workflow/); with a dot-folder
# in its path (counted below the working folder when inside it; the workflow's own temporaries
# excepted); one of the command's ``reads`` (or an existing file in a folder it reads) or the run's
# ``artifacts``; and, while :func:`write_roots` are set, anything outside them. All compared resolved:
# the target's folder with links and '..' resolved, its own name as given (a link there is refused).

#: the kernel's folders: a write there replaces a device or a file of the system (``/dev/stdout``)
SYSTEM_FOLDERS = (Path("/dev"), Path("/proc"), Path("/sys"))
#: the hidden names the workflow writes itself (its temporaries match _PARTIAL_NAME as well)
OWN_HIDDEN_NAMES = frozenset({PARTIAL_MARKER, ".flatlandia-fetch", ".flatlandia-fetches.json"})
#: what makes a folder a Python environment: a virtualenv's file, a conda environment's folder
ENV_MARKERS = ("pyvenv.cfg", "conda-meta")
#: the folders of the working folder a rule script writes (besides its own outputs' folders)
RUN_FOLDERS = ("results", "resources", "logs")

_ROOTS: tuple[Path, ...] | None = None
_KIND_NAMES = {
    stat.S_IFDIR: "a folder",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFIFO: "a named pipe",
    stat.S_IFSOCK: "a socket",
}


def resolved(path: str | Path) -> Path:
    """Where a write to ``path`` lands: its folder with links and '..' resolved, its own name kept
    (a link of that name is not followed: :func:`check_target` refuses it)."""
    p = Path(path)
    p = p if p.is_absolute() else Path.cwd() / p
    if p.name in ("", ".", ".."):
        return Path(os.path.realpath(p))
    return Path(os.path.realpath(p.parent)) / p.name


@contextlib.contextmanager
def write_roots(*folders: str | Path) -> Iterator[None]:
    """While the block runs, every writer refuses a target outside ``folders`` (resolved): what a
    rule script or a command may write. Nested, the inner set replaces the outer one."""
    global _ROOTS
    before = _ROOTS
    _ROOTS = tuple(Path(os.path.realpath(f)) for f in folders)
    try:
        yield
    finally:
        _ROOTS = before


@functools.cache
def _python_paths() -> tuple[Path, ...]:
    """The folders of this Python: its prefixes, every sysconfig path (stdlib, site-packages,
    scripts), the site-packages and the user site. A file written there can run as code."""
    raw = {sys.prefix, sys.base_prefix, sys.exec_prefix, getattr(sys, "base_exec_prefix", sys.prefix)}
    raw |= set(sysconfig.get_paths().values())
    with contextlib.suppress(AttributeError):
        raw |= set(site.getsitepackages())
    with contextlib.suppress(AttributeError):
        raw.add(site.getusersitepackages())
    return tuple(sorted({Path(os.path.realpath(p)) for p in raw if p}))


@functools.cache
def _source_folders() -> tuple[Path, ...]:
    """The flatlandia package, and the checkout's workflow/ folder holding it (its Snakefile, rules, scripts)."""
    package = Path(__file__).resolve().parents[1]
    return (package, package.parent) if (package.parent / "Snakefile").is_file() else (package,)


def _env_folder(folder: Path, cwd: Path) -> Path | None:
    """The Python environment holding ``folder`` (a folder with pyvenv.cfg or conda-meta), up to
    the first folder that holds the working folder: a run placed inside one is not judged by it."""
    for d in (folder, *folder.parents):
        if cwd.is_relative_to(d):
            return None
        if any(os.path.lexists(d / m) for m in ENV_MARKERS):
            return d
    return None


def _hidden_part(target: Path, cwd: Path) -> str | None:
    """The dot-folder (or hidden file name) in ``target``'s path, counted below the working folder
    when inside it; the workflow's own temporaries and hidden files excepted."""
    parts = target.relative_to(cwd).parts if target.is_relative_to(cwd) else target.parts[1:]
    if not parts:
        return None
    *folders, name = parts
    for f in folders:
        if f.startswith(".") and not _PARTIAL_NAME.match(f):
            return f
    if name.startswith(".") and not (_PARTIAL_NAME.match(name) or name in OWN_HIDDEN_NAMES):
        return name
    return None


def _in_the_way(target: Path) -> str | None:
    """A file where a folder of ``target``'s path should be (the first of its folders that exists)."""
    for d in target.parents:
        try:
            st = os.lstat(d)
        except FileNotFoundError:
            continue
        except OSError as e:
            return f"cannot be written: its folder {d} cannot be examined ({e.strerror or e})"
        if not stat.S_ISDIR(st.st_mode):
            return f"cannot be written: {d} is {_KIND_NAMES.get(stat.S_IFMT(st.st_mode), 'a file')}, not a folder"
        return None
    return None


def _kind_problem(target: Path, kind: str) -> str | None:
    """Why what exists at ``target`` cannot be replaced by a writer of ``kind`` ("file", "dir",
    "any": a regular file or a folder); None for a new name or a replaceable one."""
    try:
        st = os.lstat(target)
    except (FileNotFoundError, NotADirectoryError):
        return _in_the_way(target)
    except OSError as e:
        return f"cannot be examined ({e.strerror or e})"
    mode = stat.S_IFMT(st.st_mode)
    if mode == stat.S_IFLNK:
        return "is a symbolic link: a write would replace the link or write where it points; give a regular file"
    wanted = {"file": (stat.S_IFREG,), "dir": (stat.S_IFDIR,), "any": (stat.S_IFREG, stat.S_IFDIR)}[kind]
    if mode not in wanted:
        what = "a regular file" if kind == "file" else "a folder" if kind == "dir" else "a regular file or a folder"
        return f"is {_KIND_NAMES.get(mode, 'a regular file')}, not {what}: give a new name"
    return None


def _place_problem(target: Path, cwd: Path) -> str | None:
    """Why ``target``'s place is never written: the system's, Python's, the source tree, a dot-folder."""
    for folder in SYSTEM_FOLDERS:
        if target.is_relative_to(folder):
            return f"lies in {folder}: a write there replaces a device or a file of the system"
    for folder in _python_paths():
        if target.is_relative_to(folder) and not cwd.is_relative_to(folder):
            return f"lies inside the Python installation {folder}: a file written there could run as code"
    env = _env_folder(target.parent, cwd)
    if env is not None:
        return f"lies inside the Python environment {env}: a file written there could run as code"
    for folder in _source_folders():
        if target.is_relative_to(folder):
            return f"lies inside the workflow's source tree {folder}: write outputs to the run's folders"
    hidden = _hidden_part(target, cwd)
    if hidden is not None:
        return f"lies in a hidden (dot) folder or has a hidden name ({hidden!r}): the workflow never writes there"
    return None


def _read_problem(target: Path, reads: Iterable) -> str | None:
    """Why ``target`` is one of the files a command reads (or an existing file inside a folder it reads)."""
    for r in reads:
        if r is None or not str(r).strip():
            continue
        real = Path(os.path.realpath(r))
        same = target == real
        if not same and os.path.lexists(target) and os.path.exists(real):
            with contextlib.suppress(OSError):
                same = os.path.samefile(target, real)  # a hard link, a bind mount
        if same:
            return "is an input of this command: write the answer to a new file"
        if os.path.isdir(real) and target.is_relative_to(real) and os.path.lexists(target):
            return f"lies in {r}, a folder this command reads: write the answer to a new file"
    return None


def _artifact_problem(target: Path, artifacts) -> str | None:
    """Why ``target`` is an artifact of the run (``artifacts``: paths, or path -> the rule that made
    it, '' for a file the rules read)."""
    made_by = artifacts if isinstance(artifacts, dict) else dict.fromkeys(artifacts, "")
    for a, rule in made_by.items():
        if a is not None and str(a).strip() and target == Path(os.path.realpath(a)):
            return f"is an artifact of this run{f' (rule {rule})' if rule else ''}: write to a new file"
    return None


def check_target(
    path: str | Path, *, reads: Iterable = (), artifacts=(), kind: str = "file", cwd: str | Path | None = None
) -> Path:
    """The resolved target of a write to ``path`` (:func:`resolved`), or an InputError naming
    ``path`` when the write door refuses it (the comment above lists what; ``kind``: what may be
    replaced, "file", "dir" or "any"; ``cwd``: the working folder, default the current one)."""
    target = resolved(path)
    if kind == "dir" and os.path.islink(target) and os.path.isdir(target):
        target = Path(
            os.path.realpath(target)
        )  # a link to a folder: written into, never replaced; judged where it leads
    cwd = Path(os.path.realpath(cwd if cwd is not None else Path.cwd()))
    why = (
        _place_problem(target, cwd)
        or _kind_problem(target, kind)
        or _artifact_problem(target, artifacts)
        or _read_problem(target, reads)
    )
    if why is None and _ROOTS is not None and not any(target.is_relative_to(r) for r in _ROOTS):
        why = f"lies outside the folders this run writes ({', '.join(map(str, _ROOTS))})"
    if why is not None:
        from flatlandia.plumbing.errors import InputError

        raise InputError(path, why)
    return target


def _file_mode() -> int:
    """Mode of a new file under the process umask (0644 under 0022); temporary files are created
    0600, so they are given this mode before they are renamed into place."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _host_tag(host: str | None = None) -> str:
    return hashlib.sha256((host if host is not None else socket.gethostname()).encode()).hexdigest()[:8]


def _partial_start(path: Path) -> str:
    """How every temporary beside ``path`` is named first (its name cut to 80 bytes: room for the rest)."""
    return f".{path.name.encode()[:80].decode(errors='ignore')}.partial-"


def _partial_prefix(path: Path) -> str:
    """The name start of a temporary beside ``path``: recognisable, with this process and host."""
    return f"{_partial_start(path)}{_host_tag()}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this host (one of another user counts; so does a zombie)."""
    if pid <= 0:
        return True  # never a process of ours: not judged, so kept
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: alive, another user's; anything else: unknown, so kept
        return True
    return True


#: what a write that ran out of room raises (the disk, or the user's quota)
FULL_ERRNOS = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded"}


def disk_full(path: str | Path) -> bool:
    """Whether the filesystem holding ``path`` has no block left to give.

    Some writers do not say when a write ran out of room: COLMAP's ``write_binary`` returns as if
    it had written a whole model, torch's ``save`` raises a bare ``RuntimeError``. Right after such a
    write, before its temporary is removed, a full filesystem is the sign. One that reports no
    size (some network and virtual filesystems) is never judged full."""
    try:
        st = os.statvfs(path)
    except OSError:
        return False
    return st.f_blocks > 0 and st.f_bavail == 0


def full_disk_error(exc: BaseException | None) -> OSError | None:
    """The out-of-room :class:`OSError` (see :data:`FULL_ERRNOS`) in ``exc`` or the errors it came
    from, else None."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in FULL_ERRNOS:
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


@contextlib.contextmanager
def _name_full_disk(path: Path, tmp: Path) -> Iterator[None]:
    """A write to ``tmp`` (beside ``path``, for it) that fails for want of room raises an :class:`OSError`
    ENOSPC/EDQUOT naming ``path`` (the error's own ``filename`` is often missing or a temporary),
    also when the writer's error does not say so but the disk is full at that moment."""
    try:
        yield
    except Exception as e:
        full = full_disk_error(e)
        if full is not None and full.filename and not any(_PARTIAL_NAME.match(n) for n in Path(full.filename).parts):
            raise  # already names its file (an inner writer's)
        if full is not None or disk_full(tmp.parent):
            code = full.errno if full is not None else errno.ENOSPC
            raise OSError(code, os.strerror(code), str(path)) from e
        raise


def _refuse_if_full(path: Path, tmp: Path) -> None:
    """Before a temporary becomes ``path``: a full disk means its writer may have been cut short
    without saying so (COLMAP), so it never gets the final name."""
    if disk_full(tmp.parent):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


@contextlib.contextmanager
def partial_dir(path: str | Path, *, reads: Iterable = (), artifacts=()) -> Iterator[Path]:
    """Yield a new, empty-but-for-its-marker temporary folder beside ``path`` (resolved, checked by
    :func:`check_target`: a file or a folder may be there, for the caller to replace); removed on
    exit, whatever happens. Killed before that, it is a stale partial for :func:`clean_stale_partials`."""
    given, path = Path(path), check_target(path, reads=reads, artifacts=artifacts, kind="any")
    path.parent.mkdir(parents=True, exist_ok=True)
    with _name_full_disk(given, path):
        tmp = Path(tempfile.mkdtemp(prefix=_partial_prefix(path), dir=path.parent))
    try:
        with _name_full_disk(given, tmp):
            marker = {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "created": datetime.now(UTC).isoformat(timespec="seconds"),
                "for": str(path),
            }
            (tmp / PARTIAL_MARKER).write_text(json.dumps(marker) + "\n")
            yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None, *, reads: Iterable = (), artifacts=()) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (resolved and checked: :func:`check_target`; ending in
    ``suffix``, by default the suffix of ``path``: some writers infer the format from it); rename it
    onto ``path`` only on success (with the mode the umask gives new files)."""
    given, path = Path(path), check_target(path, reads=reads, artifacts=artifacts)  # errors name the path given
    path.parent.mkdir(parents=True, exist_ok=True)
    with _name_full_disk(given, path):
        fd, tmp = tempfile.mkstemp(prefix=_partial_prefix(path), suffix=suffix or path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        with _name_full_disk(given, tmp):
            yield tmp
            _refuse_if_full(given, tmp)
        if tmp.exists():
            tmp.chmod(_file_mode())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | Path, *, reads: Iterable = (), artifacts=()) -> Iterator[Path]:
    """Yield an empty temporary folder (inside a :func:`partial_dir` beside ``path``, resolved and
    checked: :func:`check_target`, an existing folder may be replaced); it replaces ``path`` only on success.

    For rules whose output is a folder (``directory()``): a crash never leaves a half-filled one,
    and a killed run's temporary is removed at the next run's start.
    """
    given, path = Path(path), check_target(path, reads=reads, artifacts=artifacts, kind="dir")
    with partial_dir(given) as work:
        tmp = work / "output"
        tmp.mkdir()
        with _name_full_disk(given, tmp):
            yield tmp
            _refuse_if_full(given, tmp)
        if os.path.lexists(path):  # the older output goes into our temporary folder, removed with it
            os.rename(path, work / "replaced")
        tmp.rename(path)


@contextlib.contextmanager
def staged(
    folder: str | Path, names: Iterable[str], *, reads: Iterable = (), artifacts=()
) -> Iterator[dict[str, Path]]:
    """Yield a temporary path for each file ``names`` (relative, below ``folder``), all inside one
    :func:`partial_dir` beside ``folder``; they are moved into place together once the block ends
    without error (a new ``folder`` in one rename), else nothing in ``folder`` changes.

    For outputs that belong together (``flatlandia score``'s run folders and scores.md): a failed
    write never leaves new files beside stale ones. A move that fails puts back what was there.
    Files of ``folder`` not named are kept; every target is checked (:func:`check_target`) first."""
    from flatlandia.plumbing.errors import InputError

    given, top = Path(folder), check_target(folder, reads=reads, artifacts=artifacts, kind="dir")
    targets = {}
    for name in dict.fromkeys(names):
        rel = Path(name)
        if rel.is_absolute() or not rel.parts or any(p in ("", ".", "..") for p in rel.parts):
            raise InputError(top / name, "not a plain relative name below its folder")
        for i in range(1, len(rel.parts)):  # the folders on the way: new, or real folders
            check_target(top.joinpath(*rel.parts[:i]), reads=reads, artifacts=artifacts, kind="dir")
        targets[name] = check_target(top / rel, reads=reads, artifacts=artifacts)
        if not targets[name].is_relative_to(top):  # a folder on the way links elsewhere
            raise InputError(top / name, f"lies outside {top} (through a link): not a file of this set")
    with partial_dir(top, reads=reads, artifacts=artifacts) as work:
        tree = work / "tree"
        tmp = {name: tree / name for name in targets}
        for p in tmp.values():
            p.parent.mkdir(parents=True, exist_ok=True)
        with _name_full_disk(given, tree):
            yield tmp
        _refuse_if_full(given, tree)
        missing = [n for n, p in tmp.items() if not p.is_file()]
        if missing:
            raise InputError(top / missing[0], "was not written: nothing of the set was moved into place")
        if not os.path.lexists(top):
            tree.rename(top)
            return
        _move_in(tmp, targets, top, work / "replaced")


def _move_in(tmp: dict[str, Path], targets: dict[str, Path], top: Path, aside: Path) -> None:
    """Rename each staged file onto its target (the older file moved ``aside`` first); on a failure,
    every move made is undone in reverse order and the error raised."""
    aside.mkdir()
    done: list[tuple[Path, Path | None, list[Path]]] = []  # (target, its older file, folders made)
    try:
        for i, (name, target) in enumerate(targets.items()):
            made = [top / d for d in reversed(target.relative_to(top).parents) if not os.path.lexists(top / d)]
            done.append((target, None, made))
            for d in made:
                d.mkdir()
            if os.path.lexists(target):
                os.rename(target, aside / str(i))
                done[-1] = (target, aside / str(i), made)
            os.rename(tmp[name], target)
    except OSError:
        for n, (target, older, made) in enumerate(reversed(done)):
            with contextlib.suppress(OSError):
                if older is not None:
                    os.replace(older, target)
                elif n > 0 and os.path.lexists(target):  # moved in (the last one failed before it was)
                    os.unlink(target)
            for d in reversed(made):
                with contextlib.suppress(OSError):
                    os.rmdir(d)
        raise


def _stale(entry: Path, host_tag: str, log) -> bool:
    """Whether ``entry`` is a temporary of the workflow whose process is gone (False when in doubt)."""
    m = _PARTIAL_NAME.match(entry.name)
    if m is None or m["host"] != host_tag:
        return False  # not ours, or another host's: its process cannot be checked from here
    pid = int(m["pid"])
    try:
        st = entry.lstat()
    except OSError:
        return False
    if stat.S_ISREG(st.st_mode):
        return not _alive(pid)
    if not stat.S_ISDIR(st.st_mode) or m["suffix"]:
        return False  # a link, a device, a folder named like a temporary file: never ours
    marker = entry / PARTIAL_MARKER
    try:
        if not stat.S_ISREG(marker.lstat().st_mode) or marker.stat().st_size > _MAX_MARKER_BYTES:
            return False
        info = json.loads(marker.read_text())
    except FileNotFoundError:
        # killed between creating the folder and writing its marker: only an empty folder is ours
        try:
            return not any(entry.iterdir()) and not _alive(pid)
        except OSError:
            return False
    except (OSError, ValueError) as e:
        log(f"kept {entry}: unreadable {PARTIAL_MARKER} ({e})")
        return False
    if not isinstance(info, dict) or info.get("pid") != pid or _host_tag(str(info.get("host"))) != host_tag:
        return False
    return not _alive(pid)


def _remove(entry: Path) -> None:
    if entry.is_dir() and not entry.is_symlink():
        shutil.rmtree(entry)
    else:
        entry.unlink()


def clean_stale_partials(folders: Iterable[str | Path] = (), beside: Iterable[str | Path] = (), log=None) -> list[Path]:
    """Remove the temporaries of interrupted runs: those named and marked as the workflow's (see
    :func:`partial_dir`, :func:`atomic_path`) whose creating process no longer runs on this host.

    ``folders`` are searched at every depth (links not followed); for each path of ``beside`` (e.g.
    ``fetch.dest``) only its own temporaries, in its parent folder. A temporary of a live process
    (a concurrent run), of another host, or anything not named and marked so is never touched.
    Returns the removed paths; ``log`` (a callable taking a line) hears of each.
    """
    log = log or (lambda line: None)
    host_tag = _host_tag()
    found: list[Path] = []
    for folder in map(Path, folders):
        if not folder.is_dir():
            continue
        for dirpath, dirnames, filenames in os.walk(folder):
            for name in filenames + dirnames:
                if _PARTIAL_NAME.match(name):
                    found.append(Path(dirpath, name))
            dirnames[:] = [d for d in dirnames if not _PARTIAL_NAME.match(d)]  # never inside a temporary
    for path in map(Path, beside):
        parent, start = path.parent, _partial_start(path)
        if parent.is_dir():
            found += [parent / n for n in os.listdir(parent) if n.startswith(start)]
    removed: list[Path] = []
    for entry in dict.fromkeys(found):
        if not _stale(entry, host_tag, log):
            continue
        try:
            _remove(entry)
        except OSError as e:
            log(f"could not remove {entry}, the leftover of an interrupted run: {e}")
            continue
        log(f"removed {entry}, the leftover of an interrupted run")
        removed.append(entry)
    return removed


def write_parquet(
    df: pd.DataFrame, path: str | Path, metadata: dict[str, Any] | None = None, *, reads: Iterable = (), artifacts=()
) -> None:
    """Write a DataFrame as Parquet atomically; ``metadata`` is stored as JSON in the schema."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(df, preserve_index=False)
    if metadata:
        meta = dict(table.schema.metadata or {})
        meta[b"flatlandia"] = json.dumps(metadata, sort_keys=True).encode()
        table = table.replace_schema_metadata(meta)
    with atomic_path(path, reads=reads, artifacts=artifacts) as tmp:
        pq.write_table(table, tmp)


def read_parquet_metadata(path: str | Path) -> dict[str, Any]:
    """The ``flatlandia`` JSON metadata stored by :func:`write_parquet` (empty if none)."""
    import pyarrow.parquet as pq

    from flatlandia.plumbing import validate

    meta = pq.read_schema(path).metadata or {}
    raw = meta.get(b"flatlandia")
    return validate.parse_json(raw, path) if raw else {}


def write_json(obj: Any, path: str | Path, *, reads: Iterable = (), artifacts=()) -> None:
    """JSON (NaN and inf refused: not JSON), written atomically through the write door."""
    text = json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n"  # a bad value before any file
    with atomic_path(path, reads=reads, artifacts=artifacts) as tmp:
        tmp.write_text(text)


def write_text(text: str, path: str | Path, *, reads: Iterable = (), artifacts=()) -> None:
    """Text, written atomically through the write door."""
    with atomic_path(path, reads=reads, artifacts=artifacts) as tmp:
        tmp.write_text(text)


def read_json(path: str | Path, max_bytes: int | None = None) -> Any:
    """A JSON file, checked at the door (:func:`flatlandia.plumbing.validate.read_json`: a regular file of at
    most ``max_bytes``, default :data:`~flatlandia.plumbing.validate.MAX_JSON_BYTES`, nested at most
    :data:`~flatlandia.plumbing.validate.MAX_JSON_DEPTH` deep; long integers read as floats)."""
    from flatlandia.plumbing import validate

    if max_bytes is None:
        return validate.read_json(path)
    return validate.read_json(path, max_bytes, "")


def sha256(path: str | Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def json_safe(d: dict) -> dict:
    """Non-finite floats as None (JSON has no inf/NaN)."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}
