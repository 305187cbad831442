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

from .classes import CLASSES

UPSTREAM_ZIP = "https://codeload.github.com/IIT-PAVIS/Flatlandia/zip/refs/heads/main"

HOW_TO_POINT = (
    "Point the workflow at a local copy of the Flatlandia data instead: set "
    "`flatlandia_root` in config/config.yaml, pass `--config flatlandia_root=/path/to/data`, "
    "or export FLATLANDIA_ROOT=/path/to/data (a folder holding individual_reference_maps/, "
    "maps/ and local_maps.json)."
)


class FetchError(RuntimeError):
    pass


def fetch_flatlandia(dest: str | Path, scenes: pd.DataFrame, url: str = UPSTREAM_ZIP,
                     timeout_s: float = 30.0) -> Path:
    """Download the upstream repository archive and unpack its ``data/`` folder into ``dest``.

    Writes ``scenes.tsv`` and ``classes.tsv`` beside it (the upstream keeps them in code).
    The folder appears only once complete (unpacked to a temporary folder, then renamed).
    """
    dest = Path(dest)
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:
            payload = resp.read()
    except (urllib.error.URLError, TimeoutError, OSError) as e:
        raise FetchError(f"could not download the Flatlandia data from {url}: {e}. {HOW_TO_POINT}") from e
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    try:
        with zipfile.ZipFile(_io.BytesIO(payload)) as z:
            members = [m for m in z.namelist() if "/data/" in m and not m.endswith("/")]
            if not members:
                raise FetchError(f"{url}: archive holds no data/ folder. {HOW_TO_POINT}")
            for m in members:
                rel = m.split("/data/", 1)[1]
                target = tmp / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                with z.open(m) as src, open(target, "wb") as out:
                    shutil.copyfileobj(src, out)
        scenes[["scene", "city", "name"]].to_csv(tmp / "scenes.tsv", sep="\t", index=False)
        pd.DataFrame({"class_id": range(len(CLASSES)), "mapillary_label": CLASSES}).to_csv(
            tmp / "classes.tsv", sep="\t", index=False)
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return dest
