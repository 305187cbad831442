"""Atomic writers for our artifacts, and the temporaries a killed run leaves behind.

Every writer goes through a temporary file in the same folder and an atomic rename, so a
crash never leaves a half-written output behind; nor does a full disk, even under a writer that
does not report it (see :func:`disk_full`). A run killed mid-write leaves a temporary that the
next run's start removes (:func:`clean_stale_partials`). The readers of the published files are
:mod:`flatlandia.data.published`.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import shutil
import socket
import stat
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
def partial_dir(path: str | Path) -> Iterator[Path]:
    """Yield a new, empty-but-for-its-marker temporary folder beside ``path``; removed on exit,
    whatever happens. Killed before that, it is a stale partial for :func:`clean_stale_partials`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with _name_full_disk(path, path):
        tmp = Path(tempfile.mkdtemp(prefix=_partial_prefix(path), dir=path.parent))
    try:
        with _name_full_disk(path, tmp):
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
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (ending in ``suffix``, by default the suffix of
    ``path``: some writers infer the format from it); rename it onto ``path`` only on success (with
    the mode the umask gives new files)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with _name_full_disk(path, path):
        fd, tmp = tempfile.mkstemp(prefix=_partial_prefix(path), suffix=suffix or path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        with _name_full_disk(path, tmp):
            yield tmp
            _refuse_if_full(path, tmp)
        if tmp.exists():
            tmp.chmod(_file_mode())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield an empty temporary folder (inside a :func:`partial_dir` beside ``path``); it replaces
    ``path`` only on success.

    For rules whose output is a folder (``directory()``): a crash never leaves a half-filled one,
    and a killed run's temporary is removed at the next run's start.
    """
    path = Path(path)
    with partial_dir(path) as work:
        tmp = work / "output"
        tmp.mkdir()
        with _name_full_disk(path, tmp):
            yield tmp
            _refuse_if_full(path, tmp)
        if os.path.lexists(path):  # the older output goes into our temporary folder, removed with it
            os.rename(path, work / "replaced")
        tmp.rename(path)


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


def write_parquet(df: pd.DataFrame, path: str | Path, metadata: dict[str, Any] | None = None) -> None:
    """Write a DataFrame as Parquet atomically; ``metadata`` is stored as JSON in the schema."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(df, preserve_index=False)
    if metadata:
        meta = dict(table.schema.metadata or {})
        meta[b"flatlandia"] = json.dumps(metadata, sort_keys=True).encode()
        table = table.replace_schema_metadata(meta)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)


def read_parquet_metadata(path: str | Path) -> dict[str, Any]:
    """The ``flatlandia`` JSON metadata stored by :func:`write_parquet` (empty if none)."""
    import pyarrow.parquet as pq

    from flatlandia.plumbing import validate

    meta = pq.read_schema(path).metadata or {}
    raw = meta.get(b"flatlandia")
    return validate.parse_json(raw, path) if raw else {}


def write_json(obj: Any, path: str | Path) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n")


def write_text(text: str, path: str | Path) -> None:
    with atomic_path(path) as tmp:
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
