"""Fetching default inputs from their public source (here a local zip served by file:// URL)."""

import hashlib
import zipfile

import pandas as pd
import pytest
from snakemake_runner import smk

from flatlandia.data import fetch, ingest

SCENE12 = [
    "local_maps.json",
    "individual_reference_maps/map_12.json",
    "maps/12/transformations.json",
    "maps/12/tokens.txt",
    "MANIFEST.tsv",
]


@pytest.fixture
def upstream_zip(tmp_path, flat_root):
    """A repository archive shaped like GitHub's: Flatlandia-main/data/..."""
    z = tmp_path / "Flatlandia-main.zip"
    with zipfile.ZipFile(z, "w") as out:
        out.writestr("Flatlandia-main/README.md", "upstream readme")
        for rel in SCENE12:
            out.write(flat_root / rel, f"Flatlandia-main/data/{rel}")
    return z


@pytest.mark.slow  # the published data (flat_root)
def test_fetch_flatlandia_unpacks_data_and_adds_sheets(upstream_zip, tmp_path):
    scenes = pd.DataFrame({"scene": ["12"], "city": ["Paris"], "name": ["ParisRosaPark"]})
    (tmp_path / "resources").mkdir()  # a fetch writes below the working folder's resources/
    dest = fetch.fetch_flatlandia(
        tmp_path / "resources/flatlandia", scenes, url=upstream_zip.as_uri(), timeout_s=5, workdir=tmp_path
    )
    assert (dest / "local_maps.json").exists() and not (dest / "README.md").exists()
    assert (dest / "classes.tsv").read_text().count("\n") == 43
    rep = ingest.ingest_scene(dest, "12", verify_hash=True)
    assert rep["n_queries"] == 3 and rep["available"]["transformations"]


@pytest.mark.slow  # the Lund photos
def test_fetch_images_takes_the_subfolder(tmp_path, lund):
    z = tmp_path / "OpenSfM-main.zip"
    with zipfile.ZipFile(z, "w") as out:
        for name in ("01.jpg", "02.jpg"):
            out.write(lund / name, f"OpenSfM-main/data/lund/images/{name}")
        out.writestr("OpenSfM-main/data/lund/config.yaml", "x")
    (tmp_path / "resources").mkdir()  # a fetch writes below the working folder's resources/
    lund_dest = tmp_path / "resources/images/lund"
    dest = fetch.fetch_images(z.as_uri(), "data/lund/images", lund_dest, timeout_s=5, workdir=tmp_path)
    assert sorted(p.name for p in dest.iterdir()) == [fetch.FETCH_MARKER, "01.jpg", "02.jpg"]


def test_offline_fetch_fails_at_once_with_instructions(tmp_path):
    dest = tmp_path / "resources/flatlandia"  # a fetch writes below the working folder's resources/
    (tmp_path / "resources").mkdir()
    with pytest.raises(fetch.FetchError, match="could not download the Flatlandia data.*FLATLANDIA_ROOT"):
        fetch.fetch_flatlandia(
            dest,
            pd.DataFrame({"scene": ["0"], "city": ["x"], "name": ["y"]}),
            url="https://127.0.0.1:9/nothing.zip",
            timeout_s=5,
            workdir=tmp_path,
        )
    assert not dest.exists()
    with pytest.raises(fetch.FetchError, match="archive holds no data/ folder"):
        bad = tmp_path / "bad.zip"
        with zipfile.ZipFile(bad, "w") as out:
            out.writestr("x/readme", "nothing")
        fetch.fetch_flatlandia(
            dest, pd.DataFrame({"scene": [], "city": [], "name": []}), url=bad.as_uri(), workdir=tmp_path
        )
    assert not dest.exists()


@pytest.mark.slow  # the published data (flat_root)
def test_workflow_fetches_when_the_data_folder_is_missing(repo, upstream_zip, tmp_path):
    cfg = tmp_path / "fetch.yaml"
    pin = hashlib.sha256(upstream_zip.read_bytes()).hexdigest()  # a pinned archive that matches unpacks
    cfg.write_text(
        f"flatlandia_root: {tmp_path / 'nowhere'}\n"
        f"fetch: {{url: '{upstream_zip.as_uri()}', dest: '{tmp_path / 'resources/fetched'}', timeout_s: 5, sha256: {pin}}}\n"
    )
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "1",
        "results/12/queries/queries.parquet",
        "results/tables/dataset_stats.parquet",
        "--configfile",
        str(cfg),
        "--config",
        "select=[12]",
        "benchmark_scenes=[12]",
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert (tmp_path / "resources/fetched/local_maps.json").exists()  # below the working folder's resources/
    assert len(pd.read_parquet(tmp_path / "results/12/queries/queries.parquet")) == 3
    stats = pd.read_parquet(tmp_path / "results/tables/dataset_stats.parquet").set_index("city")
    assert stats.loc["Paris", "images"] == 49  # tokens.txt of the fetched scene 12
