"""A fetch never deletes what it did not write, and a killed run's temporaries are cleaned.

``fetch.dest`` (and an images scene's folder) is replaced only when the run's own record says a fetch
of this run wrote it and it is unchanged since; '.', '..', the working folder, its parents, the root,
the home folder and any folder but one below the working folder's resources/ (or the declared data
folder while it does not exist) are refused before anything is downloaded. Temporaries of an
interrupted fetch or atomic write (a ``kill -9``, simulated here by a child process that kills
itself mid-write) are removed at the next start when their process is gone, and nothing else is. Every hostile input is built in the test's tmp_path and
each test checks that nothing there was deleted or written outside the destination.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest
from snakemake_runner import smk
from zip_archives import make_zip

from flatlandia.data import fetch
from flatlandia.plumbing import files

SCENES = pd.DataFrame({"scene": ["12"], "city": ["Paris"], "name": ["ParisRosaPark"]})


def tree(root: Path) -> set[str]:
    """Every path under ``root`` (links not followed), relative to it."""
    out = set()
    for dirpath, dirnames, filenames in os.walk(root):
        out |= {str(Path(dirpath, n).relative_to(root)) for n in dirnames + filenames}
    return out


@pytest.fixture
def archive(tmp_path):
    """A good images archive, tmp_path/src/good.zip (top/imgs/1.jpg)."""
    (tmp_path / "src").mkdir()
    return make_zip(tmp_path / "src" / "good.zip", {"top/imgs/1.jpg": b"1"})


@pytest.fixture
def downloads(monkeypatch):
    """Each URL fetch.download was asked for (the real download still runs)."""
    calls, real = [], fetch.download

    def spy(url, *args, **kwargs):
        calls.append(url)
        return real(url, *args, **kwargs)

    monkeypatch.setattr(fetch, "download", spy)
    return calls


def with_canary(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "canary.txt").write_text("still here")
    return folder / "canary.txt"


# ----------------------------------------------------------------------------- existing destinations


@pytest.mark.parametrize("kind", ["folder", "empty folder", "file", "link to a folder"])
@pytest.mark.parametrize("which", ["flatlandia", "images"])
def test_an_existing_destination_no_fetch_wrote_is_refused_and_kept(tmp_path, archive, downloads, kind, which):
    dest = tmp_path / "resources" / "dest"  # where a fetch may write: below the working folder's resources/
    canary = with_canary(tmp_path / "resources" / "mine")
    if kind == "folder":
        canary = with_canary(dest)
    elif kind == "empty folder":
        dest.mkdir()
    elif kind == "file":
        dest.write_text("a file of mine")
    else:
        dest.symlink_to(tmp_path / "resources" / "mine", target_is_directory=True)
    before = tree(tmp_path)
    with pytest.raises(fetch.FetchError) as err:
        if which == "flatlandia":
            fetch.fetch_flatlandia(dest, SCENES, url=archive.as_uri(), timeout_s=5, workdir=tmp_path)
        else:
            fetch.fetch_images(archive.as_uri(), "imgs", dest, timeout_s=5, workdir=tmp_path)
    msg = str(err.value)
    assert str(dest) in msg and "Remove it yourself" in msg and "nothing was downloaded" in msg, msg
    assert ("fetch.dest" in msg) == (which == "flatlandia"), msg
    assert downloads == [] and tree(tmp_path) == before
    assert canary.read_text() == "still here"


# ----------------------------------------------------------------------------- the working folder and above


@pytest.fixture
def run_dir(tmp_path, monkeypatch):
    """The working folder tmp_path/a/run, and a home folder of the test's own, each with a canary."""
    run = tmp_path / "a" / "run"
    with_canary(run)
    with_canary(tmp_path / "home")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(run)
    return run


def hostile_dests(run: Path) -> list[str]:
    tmp = run.parents[1]
    return [".", "..", "../..", "", "sub/..", "./", str(run), str(tmp), str(tmp / "a"), "/", str(tmp / "home")] + [
        "results",
        "resources",
        ".snakemake",
    ]


def test_dest_holding_the_working_folder_is_refused_before_any_download(tmp_path, run_dir, archive, downloads):
    (run_dir / "up").symlink_to(run_dir.parent, target_is_directory=True)  # a link to a parent: refused too
    before = tree(tmp_path)
    for dest in hostile_dests(run_dir) + ["up"]:
        with pytest.raises(fetch.FetchError, match="is refused: .*nothing was downloaded"):
            fetch.check_dest(dest, run_dir)
        with pytest.raises(fetch.FetchError, match=r"fetch.dest .* is refused: .*FLATLANDIA_ROOT"):
            fetch.fetch_flatlandia(dest, SCENES, url=archive.as_uri(), timeout_s=5)
        with pytest.raises(fetch.FetchError, match="is refused"):
            fetch.fetch_images(archive.as_uri(), "imgs", dest, timeout_s=5)
    assert downloads == [] and tree(tmp_path) == before
    for ok in ("resources/flatlandia", "resources/images/x"):
        fetch.check_dest(ok, run_dir)
    for outside in ("data", "../shared/flatlandia", str(tmp_path / "data")):  # only as the declared data folder
        with pytest.raises(fetch.FetchError, match="outside the working folder"):
            fetch.check_dest(outside, run_dir)
        fetch.check_dest(outside, run_dir, data_folder=outside)


# ----------------------------------------------------------------------------- an earlier fetch


def test_a_folder_from_an_earlier_fetch_is_replaced_whole(tmp_path, downloads):
    src = tmp_path / "src"
    src.mkdir()
    one = make_zip(src / "one.zip", {"Flatlandia-main/data/local_maps.json": b"{}", "Flatlandia-main/data/old": b"o"})
    two = make_zip(src / "two.zip", {"Flatlandia-main/data/local_maps.json": b"{1}"})
    dest = tmp_path / "resources" / "data"  # below the working folder's resources/
    fetch.fetch_flatlandia(dest, SCENES, url=one.as_uri(), timeout_s=5, workdir=tmp_path)
    assert tree(dest) == {"local_maps.json", "old", "scenes.tsv", "classes.tsv", fetch.FETCH_MARKER}
    assert fetch.fetched_before(dest, tmp_path)
    fetch.fetch_flatlandia(dest, SCENES, url=two.as_uri(), timeout_s=5, workdir=tmp_path)  # replaced whole
    assert tree(dest) == {"local_maps.json", "scenes.tsv", "classes.tsv", fetch.FETCH_MARKER}
    assert (dest / "local_maps.json").read_bytes() == b"{1}"
    marker = json.loads((dest / fetch.FETCH_MARKER).read_text())
    assert marker["url"] == two.as_uri() and marker["subfolder"] == "data" and len(marker["sha256"]) == 64
    state = {"resources", str(fetch.FETCH_STATE)}  # the run's record of what its fetches wrote
    fetched = {"resources/data"} | {f"resources/data/{p}" for p in tree(dest)}
    assert tree(tmp_path) == {"src", "src/one.zip", "src/two.zip"} | fetched | state
    assert downloads == [one.as_uri(), two.as_uri()]
    (dest / "added-by-hand").write_text("x")  # changed since the fetch: no longer the fetch's alone
    with pytest.raises(fetch.FetchError, match="whose files changed since"):
        fetch.fetch_flatlandia(dest, SCENES, url=one.as_uri(), timeout_s=5, workdir=tmp_path)
    assert (dest / "added-by-hand").read_text() == "x" and downloads == [one.as_uri(), two.as_uri()]


def test_a_destination_appearing_during_the_download_is_kept(tmp_path, archive, monkeypatch):
    dest = tmp_path / "resources" / "imgs"  # below the working folder's resources/
    (tmp_path / "resources").mkdir()
    real = fetch.download

    def meanwhile(*args, **kwargs):
        got = real(*args, **kwargs)
        with_canary(dest)  # another process made the folder while we downloaded
        return got

    monkeypatch.setattr(fetch, "download", meanwhile)
    with pytest.raises(fetch.FetchError, match="a folder not written by a fetch"):
        fetch.fetch_images(archive.as_uri(), "imgs", dest, timeout_s=5, workdir=tmp_path)
    assert tree(dest) == {"canary.txt"}
    assert tree(tmp_path) == {"src", "src/good.zip", "resources", "resources/imgs", "resources/imgs/canary.txt"}


# ----------------------------------------------------------------------------- killed runs

KILLED_MID_WRITE = textwrap.dedent(
    """
    import os, sys
    from pathlib import Path
    from flatlandia.data import fetch
    from flatlandia.plumbing import files

    root, url = Path(sys.argv[1]), sys.argv[2]

    def killed(url, to, *args):
        to.write_bytes(b"half a download")
        os.kill(os.getpid(), 9)

    fetch.download = killed
    with files.atomic_path(root / "results/s/maps/map.parquet") as f, files.atomic_dir(root / "results/s/sfm/model") as d:
        f.write_bytes(b"half")
        (d / "cameras.bin").write_bytes(b"half")
        fetch.fetch_images(url, "imgs", root / "resources/images/s", workdir=root)
    """
)


def killed_mid_write(root: Path, url: str) -> tuple[int, set[str]]:
    """Run a writer that is killed (SIGKILL) mid-write under ``root``; (its pid, the new paths)."""
    before = tree(root)
    child = subprocess.Popen([sys.executable, "-c", KILLED_MID_WRITE, str(root), url])
    assert child.wait(timeout=120) == -9
    return child.pid, tree(root) - before


def partials(paths: set[str]) -> set[str]:
    """The temporaries (not what is inside them) among ``paths``."""
    return {p for p in paths if ".partial-" in Path(p).name}


def test_temporaries_of_a_killed_process_are_removed_and_nothing_else(tmp_path, archive):
    root = tmp_path / "run"
    (root / "results").mkdir(parents=True)
    pid, left = killed_mid_write(root, archive.as_uri())
    stale = partials(left)
    assert {Path(p).parent.as_posix() for p in stale} == {"results/s/maps", "results/s/sfm", "resources/images"}
    assert {Path(p).suffix for p in stale if p.startswith("results/s/maps")} == {".parquet"}  # the target's suffix

    # look-alikes that must stay: a live process's temporaries, unmarked or foreign ones, links, old-style names
    tag = files._host_tag()
    keep = root / "results" / "keep"
    keep.mkdir()
    with_canary(keep / f".model.partial-{tag}-{pid}-abcdefgh")  # named like ours, no marker: not ours
    foreign = keep / f".model.partial-00000000-{pid}-abcdefgh"  # another host's: its process cannot be checked
    with_canary(foreign)
    (foreign / files.PARTIAL_MARKER).write_text(json.dumps({"pid": pid, "host": "elsewhere"}))
    lying = keep / f".model.partial-{tag}-{pid}-ijklmnop"  # a marker naming another process than the name
    with_canary(lying)
    (lying / files.PARTIAL_MARKER).write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}))
    (keep / f".map.partial-{tag}-{pid}-abcdefgh.parquet").symlink_to(keep / lying.name / "canary.txt")
    with_canary(keep / "model.tmp")
    with_canary(keep / ".images.x1y2z3")
    live_file = files.atomic_path(keep / "live.parquet")
    live_dir = files.atomic_dir(root / "resources" / "live")
    with live_file as f, live_dir as d:
        f.write_bytes(b"being written")
        (d / "x").write_text("being written")
        before = tree(tmp_path)
        said = []
        removed = files.clean_stale_partials(
            [root / "results", root / "resources", root / "absent"],
            beside=[root / "resources/images/s"],
            log=said.append,
        )
        assert {p.relative_to(root).as_posix() for p in removed} == stale
        assert tree(tmp_path) == {p for p in before if not any(p.startswith(f"run/{s}") for s in stale)}
        assert len(said) == len(stale) and all("leftover of an interrupted run" in line for line in said)
        assert files.clean_stale_partials([root / "results", root / "resources"]) == []  # a second pass: nothing
    assert (keep / "live.parquet").read_bytes() == b"being written"
    look_alikes = {
        f".model.partial-{tag}-{pid}-abcdefgh",
        foreign.name,
        lying.name,
        f".map.partial-{tag}-{pid}-abcdefgh.parquet",
    }
    assert partials(tree(tmp_path)) == {f"run/results/keep/{n}" for n in look_alikes}
    assert (root / "resources/live/x").exists() and not (root / "resources/images/s").exists()


def test_temporaries_are_named_recognisably_and_keep_the_suffix(tmp_path):
    long_name = "é" * 100 + ".png"  # 204 bytes: the temporary's name must still fit in 255
    for name in ("fig.png", "model.npz", long_name):
        with files.atomic_path(tmp_path / name) as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == Path(name).suffix and len(tmp.name.encode()) < 255
            assert files._PARTIAL_NAME.match(tmp.name)["pid"] == str(os.getpid())
            tmp.write_bytes(b"x")
    with files.atomic_dir(tmp_path / "masks") as d:
        work = d.parent
        assert work.parent == tmp_path and files._PARTIAL_NAME.match(work.name)
        assert json.loads((work / files.PARTIAL_MARKER).read_text())["pid"] == os.getpid()
        (d / "m.png").write_bytes(b"x")
    assert tree(tmp_path) == {"fig.png", "model.npz", long_name, "masks", "masks/m.png"}


def test_a_linked_results_folder_is_searched_but_no_link_below_it(tmp_path, archive):
    elsewhere = tmp_path / "scratch"
    (elsewhere / "results").mkdir(parents=True)
    _, left = killed_mid_write(elsewhere, archive.as_uri())
    run = tmp_path / "run"
    run.mkdir()
    (run / "results").symlink_to(elsewhere / "results", target_is_directory=True)
    (run / "resources").mkdir()
    (run / "resources" / "link").symlink_to(elsewhere / "resources", target_is_directory=True)
    removed = files.clean_stale_partials([run / "results", run / "resources"])
    assert {p.relative_to(run).as_posix() for p in removed} == {p for p in partials(left) if p.startswith("results")}
    assert partials(tree(elsewhere)) == {p for p in partials(left) if p.startswith("resources")}


def test_a_fetch_removes_the_temporaries_of_a_killed_fetch_of_the_same_folder(tmp_path, archive):
    root = tmp_path / "run"
    root.mkdir()
    _, left = killed_mid_write(root, archive.as_uri())
    assert partials(left)
    other = with_canary(root / "resources/images/.t.x1y2z3")  # not ours: kept
    fetch.fetch_images(archive.as_uri(), "imgs", root / "resources/images/s", timeout_s=5, workdir=root)
    assert tree(root / "resources/images") == {
        "s",
        "s/1.jpg",
        f"s/{fetch.FETCH_MARKER}",
        ".t.x1y2z3",
        ".t.x1y2z3/canary.txt",
    }
    assert other.read_text() == "still here"


# ----------------------------------------------------------------------------- through Snakemake


@pytest.mark.slow  # Snakemake jobs
def test_workflow_refuses_dest_dotdot_with_one_error_and_deletes_nothing(repo, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    canary = with_canary(tmp_path / "mine")
    archive = make_zip(tmp_path / "Flatlandia-main.zip", {"Flatlandia-main/data/local_maps.json": b"{}"})
    cfg = tmp_path / "dotdot.yaml"
    cfg.write_text(f"flatlandia_root: {tmp_path / 'nowhere'}\nfetch: {{url: '{archive.as_uri()}', dest: '..'}}\n")
    before = tree(tmp_path)
    res = smk(
        repo, run, "--cores", "1", "results/12/ingest/ingest.json", "--configfile", str(cfg), "--config", "select=[12]"
    )
    assert res.returncode != 0
    errors = [line for line in res.stderr.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and "fetch.dest '..'" in errors[0] and "is refused" in errors[0], res.stderr[-3000:]
    assert "Traceback" not in res.stderr, res.stderr[-3000:]
    new = {p for p in tree(tmp_path) - before if not p.startswith(("run/.snakemake", "run/logs"))}
    assert new <= {"run/...fetched"}, new  # nothing but (at most) Snakemake's bookkeeping
    assert before <= tree(tmp_path) and canary.read_text() == "still here"


@pytest.mark.slow  # the published data (flat_root)
def test_a_run_removes_the_leftovers_of_a_killed_one_and_a_dry_run_does_not(repo, flat_root, tmp_path, archive):
    run = tmp_path / "run"
    (run / "results").mkdir(parents=True)
    _, left = killed_mid_write(run, archive.as_uri())
    stale = partials(left)
    args = ["--cores", "1", "results/12/ingest/ingest.json", "--config", f"flatlandia_root={flat_root}", "select=[12]"]
    res = smk(repo, run, "-n", *args)
    assert res.returncode == 0 and partials(tree(run)) == stale, res.stderr[-3000:]
    res = smk(repo, run, *args)
    assert res.returncode == 0, res.stderr[-3000:]
    assert not partials(tree(run)) and (run / "results/12/ingest/ingest.json").exists()
    assert sum("leftover of an interrupted run" in line for line in res.stderr.splitlines()) == len(stale)
