"""Fetch the published Flatlandia data, and images scenes' folders, from their public source when
no local copy exists.

The archives are untrusted: the scene sheet and the config name them. So a fetch
- follows https:// only (file:// for a local archive), redirects included;
- streams the download to a temporary file and stops past ``fetch.max_download_mb``;
- checks the download against a pinned sha256 (the sheet's ``sha256`` column, ``fetch.sha256``)
  before unpacking anything;
- unpacks regular files only, each to a destination resolved inside the temporary folder:
  absolute names, ``..`` components, symlinks, devices, more members than ``fetch.max_members``
  and more bytes than ``fetch.max_unpacked_mb`` are refused, naming the archive and the member;
- writes nothing outside the destination: all happens in one temporary folder beside it, renamed
  into place once complete and removed on any failure;
- never deletes what it did not write, and never writes where code runs from: the destination lies
  below the working folder's ``resources/``, or is exactly the folder the config declares as the data
  folder (``flatlandia_root``) while that folder does not exist; never in a dot-folder, a Python
  installation or environment, the source tree, ``/dev``... (:func:`check_dest`, the write door of
  :mod:`flatlandia.plumbing.files`); an existing one is replaced only when the run's own record
  (FETCH_STATE, in the working folder) says a fetch of this run wrote it and its files are
  unchanged since; a marker file inside a folder proves nothing. Otherwise the fetch is refused.
- writes its files without exec bits (mode 0666 less the umask), whatever the archive says.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import stat
import urllib.error
import urllib.parse
import urllib.request
import zipfile
import zlib
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from flatlandia import config
from flatlandia.classes import CLASSES
from flatlandia.plumbing import escape, files

#: Defaults: the `fetch` section of workflow/schemas/config.schema.yaml.
_FETCH = config.section_defaults("fetch")
#: the published data's archive (the default of `fetch.url`)
UPSTREAM_ZIP = _FETCH["url"]

HOW_TO_POINT = (
    "Point the workflow at a local copy of the Flatlandia data instead: set "
    "`flatlandia_root` in config/config.yaml, pass `--config flatlandia_root=/path/to/data`, "
    "or export FLATLANDIA_ROOT=/path/to/data (a folder holding individual_reference_maps/, "
    "maps/ and local_maps.json)."
)

#: The only sources fetched: https (integrity in transit) and local archives (file://).
SCHEMES = ("https", "file")
MB = 1_000_000
CHUNK = 1 << 20

_LOG = logging.getLogger("flatlandia.fetch")  # into the rule's log (flatlandia.plumbing.rule_log)


class FetchError(RuntimeError):
    pass


class DownloadError(FetchError):
    """The source could not be read (offline, not found): the user can point at a local copy."""


@config.settings("fetch", frozen=True)
class Limits:
    """The config section ``fetch`` (each key is described in config/README.md, ``fetch.*``): the
    downloads and unpacking read its caps (``max_download_mb``, ``max_unpacked_mb``,
    ``max_members``), so a hostile or broken archive cannot fill disk or memory."""

    @classmethod
    def from_config(cls, fetch_cfg: dict | None) -> Limits:
        """The settings of a config's ``fetch`` section, or of part of it (strict: :meth:`from_dict`)."""
        return cls.from_dict(fetch_cfg)


# ----------------------------------------------------------------------------- download


def check_url(url: str) -> None:
    """Refuse every source but https:// and file://: http:// can be altered in transit, and
    urllib would also follow ftp:// and data: addresses."""
    scheme = urllib.parse.urlsplit(url).scheme.lower()
    if scheme not in SCHEMES:
        raise FetchError(
            f"{url}: refused: only https:// sources (or file:// for a local archive) are fetched, "
            f"not {scheme + '://' if scheme else 'a bare path'}"
        )


class _HttpsRedirectsOnly(urllib.request.HTTPRedirectHandler):
    """Follow a redirect only to another https:// address: never down to http:// or elsewhere."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        if urllib.parse.urlsplit(newurl).scheme.lower() != "https":
            raise FetchError(f"{req.full_url}: refused a redirect to {newurl} (only https:// is followed)")
        return super().redirect_request(req, fp, code, msg, headers, newurl)


_OPENER = urllib.request.build_opener(_HttpsRedirectsOnly)


def _too_big(url: str, n_bytes: int, max_bytes: int) -> str:
    return (
        f"{url}: the download exceeds fetch.max_download_mb ({max_bytes / MB:g} MB): "
        f"{n_bytes} bytes or more; nothing was unpacked"
    )


def download(url: str, to: Path, timeout_s: float, max_bytes: int) -> str:
    """Stream ``url`` into the file ``to`` (at most ``max_bytes``, never all in memory); its sha256."""
    check_url(url)
    _check_local_source(url)
    digest, n = hashlib.sha256(), 0
    try:
        with _OPENER.open(url, timeout=timeout_s) as resp, open(to, "wb") as out:
            declared = resp.headers.get("Content-Length", "")
            if declared.isdigit() and int(declared) > max_bytes:
                raise FetchError(_too_big(url, int(declared), max_bytes))
            while chunk := resp.read(CHUNK):
                n += len(chunk)
                if n > max_bytes:
                    raise FetchError(_too_big(url, n, max_bytes))
                digest.update(chunk)
                out.write(chunk)
    except (urllib.error.URLError, TimeoutError, OSError) as e:
        raise DownloadError(f"could not download {url}: {e}") from e
    return digest.hexdigest()


def _check_local_source(url: str) -> None:
    """A file:// source must be a regular file, checked before it is opened: a named pipe would
    block the fetch for ever, a device never end."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme.lower() != "file":
        return
    path = urllib.request.url2pathname(parts.path)
    try:
        st = os.stat(path)
    except OSError as e:
        raise DownloadError(f"could not download {url}: {e.strerror or e}") from None
    if not stat.S_ISREG(st.st_mode):
        raise FetchError(f"{url}: refused: not a regular file (a folder, a named pipe or a device); nothing was read")


def check_sha256(url: str, got: str, expected: str | None) -> None:
    """Stop before unpacking when a pinned checksum differs: the archive is not the one pinned."""
    expected = (expected or "").strip().lower()
    if expected and got.lower() != expected:
        raise FetchError(
            f"{url}: sha256 mismatch: the download is {got}, the pinned value is {expected}; nothing was unpacked"
        )


def _known_size(url: str, max_download_mb: float) -> str:
    """How big a download is, in words: a local archive's size (file://); an https:// one's is
    known only once it starts, so its cap is named instead."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme.lower() == "file":
        try:
            return f"{os.stat(urllib.request.url2pathname(parts.path)).st_size / MB:,.1f} MB"
        except OSError:
            return "a local archive not found"
    return f"size unknown until it starts, at most {max_download_mb:g} MB (fetch.max_download_mb)"


def download_note(what: str, rule: str, url: str, dest: str, why: str, max_download_mb: float) -> str:
    """The one line a plan that downloads prints before any job: what (and the rule), from where,
    into where, how big when known, and why the local copy was not used. Why: a dry run must not
    plan a download silently (a project whose relative data folder does not resolve there)."""
    return escape.terminal(
        f"this plan downloads {what} (rule {rule}): {url} into {dest}, {_known_size(url, max_download_mb)}; {why}"
    )


# ----------------------------------------------------------------------------- unpacking


def _subfolder_parts(subfolder: str, url: str) -> list[str]:
    """The components of the archive folder to unpack (below the top folder); no '..' or '.'."""
    parts = [p for p in (subfolder or "").strip("/").split("/") if p]
    if "\\" in (subfolder or "") or any(p in (".", "..") for p in parts):
        raise FetchError(f"{url}: subfolder {subfolder!r} must be a plain relative folder (no '..', no '.')")
    return parts


def _below(name: str, sub: list[str]) -> str | None:
    """The part of a member name below ``<top>/<subfolder>/``; None for a member elsewhere."""
    parts = name.split("/")
    if len(parts) < len(sub) + 2 or parts[1 : len(sub) + 1] != sub:
        return None
    return "/".join(parts[len(sub) + 1 :])


def _name_problem(rest: str) -> str | None:
    """Why a member's path below the subfolder cannot be unpacked safely (None: it can)."""
    if rest.startswith("/"):
        return "absolute path"
    parts = rest.split("/")
    if ".." in parts:
        return "'..' component (it would land outside the destination)"
    if "\\" in rest or any(ord(c) < 32 for c in rest):
        return "backslash or control character in the name"
    if any(p in ("", ".") for p in parts):
        return "empty or '.' path component"
    return None


_KINDS = {
    stat.S_IFLNK: "a symbolic link",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFIFO: "a named pipe",
    stat.S_IFSOCK: "a socket",
    stat.S_IFDIR: "a directory stored as a file",
}


def _type_problem(info: zipfile.ZipInfo) -> str | None:
    """Why a member is not a plain file: only regular files are unpacked (no links, no devices)."""
    kind = stat.S_IFMT(info.external_attr >> 16)
    if kind not in (0, stat.S_IFREG):
        return f"{_KINDS.get(kind, 'not a regular file')}: only regular files are unpacked"
    if info.flag_bits & 0x1:
        return "encrypted member"
    return None


def _refused(url: str, member: str, why: str) -> FetchError:
    return FetchError(f"{url}: refused archive member {member!r}: {why}; nothing was unpacked")


def _inside(root: Path, rest: str, url: str, member: str) -> Path:
    """The resolved destination of a member; refused unless strictly inside ``root``."""
    real_root = root.resolve()
    target = (real_root / rest).resolve()
    if target == real_root or not target.is_relative_to(real_root):
        raise _refused(url, member, f"it resolves to {target}, outside the destination")
    return target


def _plan(
    z: zipfile.ZipFile, sub: list[str], root: Path, url: str, limits: Limits
) -> list[tuple[zipfile.ZipInfo, Path]]:
    """The (member, resolved destination) pairs to unpack: every member checked (name, type, size,
    destination) before anything is written."""
    infos = z.infolist()
    if len(infos) > limits.max_members:
        raise FetchError(
            f"{url}: the archive holds {len(infos)} members, over fetch.max_members ({limits.max_members}); "
            "nothing was unpacked"
        )
    cap = int(limits.max_unpacked_mb * MB)
    plan, total = [], 0
    for info in infos:
        rest = _below(info.filename, sub)
        if rest is None or info.is_dir():
            continue
        why = _name_problem(rest) or _type_problem(info)
        if why is None and info.file_size > cap:
            why = f"it unpacks to {info.file_size} bytes, over fetch.max_unpacked_mb ({limits.max_unpacked_mb:g} MB)"
        if why:
            raise _refused(url, info.filename, why)
        total += info.file_size
        plan.append((info, _inside(root, rest, url, info.filename)))
    if not plan:
        raise FetchError(f"{url}: archive holds no {'/'.join(sub)}/ folder")
    if total > cap:
        raise FetchError(
            f"{url}: the files under {'/'.join(sub)}/ unpack to {total} bytes, over fetch.max_unpacked_mb "
            f"({limits.max_unpacked_mb:g} MB); nothing was unpacked"
        )
    return plan


def _copy(z: zipfile.ZipFile, info: zipfile.ZipInfo, target: Path, budget: int, url: str) -> int:
    """Copy one member to ``target``, counting the bytes really written against ``budget``."""
    n = 0
    fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o666)  # no exec bit, never a link
    with z.open(info) as src, open(fd, "wb") as out:
        while chunk := src.read(CHUNK):
            n += len(chunk)
            if n > budget:
                raise FetchError(
                    f"{url}: archive member {info.filename!r} unpacks past fetch.max_unpacked_mb; "
                    "the partial unpacking was removed"
                )
            out.write(chunk)
    return n


def unpack_subfolder(archive: Path, subfolder: str, root: Path, url: str, limits: Limits | None = None) -> Path:
    """Unpack the regular files under ``<top>/<subfolder>/`` of the zip ``archive`` into the folder
    ``root`` (the caller's temporary folder); nothing is written before every member is checked."""
    limits = limits or Limits()
    sub = _subfolder_parts(subfolder, url)
    root.mkdir(parents=True, exist_ok=True)
    budget = int(limits.max_unpacked_mb * MB)
    try:
        z = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError) as e:
        raise FetchError(f"{url}: not a readable zip archive ({e}); nothing was unpacked") from e
    with z:
        try:
            for info, target in _plan(z, sub, root, url, limits):
                target.parent.mkdir(parents=True, exist_ok=True)
                budget -= _copy(z, info, target, budget, url)
        except FetchError:
            raise
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError, OSError) as e:
            raise FetchError(f"{url}: could not unpack the archive ({e}); the partial unpacking was removed") from e
    return root


# ----------------------------------------------------------------------------- destination

#: The file a fetch writes into the folder it unpacks (JSON: url, subfolder, sha256, time): what the
#: folder holds, for people and the tests; it proves nothing (anyone can write one), so it is not
#: what allows a later fetch to replace the folder: the run's own record is (FETCH_STATE).
FETCH_MARKER = ".flatlandia-fetch"
#: The run's record of the folders its fetches wrote, in its working folder (JSON: resolved
#: destination -> the folder's identity and a fingerprint of its files): only a folder recorded
#: here, and unchanged since, is ever replaced by a later fetch.
FETCH_STATE = Path("resources") / ".flatlandia-fetches.json"
#: Folders of the working folder that the workflow writes itself: never a fetch's destination.
WORKFLOW_FOLDERS = (".snakemake", "config", "logs", "resources", "results", "workflow")
_MAX_STATE_BYTES = 16 * MB


def check_dest(
    dest: str | Path, cwd: str | Path | None = None, setting: str = "fetch.dest", data_folder: str | Path | None = None
) -> Path:
    """The resolved destination of a fetch, refused (FetchError) when replacing it could delete
    what a fetch did not write or the files could run as code: '.', '..', a name ending in them,
    the working folder ``cwd``, any of its parents, the filesystem root, the home folder or its
    parents, a folder of the workflow's own (results, resources, ...), a place the write door never
    writes (a dot-folder, a Python installation or environment, the source tree, /dev: :mod:`flatlandia.plumbing.files`),
    and anything but a folder below ``cwd``'s ``resources/`` or, while it does not exist, the folder
    the config declares as the data folder (``data_folder``: ``flatlandia_root``). Called at parse
    time and again before any download."""
    raw = str(dest)
    cwd = Path(cwd if cwd is not None else os.getcwd()).resolve()
    try:
        target = (cwd / raw).resolve() if raw.strip() else cwd
        declared = (cwd / Path(data_folder)).resolve() if data_folder is not None else None
        own = (cwd / "resources").resolve()
    except (OSError, RuntimeError) as e:  # a loop of links
        raise FetchError(f"{setting} {raw!r} is refused: it cannot be resolved ({e}); nothing was downloaded") from e
    why = _dest_problem(raw, target, cwd) or _place_problem(target, cwd)
    if why is None and not (target.is_relative_to(own) and target != own):
        if target != declared:
            why = (
                f"it lies outside the working folder's resources/ ({own}); a fetch writes there, or into the "
                "folder the config declares as the data folder while it does not exist (set flatlandia_root to "
                "the same folder)"
            )
        elif os.path.lexists(target):
            why = "the declared data folder (flatlandia_root) already exists: a fetch only creates it"
    if why:
        raise FetchError(
            f"{setting} {raw!r} ({target}) is refused: {why}. A fetch replaces its destination, so "
            f"{setting} must name a folder of its own (e.g. resources/flatlandia); nothing was downloaded"
        )
    return target


def _dest_problem(raw: str, target: Path, cwd: Path) -> str | None:
    """Why a fetch must never replace ``target``: it holds the working folder, the home folder, the
    workflow's own output folders, or the name ends in no folder of its own."""
    try:
        home = Path.home().resolve()
    except (OSError, RuntimeError, KeyError):  # no home folder known: nothing to compare with
        home = cwd
    if target == Path(target.anchor):
        return "the filesystem root"
    if target == cwd:
        return "the working folder"
    if target in cwd.parents:
        return f"a parent of the working folder {cwd}"
    if target == home or target in home.parents:
        return "the home folder" if target == home else "a parent of the home folder"
    if target.parent == cwd and target.name in WORKFLOW_FOLDERS:
        return "a folder the workflow writes itself"
    if not raw.strip() or Path(raw).name in ("", ".", ".."):
        return "it does not end in a folder name of its own (it is empty or ends in '.' or '..')"
    return None


def _place_problem(target: Path, cwd: Path) -> str | None:
    """The write door's refusal of ``target`` (a dot-folder, Python's folders, the source tree,
    /dev, a file in the way), judged from the working folder ``cwd``."""
    from flatlandia.plumbing.errors import InputError

    try:
        files.check_target(target, kind="any", cwd=cwd)
    except InputError as e:
        return f"it {e.problem}"
    return None


def _fingerprint(dest: Path) -> dict:
    """What identifies a fetched folder: its device and inode, and a digest of every entry below it
    (relative name, kind, size, modification time). Any file added, removed or edited changes it."""
    st = os.lstat(dest)
    h = hashlib.sha256()
    for dirpath, dirnames, filenames in os.walk(dest):
        dirnames.sort()
        for name in sorted(dirnames + filenames):
            p = Path(dirpath, name)
            e = os.lstat(p)
            h.update(f"{p.relative_to(dest)}\0{stat.S_IFMT(e.st_mode)}\0{e.st_size}\0{e.st_mtime_ns}\n".encode())
    return {"device": st.st_dev, "inode": st.st_ino, "files": h.hexdigest()}


def _state_path(workdir: Path) -> Path:
    return workdir / FETCH_STATE


def _read_state(workdir: Path) -> dict:
    """The run's fetch record (empty when there is none, or it is not one: then nothing is replaced)."""
    from flatlandia.plumbing import validate
    from flatlandia.plumbing.errors import InputError

    path = _state_path(workdir)
    if not os.path.lexists(path):
        return {}
    try:
        state = validate.read_json(path, _MAX_STATE_BYTES)
    except InputError as e:
        _LOG.warning("ignoring the fetch record %s: %s", path, e)
        return {}
    if not isinstance(state, dict):
        _LOG.warning("ignoring the fetch record %s: not a JSON object but %s", path, type(state).__name__)
        return {}
    kept = {}
    for dest, rec in state.items():
        why = _entry_problem(rec)
        if why:  # unknown: its folder is never replaced, and the entry is not written back
            _LOG.warning("ignoring the entry %r of the fetch record %s: %s", validate.shown(dest), path, why)
        else:
            kept[dest] = rec
    return kept


#: each entry of FETCH_STATE: its fields and their types (what _fingerprint and _record_fetch write)
_ENTRY_FIELDS = {"device": int, "inode": int, "files": str, "url": str, "subfolder": str, "sha256": str, "time": str}


def _entry_problem(rec) -> str | None:
    """Why an entry of the fetch record is not one a fetch wrote (None: it is): a field missing or
    of another type (NaN where an inode should be, a list, a string)."""
    if not isinstance(rec, dict):
        return f"not a JSON object but {type(rec).__name__}"
    for key, kind in _ENTRY_FIELDS.items():
        value = rec.get(key)
        if type(value) is not kind or (kind is int and value < 0):
            return f"'{key}' is missing or not {'a whole number' if kind is int else 'text'}"
    return None


class _StateLock:
    """An exclusive lock on the fetch record while it is read and rewritten (two fetches of one run,
    the data and a photo folder, may finish at once)."""

    def __init__(self, workdir: Path):
        self.folder = _state_path(workdir).parent  # the lock is on the record's folder: no lock file left

    def __enter__(self):
        import fcntl

        self.folder.mkdir(parents=True, exist_ok=True)
        self.fd = os.open(self.folder, os.O_RDONLY)
        fcntl.flock(self.fd, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        import fcntl

        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)


def _record_fetch(dest: Path, workdir: Path, url: str, subfolder: str, got: str) -> None:
    """Add ``dest`` (resolved) to the run's fetch record with its fingerprint: this run wrote it."""
    with _StateLock(workdir):
        state = _read_state(workdir)
        state[str(dest.resolve())] = {
            **_fingerprint(dest),
            "url": url,
            "subfolder": subfolder,
            "sha256": got,
            "time": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        files.write_json(state, _state_path(workdir))


def fetched_before(dest: str | Path, workdir: str | Path | None = None) -> bool:
    """Whether ``dest`` is a folder this run's fetch wrote (recorded in the working folder
    ``workdir``'s FETCH_STATE) and nothing in it changed since: the only folder a fetch replaces."""
    workdir = Path(workdir if workdir is not None else os.getcwd()).resolve()
    dest = (workdir / Path(dest)).absolute()
    try:
        if dest.is_symlink() or not dest.is_dir():
            return False
        rec = _read_state(workdir).get(str(dest.resolve()))
        if not isinstance(rec, dict):
            return False
        now = _fingerprint(dest)
    except OSError:
        return False
    return all(rec.get(k) == v for k, v in now.items())


def _check_replaceable(
    dest: Path, hint: str, setting: str, workdir: Path, done: str = "nothing was downloaded or removed"
) -> None:
    """Refuse an existing ``dest`` that this run's fetch did not write, or that changed since: a
    fetch never deletes a folder or a file it did not create."""
    if not os.path.lexists(dest) or fetched_before(dest, workdir):
        return
    kind = "a folder not written by a fetch of this run" if dest.is_dir() else "not a folder"
    if dest.is_dir() and not dest.is_symlink() and str(dest.resolve()) in _read_state(workdir):
        kind = "a folder a fetch wrote but whose files changed since (added, removed or edited)"
    if dest.is_symlink():
        kind = "a symbolic link"
    raise FetchError(
        f"{setting} {str(dest)!r} ({dest.absolute()}) already exists and is {kind} (the run's record of its "
        f"fetches, {_state_path(workdir)}, is what allows a replacement, not a {FETCH_MARKER} file): a fetch "
        f"never replaces what it did not write, so {done}. {hint}"
    )


def _into_place(unpacked: Path, dest: Path, work: Path, hint: str, setting: str, workdir: Path) -> None:
    """Rename the complete ``unpacked`` folder onto ``dest``; an older fetched copy is first moved
    into the temporary folder ``work`` (removed with it), anything else at ``dest`` is refused."""
    # again: something may have appeared there during the download
    _check_replaceable(dest, hint, setting, workdir, "the download was discarded and nothing was removed")
    if not os.path.lexists(dest):
        unpacked.rename(dest)
        return
    older = work / "replaced"
    dest.rename(older)
    try:
        unpacked.rename(dest)
    except OSError:
        older.rename(dest)
        raise


def fetch_archive(
    url: str,
    subfolder: str,
    dest: str | Path,
    timeout_s: float = _FETCH["timeout_s"],
    sha256: str | None = None,
    limits: Limits | None = None,
    finish: Callable[[Path], None] | None = None,
    setting: str = "fetch.dest",
    hint: str = "Remove it yourself, or choose another `fetch.dest`",
    workdir: str | Path | None = None,
    data_folder: str | Path | None = None,
) -> Path:
    """Download a zip archive and unpack its ``<top>/<subfolder>/`` files into ``dest``.

    ``dest`` is checked first (:func:`check_dest`: below the working folder ``workdir``'s resources/,
    default the current one's, or the declared ``data_folder`` while absent; an existing one must be recorded in the run's
    FETCH_STATE as its own fetch, unchanged since, else it is refused with ``hint``), then all
    happens in one temporary folder beside it (download, checksum, unpacking, ``finish(folder)`` for
    files of the caller, the marker); ``dest`` appears, replacing an older fetched copy, only once
    complete, and is recorded; the temporary folder is removed whatever happens (a killed fetch's
    one, at the next fetch or run). Returns the destination (absolute).
    """
    limits = limits or Limits()
    workdir = Path(workdir if workdir is not None else os.getcwd()).resolve()
    check_url(url)
    _subfolder_parts(subfolder, url)
    check_dest(dest, workdir, setting=setting, data_folder=data_folder)
    dest = workdir / Path(dest)  # as given (a link stays a link, refused below), from the working folder
    _check_replaceable(dest, hint, setting, workdir)
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        files.clean_stale_partials(beside=[dest], log=_LOG.info)  # a killed fetch's temporary folder
        with files.partial_dir(dest) as work:
            got = download(url, work / "archive.zip", timeout_s, int(limits.max_download_mb * MB))
            check_sha256(url, got, sha256)
            unpacked = unpack_subfolder(work / "archive.zip", subfolder, work / "unpacked", url, limits)
            if finish is not None:
                finish(unpacked)
            marker = {
                "url": url,
                "subfolder": subfolder,
                "sha256": got,
                "time": datetime.now(UTC).isoformat(timespec="seconds"),
            }
            (unpacked / FETCH_MARKER).write_text(json.dumps(marker, indent=2) + "\n")
            _into_place(unpacked, dest, work, hint, setting, workdir)
        _record_fetch(dest, workdir, url, subfolder, got)
    except OSError as e:
        raise FetchError(f"could not write the fetch of {url} into {dest}: {e}") from e
    return dest


def fetch_images(
    url: str,
    subfolder: str,
    dest: str | Path,
    timeout_s: float = _FETCH["timeout_s"],
    sha256: str | None = None,
    limits: Limits | None = None,
    workdir: str | Path | None = None,
) -> Path:
    """An images scene's folder from a repository archive (e.g. OpenSfM's data/lund/images), into
    ``dest`` below the working folder ``workdir``'s resources/ (default: the current one's)."""
    try:
        return fetch_archive(
            url,
            subfolder,
            dest,
            timeout_s,
            sha256,
            limits,
            setting="the images folder",
            hint="Remove it yourself, or, if it holds the scene's images, set the scene sheet's `path` to it",
            workdir=workdir,
        )
    except DownloadError as e:
        raise FetchError(f"{e}. Point the scene sheet's `path` at a local folder of images instead.") from e


def fetch_flatlandia(
    dest: str | Path,
    scenes: pd.DataFrame,
    url: str = UPSTREAM_ZIP,
    timeout_s: float = _FETCH["timeout_s"],
    sha256: str | None = None,
    limits: Limits | None = None,
    workdir: str | Path | None = None,
    data_folder: str | Path | None = None,
) -> Path:
    """Download the upstream repository archive and unpack its ``data/`` folder into ``dest`` (below
    the working folder ``workdir``'s resources/, default the current one's, or the declared
    ``data_folder`` while it does not exist).

    Adds ``scenes.tsv`` and ``classes.tsv`` to it (the upstream keeps them in code) before it is
    renamed into place: the folder appears only once complete.
    """

    def sheets(folder: Path) -> None:
        sheet = scenes[["scene", "city", "name"]].map(
            escape.csv_cell
        )  # no spreadsheet formula (flatlandia.plumbing.escape)
        sheet.to_csv(folder / "scenes.tsv", sep="\t", index=False)
        pd.DataFrame({"class_id": range(len(CLASSES)), "mapillary_label": CLASSES}).to_csv(
            folder / "classes.tsv", sep="\t", index=False
        )

    try:
        return fetch_archive(
            url, "data", dest, timeout_s, sha256, limits, finish=sheets, workdir=workdir, data_folder=data_folder
        )
    except DownloadError as e:
        raise FetchError(f"could not download the Flatlandia data: {e}. {HOW_TO_POINT}") from e
    except FetchError as e:
        raise FetchError(f"{e}. {HOW_TO_POINT}") from e
