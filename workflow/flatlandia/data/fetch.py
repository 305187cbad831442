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
  into place once complete and removed on any failure.
"""

from __future__ import annotations

import hashlib
import shutil
import stat
import tempfile
import urllib.error
import urllib.parse
import urllib.request
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from flatlandia import config
from flatlandia.classes import CLASSES

UPSTREAM_ZIP = "https://codeload.github.com/IIT-PAVIS/Flatlandia/zip/refs/heads/main"

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

_DEFAULTS = config.section_defaults("fetch")


class FetchError(RuntimeError):
    pass


class DownloadError(FetchError):
    """The source could not be read (offline, not found): the user can point at a local copy."""


@dataclass(frozen=True)
class Limits:
    """Caps on one fetch (config ``fetch``), so a hostile or broken archive cannot fill disk or memory."""

    max_download_mb: float = _DEFAULTS["max_download_mb"]
    max_unpacked_mb: float = _DEFAULTS["max_unpacked_mb"]
    max_members: int = _DEFAULTS["max_members"]

    @classmethod
    def from_config(cls, fetch_cfg: dict | None) -> Limits:
        """The caps of a config's ``fetch`` section (its other keys ignored)."""
        keys = ("max_download_mb", "max_unpacked_mb", "max_members")
        return cls(**{k: fetch_cfg[k] for k in keys if k in (fetch_cfg or {})})


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


def check_sha256(url: str, got: str, expected: str | None) -> None:
    """Stop before unpacking when a pinned checksum differs: the archive is not the one pinned."""
    expected = (expected or "").strip().lower()
    if expected and got.lower() != expected:
        raise FetchError(
            f"{url}: sha256 mismatch: the download is {got}, the pinned value is {expected}; nothing was unpacked"
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
    with z.open(info) as src, open(target, "wb") as out:
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


def fetch_archive(
    url: str,
    subfolder: str,
    dest: str | Path,
    timeout_s: float = 30.0,
    sha256: str | None = None,
    limits: Limits | None = None,
) -> Path:
    """Download a zip archive and unpack its ``<top>/<subfolder>/`` files into ``dest``.

    All happens in one temporary folder beside ``dest`` (download, checksum, unpacking); ``dest``
    appears, replacing an older copy, only once complete, and the temporary folder is removed
    whatever happens.
    """
    limits = limits or Limits()
    dest = Path(dest)
    check_url(url)
    _subfolder_parts(subfolder, url)
    dest.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    try:
        got = download(url, work / "archive.zip", timeout_s, int(limits.max_download_mb * MB))
        check_sha256(url, got, sha256)
        unpacked = unpack_subfolder(work / "archive.zip", subfolder, work / "unpacked", url, limits)
        if dest.exists():
            shutil.rmtree(dest)
        unpacked.rename(dest)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return dest


def fetch_images(
    url: str,
    subfolder: str,
    dest: str | Path,
    timeout_s: float = 30.0,
    sha256: str | None = None,
    limits: Limits | None = None,
) -> Path:
    """An images scene's folder from a repository archive (e.g. OpenSfM's data/lund/images)."""
    try:
        return fetch_archive(url, subfolder, dest, timeout_s, sha256, limits)
    except DownloadError as e:
        raise FetchError(f"{e}. Point the scene sheet's `path` at a local folder of images instead.") from e


def fetch_flatlandia(
    dest: str | Path,
    scenes: pd.DataFrame,
    url: str = UPSTREAM_ZIP,
    timeout_s: float = 30.0,
    sha256: str | None = None,
    limits: Limits | None = None,
) -> Path:
    """Download the upstream repository archive and unpack its ``data/`` folder into ``dest``.

    Writes ``scenes.tsv`` and ``classes.tsv`` beside it (the upstream keeps them in code).
    The folder appears only once complete (unpacked to a temporary folder, then renamed).
    """
    try:
        dest = fetch_archive(url, "data", dest, timeout_s, sha256, limits)
    except DownloadError as e:
        raise FetchError(f"could not download the Flatlandia data: {e}. {HOW_TO_POINT}") from e
    except FetchError as e:
        raise FetchError(f"{e}. {HOW_TO_POINT}") from e
    scenes[["scene", "city", "name"]].to_csv(dest / "scenes.tsv", sep="\t", index=False)
    pd.DataFrame({"class_id": range(len(CLASSES)), "mapillary_label": CLASSES}).to_csv(
        dest / "classes.tsv", sep="\t", index=False
    )
    return dest
