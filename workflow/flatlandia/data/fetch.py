"""Fetch the published Flatlandia data from its upstream repository when no local copy exists."""

from __future__ import annotations

import io as _io
import shutil
import tempfile
import urllib.error
import urllib.request
import zipfile
from pathlib import Path

import pandas as pd

from flatlandia.classes import CLASSES

UPSTREAM_ZIP = "https://codeload.github.com/IIT-PAVIS/Flatlandia/zip/refs/heads/main"

HOW_TO_POINT = (
    "Point the workflow at a local copy of the Flatlandia data instead: set "
    "`flatlandia_root` in config/config.yaml, pass `--config flatlandia_root=/path/to/data`, "
    "or export FLATLANDIA_ROOT=/path/to/data (a folder holding individual_reference_maps/, "
    "maps/ and local_maps.json)."
)


class FetchError(RuntimeError):
    pass


def download(url: str, timeout_s: float) -> bytes:
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:
            return resp.read()
    except (urllib.error.URLError, TimeoutError, OSError) as e:
        raise FetchError(f"could not download {url}: {e}") from e


def unpack_subfolder(payload: bytes, subfolder: str, dest: Path, url: str) -> Path:
    """Unpack the members under ``<top>/<subfolder>/`` of a repository zip into ``dest`` atomically."""
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    marker = "/" + subfolder.strip("/") + "/"
    try:
        with zipfile.ZipFile(_io.BytesIO(payload)) as z:
            members = [m for m in z.namelist() if marker in m and not m.endswith("/")]
            if not members:
                raise FetchError(f"{url}: archive holds no {subfolder}/ folder")
            for m in members:
                target = tmp / m.split(marker, 1)[1]
                target.parent.mkdir(parents=True, exist_ok=True)
                with z.open(m) as src, open(target, "wb") as out:
                    shutil.copyfileobj(src, out)
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return dest


def fetch_images(url: str, subfolder: str, dest: str | Path, timeout_s: float = 30.0) -> Path:
    """An images scene's folder from a repository archive (e.g. OpenSfM's data/lund/images)."""
    try:
        payload = download(url, timeout_s)
    except FetchError as e:
        raise FetchError(f"{e}. Point the scene sheet's `path` at a local folder of images instead.") from e
    return unpack_subfolder(payload, subfolder, Path(dest), url)


def fetch_flatlandia(dest: str | Path, scenes: pd.DataFrame, url: str = UPSTREAM_ZIP, timeout_s: float = 30.0) -> Path:
    """Download the upstream repository archive and unpack its ``data/`` folder into ``dest``.

    Writes ``scenes.tsv`` and ``classes.tsv`` beside it (the upstream keeps them in code).
    The folder appears only once complete (unpacked to a temporary folder, then renamed).
    """
    try:
        payload = download(url, timeout_s)
    except FetchError as e:
        raise FetchError(f"could not download the Flatlandia data: {e}. {HOW_TO_POINT}") from e
    try:
        dest = unpack_subfolder(payload, "data", Path(dest), url)
    except FetchError as e:
        raise FetchError(f"{e}. {HOW_TO_POINT}") from e
    scenes[["scene", "city", "name"]].to_csv(dest / "scenes.tsv", sep="\t", index=False)
    pd.DataFrame({"class_id": range(len(CLASSES)), "mapillary_label": CLASSES}).to_csv(
        dest / "classes.tsv", sep="\t", index=False
    )
    return dest
