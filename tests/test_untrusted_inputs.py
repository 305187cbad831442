"""Untrusted inputs cannot write outside the workflow or run code: crafted archives, pinned
checksums, pickled checkpoints, names from users' files, model folders with their own code.

Every archive and file is built here, in the test's temporary folder; each attack is also checked
by a scan of that whole folder: nothing is written outside the destination.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
import re
import shutil
import stat
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from snakemake_runner import smk
from zip_archives import make_zip

from flatlandia import checkpoints
from flatlandia.data import fetch
from flatlandia.fine import models
from flatlandia.images import classify_points, depth, image_audit, segment
from flatlandia.plumbing import rule_log
from flatlandia.plumbing.errors import InputError


def tree(root: Path) -> set[str]:
    """Every path under ``root`` (folders, files, links; links not followed), relative to it."""
    out = set()
    for dirpath, dirnames, filenames in os.walk(root):
        out |= {str(Path(dirpath, n).relative_to(root)) for n in dirnames + filenames}
    return out


@pytest.fixture
def deep_dest(tmp_path):
    """A destination four folders down below resources/ (where a fetch may write), so a
    ``../../../..`` member would still land in tmp_path."""
    parent = tmp_path / "resources" / "a" / "b" / "c" / "d"
    parent.mkdir(parents=True)
    return parent / "dest"


def attack(kind: str, tmp_path: Path) -> tuple[list[tuple], str, dict]:
    """(members, the refused member's name, limits) of one crafted archive; each also holds a good file."""
    good = ("top/imgs/ok.jpg", b"fine")
    if kind == "dotdot":
        bad = "top/imgs/../../../../x.jpg"
        return [good, (bad, b"escaped")], bad, {}
    if kind == "absolute":
        bad = f"top/imgs/{tmp_path}/abs/x.jpg"  # top/imgs//tmp/.../abs/x.jpg
        return [good, (bad, b"escaped")], bad, {}
    if kind == "symlink":
        bad = "top/imgs/link.jpg"
        return [good, (bad, str(tmp_path / "outside.txt").encode(), stat.S_IFLNK)], bad, {}
    if kind == "device":
        bad = "top/imgs/dev.jpg"
        return [good, (bad, b"", stat.S_IFCHR)], bad, {}
    if kind == "oversize":
        bad = "top/imgs/huge.jpg"  # 2 MB of zeros: a few KB compressed
        return [good, (bad, bytes(2_000_000))], bad, {"max_unpacked_mb": 1}
    raise ValueError(kind)


@pytest.mark.parametrize("kind", ["dotdot", "absolute", "symlink", "device", "oversize"])
def test_crafted_archive_is_refused_and_nothing_is_written(tmp_path, deep_dest, kind):
    members, bad, caps = attack(kind, tmp_path)
    archive = make_zip(tmp_path / "crafted.zip", members)
    before = tree(tmp_path)
    with pytest.raises(fetch.FetchError) as err:
        fetch.fetch_images(
            archive.as_uri(), "imgs", deep_dest, timeout_s=5, limits=fetch.Limits(**caps), workdir=tmp_path
        )
    msg = str(err.value)
    assert msg.startswith(archive.as_uri()) and repr(bad) in msg and "nothing was unpacked" in msg, msg
    assert tree(tmp_path) == before  # no member, no temporary folder, not even the destination


def test_too_many_members_and_too_big_a_download_are_refused(tmp_path):
    archive = make_zip(tmp_path / "many.zip", [(f"top/imgs/{i}.jpg", b"x" * 500) for i in range(5)])
    dest = tmp_path / "resources" / "dest"  # below the working folder's resources/
    dest.parent.mkdir()
    before = tree(tmp_path)
    with pytest.raises(fetch.FetchError, match=r"holds 5 members, over fetch.max_members \(4\)"):
        fetch.fetch_images(archive.as_uri(), "imgs", dest, limits=fetch.Limits(max_members=4), workdir=tmp_path)
    with pytest.raises(fetch.FetchError, match=r"exceeds fetch.max_download_mb \(0.0001 MB\)"):
        fetch.fetch_images(
            archive.as_uri(), "imgs", dest, limits=fetch.Limits(max_download_mb=0.0001), workdir=tmp_path
        )
    assert tree(tmp_path) == before
    got = fetch.fetch_images(archive.as_uri(), "imgs", dest, limits=fetch.Limits(max_members=5), workdir=tmp_path)
    assert sorted(p.name for p in got.iterdir()) == [fetch.FETCH_MARKER] + [f"{i}.jpg" for i in range(5)]


def test_members_outside_the_subfolder_are_never_written(tmp_path):
    archive = make_zip(
        tmp_path / "mixed.zip",
        [("top/imgs/ok.jpg", b"a"), ("top/src/imgs/other.jpg", b"b"), ("top/../imgs/x.jpg", b"c"), ("top/imgs/", b"")],
    )
    got = fetch.fetch_images(archive.as_uri(), "imgs", tmp_path / "resources/dest", workdir=tmp_path)
    assert tree(got) == {"ok.jpg", fetch.FETCH_MARKER}
    state = {"resources", str(fetch.FETCH_STATE)}  # the run's record of what its fetches wrote
    fetched = {"resources/dest", "resources/dest/ok.jpg", f"resources/dest/{fetch.FETCH_MARKER}"}
    assert tree(tmp_path) == {"mixed.zip"} | fetched | state


@pytest.mark.parametrize("url", ["http://example.org/a.zip", "ftp://example.org/a.zip", "data:,x", "/tmp/a.zip"])
def test_only_https_and_local_files_are_fetched(tmp_path, url):
    with pytest.raises(fetch.FetchError, match="only https:// sources"):
        fetch.fetch_images(url, "imgs", tmp_path / "dest", workdir=tmp_path)
    assert tree(tmp_path) == set()


def test_a_redirect_away_from_https_is_refused():
    handler = fetch._HttpsRedirectsOnly()
    req = urllib.request.Request("https://example.org/a.zip")
    with pytest.raises(fetch.FetchError, match="refused a redirect to http://evil.example/a.zip"):
        handler.redirect_request(req, None, 302, "Found", {}, "http://evil.example/a.zip")
    assert handler.redirect_request(req, None, 302, "Found", {}, "https://mirror.example/a.zip") is not None


def test_sha256_mismatch_stops_before_unpacking_and_a_match_unpacks(tmp_path):
    archive = make_zip(tmp_path / "good.zip", [("top/imgs/01.jpg", b"one"), ("top/imgs/02.jpg", b"two")])
    pin = hashlib.sha256(archive.read_bytes()).hexdigest()
    dest = tmp_path / "resources" / "dest"  # below the working folder's resources/
    dest.parent.mkdir()
    before = tree(tmp_path)
    with pytest.raises(fetch.FetchError, match=f"sha256 mismatch: the download is {pin}, the pinned value is 0+;"):
        fetch.fetch_images(archive.as_uri(), "imgs", dest, sha256="0" * 64, workdir=tmp_path)
    assert tree(tmp_path) == before
    got = fetch.fetch_images(archive.as_uri(), "imgs", dest, sha256=pin.upper(), workdir=tmp_path)
    assert (got / "01.jpg").read_bytes() == b"one" and (got / "02.jpg").read_bytes() == b"two"


def test_flatlandia_archive_pin_mismatch_says_how_to_point_at_a_local_copy(tmp_path):
    archive = make_zip(tmp_path / "Flatlandia-main.zip", [("Flatlandia-main/data/local_maps.json", b"{}")])
    scenes = SimpleNamespace()  # never reached: the mismatch stops first
    dest = tmp_path / "resources" / "flatlandia"  # below the working folder's resources/
    dest.parent.mkdir()
    with pytest.raises(fetch.FetchError, match="sha256 mismatch.*FLATLANDIA_ROOT"):
        fetch.fetch_flatlandia(dest, scenes, url=archive.as_uri(), sha256="a" * 64, workdir=tmp_path)
    assert tree(tmp_path) == {"Flatlandia-main.zip", "resources"}  # nothing but the (empty) parent made here


def _sheet(tmp_path: Path, url: str, sha256: str = "") -> Path:
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(
        "scene\tsource\tcity\tname\tpath\turl\tsubfolder\tsha256\n"
        f"mine\timages\tLund\tmine\t{tmp_path / 'absent'}\t{url}\timgs\t{sha256}\n"
    )
    return sheet


@pytest.mark.parametrize("case", ["dotdot", "sha256"])
@pytest.mark.slow  # the published data (flat_root)
def test_scene_sheet_archive_stops_the_run_with_one_error(repo, flat_root, tmp_path, case):
    if case == "dotdot":
        archive = make_zip(tmp_path / "crafted.zip", attack("dotdot", tmp_path)[0])
        sheet, want = _sheet(tmp_path, archive.as_uri()), "refused archive member 'top/imgs/../../../../x.jpg'"
    else:
        archive = make_zip(tmp_path / "good.zip", [("top/imgs/01.jpg", b"one")])
        sheet, want = _sheet(tmp_path, archive.as_uri(), "f" * 64), "sha256 mismatch"
    before = tree(tmp_path)
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "1",
        "results/mine/images/images.parquet",
        "--config",
        f"flatlandia_root={flat_root}",
        f"scenes={sheet}",
    )
    assert res.returncode != 0
    errors = [line for line in res.stderr.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and want in errors[0] and archive.as_uri() in errors[0], res.stderr[-3000:]
    new = {p for p in tree(tmp_path) - before if not p.startswith((".snakemake", "logs"))}
    assert new <= {"resources", "resources/images"}, new  # the destination's parent, empty


# ----------------------------------------------------------------------------- checkpoints


class PickledCallable:
    """Unpickling this calls Path.write_text: what a shared checkpoint could do with any callable."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (pathlib.Path.write_text, (self.marker, "code ran"))


def _tiny_result():
    cfg = models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)
    model = models.build_model(cfg)
    history = [{"epoch": 0, "train_loss": np.float32(1.5), "val_median_m": np.float64(3.0)}]
    result = {"state_dict": model.state_dict(), "config": cfg.to_dict(), "history": history, "best_epoch": np.int64(0)}
    return model, cfg, {**result, "best_val_median_m": float("inf"), "seconds": 0.5}


def test_the_workflows_own_checkpoint_loads_with_weights_only(tmp_path):
    model, cfg, result = _tiny_result()
    path = tmp_path / "ck.pt"
    checkpoints.save_checkpoint(result, path)
    loaded, cfg2 = checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model)
    assert cfg2 == cfg
    assert all(torch.equal(loaded.state_dict()[k], v) for k, v in model.state_dict().items())
    info = checkpoints.checkpoint_info(path)
    assert info["history"][0]["train_loss"] == 1.5 and info["best_val_median_m"] == float("inf")
    raw = torch.load(path, weights_only=True)  # nothing but tensors and plain data
    assert set(raw) == {"format", "state_dict", "meta"} and isinstance(raw["meta"], str)


def test_checkpoint_with_a_pickled_callable_is_refused_and_runs_nothing(tmp_path, capsys):
    model, cfg, result = _tiny_result()
    marker = tmp_path / "marker"
    path = tmp_path / "shared.pt"
    meta = json.dumps({"config": cfg.to_dict()})
    torch.save(
        {"format": checkpoints.FORMAT, "state_dict": model.state_dict(), "meta": meta, "x": PickledCallable(marker)},
        path,
    )

    def main(smk, log):  # as a rule script loads it
        checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model)

    with pytest.raises(SystemExit):
        rule_log.run(main, SimpleNamespace(log=[]))
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and errors[0].startswith(f"ERROR: {path}: refused:"), errors
    assert "could run code" in errors[0] and "getattr" in errors[0]
    assert not marker.exists()
    torch.load(path, weights_only=False)  # the file really carries code: the old loader ran it
    assert marker.read_text() == "code ran"


def test_a_checkpoint_of_the_old_format_asks_to_be_rebuilt(tmp_path):
    model, cfg, _ = _tiny_result()
    path = tmp_path / "old.pt"
    torch.save({"state_dict": model.state_dict(), "config": cfg.to_dict()}, path)
    with pytest.raises(InputError, match="not a checkpoint of this workflow's format.*delete it and rerun"):
        checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model)


# ----------------------------------------------------------------------------- names from users' files


def _photos(src: Path, dest: Path, n: int = 3) -> Path:
    dest.mkdir()
    for k in range(1, n + 1):
        shutil.copy(src / f"{k:02d}.jpg", dest / f"{k:02d}.jpg")
    return dest


@pytest.mark.parametrize("name", ["../x.jpg", "/etc/x.jpg", "sub/01.jpg", "..", "a\\b.jpg"])
@pytest.mark.slow  # the Lund photos
def test_metadata_csv_names_must_be_plain_file_names(lund, tmp_path, name):
    photos = _photos(lund, tmp_path / "photos")
    (photos / "metadata.csv").write_text(f"name,lat,lon\n01.jpg,55.7,13.19\n{name},55.7,13.19\n")
    with pytest.raises(InputError, match=re.escape(f"metadata.csv: image name {name!r} is refused")):
        image_audit.read_folder_metadata(photos)


@pytest.mark.slow  # the published data (flat_root)
def test_metadata_csv_naming_a_parent_file_stops_the_workflow(repo, flat_root, lund, tmp_path):
    photos = _photos(lund, tmp_path / "photos")
    (photos / "metadata.csv").write_text("name,lat,lon\n../x.jpg,55.7,13.19\n")
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(f"scene\tsource\tcity\tname\tpath\turl\tsubfolder\nmine\timages\tLund\tmine\t{photos}\t\t\n")
    args = ["--config", f"flatlandia_root={flat_root}", f"scenes={sheet}"]
    res = smk(repo, tmp_path, "--cores", "1", "results/mine/images/images.parquet", *args)
    assert res.returncode != 0
    errors = [line for line in res.stderr.splitlines() if line.startswith("ERROR:")]
    want = f"ERROR: {photos / 'metadata.csv'}: image name '../x.jpg' is refused"
    assert len(errors) == 1 and errors[0].startswith(want), res.stderr[-3000:]
    assert not (tmp_path / "results/mine/images").exists()


@pytest.mark.parametrize("labels", [["void", "../x"], ["void", 3], {"labels": [{"name": "a/b"}]}, [], "void"])
def test_labels_json_names_are_checked(tmp_path, labels):
    (tmp_path / "labels.json").write_text(json.dumps(labels))
    with pytest.raises(InputError, match="labels.json: "):
        segment.PrecomputedBackend(tmp_path)


def test_label_and_instance_folders_only_read_plain_names(tmp_path):
    (tmp_path / "x.jpg.png").write_bytes(b"")  # what '../x.jpg' would reach from tmp_path/sub
    (tmp_path / "sub").mkdir()
    with pytest.raises(InputError, match="image name '../x.jpg' is refused"):
        classify_points.load_class_maps(tmp_path / "sub", ["../x.jpg"])
    with pytest.raises(InputError, match="image name '../x.jpg' is refused"):
        classify_points.load_instance_maps(tmp_path / "sub", ["../x.jpg"])


# ----------------------------------------------------------------------------- model folders


def _folder_with_its_own_code(folder: Path, marker: Path) -> Path:
    """A model folder whose config asks transformers to import its evil.py (which leaves a marker)."""
    folder.mkdir()
    auto = {"AutoConfig": "evil.EvilConfig", "AutoModelForDepthEstimation": "evil.EvilModel"}
    (folder / "config.json").write_text(json.dumps({"model_type": "flatlandia-evil", "auto_map": auto}))
    (folder / "preprocessor_config.json").write_text(
        json.dumps({"image_processor_type": "EvilProcessor", "auto_map": {"AutoImageProcessor": "evil.EvilProcessor"}})
    )
    (folder / "evil.py").write_text(f"open({str(marker)!r}, 'w').write('code ran')\n")
    (folder / "model.safetensors").write_bytes(b"")
    return folder


def test_model_folder_code_is_never_run(tmp_path):
    marker = tmp_path / "marker"
    folder = _folder_with_its_own_code(tmp_path / "model", marker)
    with pytest.raises(InputError, match="without remote code.*custom code"):
        depth.MonocularDepth(folder)
    with pytest.raises(InputError, match="without remote code.*custom code"):
        segment.TransformersBackend(folder)
    assert not marker.exists()


def test_pickled_bin_weights_are_not_loaded(tmp_path):
    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "config.json").write_text("{}")
    (folder / "pytorch_model.bin").write_bytes(b"")
    with pytest.raises(InputError, match=r"no \*.safetensors weights"):
        depth.MonocularDepth(folder)


def test_model_folders_are_loaded_local_only_without_remote_code(tmp_path, monkeypatch):
    """The flags are stated in code, whatever transformers' defaults: spied on both loaders."""
    import transformers

    seen = []

    def spy(folder, **kwargs):
        seen.append(kwargs)
        raise OSError("stop here")

    monkeypatch.setattr(transformers.AutoImageProcessor, "from_pretrained", spy)
    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "config.json").write_text("{}")
    (folder / "model.safetensors").write_bytes(b"")
    with pytest.raises(InputError):
        depth.MonocularDepth(folder)
    monkeypatch.setattr(transformers.AutoImageProcessor, "from_pretrained", lambda folder, **kw: seen.append(kw))
    monkeypatch.setattr(transformers.AutoModelForDepthEstimation, "from_pretrained", spy)
    with pytest.raises(InputError):
        depth.MonocularDepth(folder)
    assert len(seen) == 3
    assert all(kw["local_files_only"] is True and kw["trust_remote_code"] is False for kw in seen)
    assert seen[2]["use_safetensors"] is True
