"""`make test` on a clone without ../shared: the tests get the published data the way `make all`
does (the workflow's fetch into resources/flatlandia), here from a file:// archive of it; and the
Lund photos the same way (rule fetch_images' fetch into resources/images/lund), and the Berlin
photos and masks from the same OpenSfM archive (into resources/images/berlin)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import conftest
import pytest
from conftest import (
    REPO,
    berlin_source,
    data_root,
    ensure_published_data,
    find_berlin_images,
    find_lund_images,
    lund_source,
)

from flatlandia.data import fetch

#: every test here runs Snakemake jobs or reads the published data (the slow lane)
pytestmark = pytest.mark.slow

#: the published files one scene's tests read, in the upstream repository's layout (data/...)
SCENE12 = [
    "local_maps.json",
    "MANIFEST.tsv",
    "individual_reference_maps/map_12.json",
    "maps/12/transformations.json",
    "maps/12/tokens.txt",
]


def upstream_archive(root: Path, path: Path) -> Path:
    """A zip laid out as GitHub's archive of IIT-PAVIS/Flatlandia: Flatlandia-main/data/..."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for rel in SCENE12:
            z.write(root / rel, f"Flatlandia-main/data/{rel}")
    return path


def test_the_published_data_is_fetched_as_make_all_fetches_it(tmp_path):
    archive = upstream_archive(data_root(), tmp_path / "flatlandia.zip")
    dest = tmp_path / "resources" / "flatlandia"
    assert ensure_published_data(dest, archive.as_uri()) == ""
    assert (dest / "local_maps.json").read_bytes() == (data_root() / "local_maps.json").read_bytes()
    assert (dest / ".flatlandia-fetch").exists() and (dest / "scenes.tsv").exists()
    problem = ensure_published_data(tmp_path / "elsewhere", (tmp_path / "missing.zip").as_uri())
    assert "missing.zip" in problem and "FLATLANDIA_ROOT" in problem  # says how to point at a local copy


def test_a_fresh_clone_without_shared_passes_a_data_test(tmp_path):
    """A clone of the repository with no ../shared beside it: a test of the slow lane that reads the
    published data fetches it first (FLATLANDIA_FETCH_URL: a file:// archive instead of GitHub)."""
    if not (REPO / ".git").exists() or shutil.which("git") is None:
        pytest.skip("the repository is not a git checkout (nothing to clone)")
    clone = tmp_path / "work" / "main"
    res = subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert not (clone.parent / "shared").exists()
    archive = upstream_archive(data_root(), tmp_path / "flatlandia.zip")
    env = {k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"}
    env |= {"FLATLANDIA_FETCH_URL": archive.as_uri(), "PYTHONPATH": str(clone / "workflow")}
    test = "tests/test_bad_input.py::test_ingest_detects_truncation_and_missing_required"
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", test],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]
    assert "fetching it as `make all` does" in res.stdout and "1 passed" in res.stdout
    fetched = clone / "resources" / "flatlandia"
    assert (fetched / "local_maps.json").exists() and (fetched / ".flatlandia-fetch").exists()


def opensfm_archive(lund: Path, path: Path, names=("01.jpg", "02.jpg", "03.jpg"), berlin: Path | None = None) -> Path:
    """A zip laid out as GitHub's archive of mapillary/OpenSfM: OpenSfM-main/data/lund/images/...,
    and with ``berlin`` its folder's files as OpenSfM-main/data/berlin/{images,masks}/..."""
    sub = lund_source()["subfolder"]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("OpenSfM-main/data/lund/config.yaml", "x")
        for name in names:
            z.write(lund / name, f"OpenSfM-main/{sub}/{name}")
        if berlin is not None:
            z.writestr("OpenSfM-main/data/berlin/config.yaml", "x")
            for file in sorted(berlin.glob("*/*.*")):
                z.write(file, f"OpenSfM-main/{berlin_source()['subfolder']}/{file.relative_to(berlin)}")
    return path


def test_the_lund_photos_are_fetched_as_make_all_fetches_them(lund, tmp_path, monkeypatch):
    """No ../shared/images/lund: the photos are fetched from the scene sheet's source (here
    FLATLANDIA_LUND_URL, a file:// zip) into resources/images/lund, once; a failed fetch is one line."""
    archive = opensfm_archive(lund, tmp_path / "OpenSfM-main.zip")
    shared = tmp_path / "shared" / "images" / "lund"  # absent
    dest = tmp_path / "main" / "resources" / "images" / "lund"
    monkeypatch.setenv("FLATLANDIA_LUND_URL", archive.as_uri())
    assert find_lund_images(shared, dest) == (dest, "")
    assert sorted(p.name for p in dest.glob("*.jpg")) == ["01.jpg", "02.jpg", "03.jpg"]
    assert (dest / "01.jpg").read_bytes() == (lund / "01.jpg").read_bytes() and fetch.fetched_before(
        dest, conftest.fetch_workdir(dest)
    )
    archive.unlink()  # a complete fetch of the same source is used as it is: nothing is downloaded
    assert find_lund_images(shared, dest) == (dest, "")
    shared.mkdir(parents=True)  # ../shared/images/lund, when there, comes first
    assert find_lund_images(shared, dest) == (shared, "")

    half = tmp_path / "half"  # a folder without the marker of a complete fetch is not trusted
    half.mkdir()
    (half / "01.jpg").write_bytes(b"")
    missing = tmp_path / "missing.zip"
    for where in (half, tmp_path / "nothing"):
        folder, problem = find_lund_images(tmp_path / "absent", where, missing.as_uri())
        assert folder == where and "\n" not in problem, problem
        for said in ("the Lund photos are needed", str(tmp_path / "absent"), str(where), "missing.zip"):
            assert said in problem, (said, problem)
        assert "FLATLANDIA_LUND_URL" in problem
    assert not (tmp_path / "nothing").exists()
    monkeypatch.setattr(conftest, "_lund_images", lambda: (dest, problem))
    with pytest.raises(pytest.fail.Exception, match="the Lund photos are needed") as failed:
        conftest.lund_images()
    assert not failed.value.pytrace  # one line, no traceback


def test_the_berlin_photos_and_masks_are_fetched_from_the_same_archive(lund, berlin, tmp_path, monkeypatch):
    """No ../shared/images/berlin: its photos and masks are fetched from OpenSfM's data/berlin, the
    archive of the Lund photos (here a file:// zip: FLATLANDIA_LUND_URL serves both, unless
    FLATLANDIA_BERLIN_URL is set), into resources/images/berlin, with the layout of ../shared's."""
    archive = opensfm_archive(lund, tmp_path / "OpenSfM-main.zip", ("01.jpg",), berlin=berlin)
    shared = tmp_path / "shared" / "images" / "berlin"  # absent
    dest = tmp_path / "main" / "resources" / "images" / "berlin"
    monkeypatch.delenv("FLATLANDIA_BERLIN_URL", raising=False)
    monkeypatch.setenv("FLATLANDIA_LUND_URL", archive.as_uri())
    assert find_berlin_images(shared, dest) == (dest, "") and fetch.fetched_before(dest, conftest.fetch_workdir(dest))
    for sub in ("images", "masks"):
        want = sorted(p.name for p in (berlin / sub).iterdir())
        assert want and sorted(p.name for p in (dest / sub).iterdir()) == want
    assert (dest / "masks" / "01.jpg.png").read_bytes() == (berlin / "masks" / "01.jpg.png").read_bytes()
    lund_dest = tmp_path / "main" / "resources" / "images" / "lund"
    assert find_lund_images(tmp_path / "absent", lund_dest) == (lund_dest, "")  # the same archive
    assert [p.name for p in lund_dest.glob("*.jpg")] == ["01.jpg"]
    archive.unlink()  # a complete fetch of the same source is used as it is
    assert find_berlin_images(shared, dest) == (dest, "")

    missing = tmp_path / "missing.zip"
    monkeypatch.setenv("FLATLANDIA_BERLIN_URL", missing.as_uri())  # it comes first
    folder, problem = find_berlin_images(shared, tmp_path / "nothing")
    assert folder == tmp_path / "nothing" and "\n" not in problem, problem
    for said in ("the Berlin photos and masks are needed", str(shared), "missing.zip", "FLATLANDIA_BERLIN_URL"):
        assert said in problem, (said, problem)
    monkeypatch.setattr(conftest, "_berlin_images", lambda: (dest, problem))
    with pytest.raises(pytest.fail.Exception, match="the Berlin photos and masks are needed") as failed:
        conftest.berlin_images()
    assert not failed.value.pytrace
