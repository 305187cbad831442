"""One photo in, a pose out (`flatlandia localize --image`, flatlandia.images.photo_query): the
photo's query made by the learned backends for real, with the tiny random models of
tests/test_learned_backends.py (nothing downloaded), localized on the tiny scene's map as `--query`
is; the geometry of the bearings and depths on a precomputed label image; every refusal one ERROR
line (the command run as a user runs it, for the default backends, a missing checkpoint and a file
that is no photo)."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import ExifTags, Image
from test_learned_backends import VISTAS_V12, save_depth_anything, save_mask2former
from test_localize import query_file, run_cli, tiny_map, tiny_scene  # noqa: F401

from flatlandia import localize
from flatlandia.classes import CLASSES
from flatlandia.images import photo_query, segment
from flatlandia.plumbing.errors import InputError

#: the classes the tiny segmenter's four queries vote for (its class head reads one hidden unit each)
VOTED = ["Pole", "Street Light", "Trash Can", "Bench"]
EXIF_FOCAL_35MM = 28


def save_object_segmenter(folder: Path) -> Path:
    """The tiny random Mask2Former with Vistas classes, its four queries voting for the object classes
    of :data:`VOTED` and its masks sharpened (their embedding x 100), so that a photo of coloured
    stripes comes out as several regions of object classes instead of one class everywhere."""
    from transformers import Mask2FormerForUniversalSegmentation

    save_mask2former(folder / "random", VISTAS_V12)
    model = Mask2FormerForUniversalSegmentation.from_pretrained(folder / "random").eval()
    with torch.no_grad():
        model.class_predictor.weight.zero_()
        model.class_predictor.bias.fill_(-10.0)
        for k, name in enumerate(VOTED):
            model.class_predictor.weight[VISTAS_V12.index(name), k] = 10.0
        params = dict(model.named_parameters())
        params["model.transformer_module.decoder.mask_predictor.mask_embedder.2.0.weight"].mul_(100.0)
    model.save_pretrained(folder / "objects")
    shutil.copy(folder / "random" / "preprocessor_config.json", folder / "objects")
    return folder / "objects"


def save_photo(path: Path, focal_35mm: int | None = EXIF_FOCAL_35MM, orientation: int | None = None) -> Path:
    """A 160 x 120 photo of eight coloured vertical stripes, with its EXIF camera."""
    rng = np.random.default_rng(0)
    img = np.zeros((120, 160, 3), np.uint8)
    for i in range(8):
        img[:, i * 20 : (i + 1) * 20] = rng.integers(0, 255, 3)
    exif = Image.Exif()
    if focal_35mm is not None:
        exif.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.FocalLengthIn35mmFilm] = focal_35mm
    if orientation is not None:
        exif[ExifTags.Base.Orientation] = orientation
    Image.fromarray(img).save(path, exif=exif)
    return path


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> dict:
    """The config of the learned backends: the tiny segmenter and a tiny random Depth-Anything."""
    tmp = tmp_path_factory.mktemp("photo_models")
    return {
        "segment": {"backend": "transformers", "weights": str(save_object_segmenter(tmp / "m2f"))},
        "images": {"depth": {"backend": "transformers", "weights": str(save_depth_anything(tmp / "depth"))}},
    }


@pytest.fixture(scope="module")
def flat_depth(tmp_path_factory) -> str:
    """A tiny Depth-Anything predicting 0.5 everywhere: every pixel at depth 2 (inverse depth)."""
    return str(save_depth_anything(tmp_path_factory.mktemp("flat_depth"), constant=0.5))


def precomputed(folder: Path, labels: np.ndarray, names: list[str], depth_weights: str, **photo) -> dict:
    """The settings of a precomputed label image for the photo ``street.jpg`` (Vistas ``names``)."""
    folder.mkdir()
    Image.fromarray(labels).save(folder / "street.png")
    (folder / "labels.json").write_text(json.dumps(names))
    return {
        "segment": {"backend": "precomputed", "labels_dir": str(folder)},
        "images": {"depth": {"backend": "transformers", "weights": depth_weights}, "photo": photo},
    }


def write_config(path: Path, settings: dict) -> Path:
    path.write_text(json.dumps(settings))  # JSON is YAML, and a config file may be either
    return path


def command(*args) -> subprocess.CompletedProcess:
    """`flatlandia localize ...` as a user runs it."""
    exe = shutil.which("flatlandia") or str(Path(sys.executable).with_name("flatlandia"))
    return subprocess.run([exe, "localize", *map(str, args)], capture_output=True, text=True)


def assert_one_error_line(done: subprocess.CompletedProcess, *says: str) -> str:
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and done.stdout == "" and "Traceback" not in done.stderr, done.stderr
    assert len(lines) == 1 and lines[0].startswith("ERROR: "), done.stderr
    for s in says:
        assert s in lines[0], lines[0]
    return lines[0]


# ---------------------------------------------------------------- a photo in, a pose out
def test_a_photo_becomes_a_query_and_its_answer(models, tiny_scene, tiny_map, tmp_path, capsys):  # noqa: F811
    """The photo's objects come from the segmenter (its voted classes, boxes in the photo), their
    ranges from the depth model; the answer is --query's (same keys, the same statuses) plus
    ``photo``, and --plot draws it."""
    photo = save_photo(tmp_path / "street.jpg")
    config = write_config(tmp_path / "my.yaml", models)
    status, text = run_cli(
        capsys,
        *("--map", tiny_map, "--image", photo, "--configfile", config),
        *("--out", tmp_path / "answer.json", "--plot", tmp_path / "answer.png"),
    )
    answer = json.loads(text)
    assert status == 0 and json.loads((tmp_path / "answer.json").read_text()) == answer
    assert (tmp_path / "answer.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert answer["map_type"] == "depth" and answer["id"] == "street.jpg"
    assert answer["status"] in {"ok", "ambiguous", "no pose"} and 0.0 <= answer["probability"] <= 1.0
    # the answer --query gives, key for key, plus where the query came from
    _, _, q = tiny_scene
    status, text = run_cli(
        capsys, "--map", tiny_map, "--query", query_file(tmp_path / "q.json", q.iloc[0]), "--map-type", "depth"
    )
    assert set(answer) == set(json.loads(text)) | {"photo"}
    made = answer["photo"]
    assert made["segment_backend"] == made["depth_backend"] == "transformers"
    assert made["focal_35mm"] == EXIF_FOCAL_35MM and made["focal_from"] == "EXIF FocalLengthIn35mmFilm"
    assert made["focal_px"] == pytest.approx(EXIF_FOCAL_35MM * math.hypot(160, 120) / math.hypot(36, 24))
    objects = made["objects"]
    voted = {segment.VISTAS_V12_READABLE[n] for n in VOTED}  # each a Flatlandia class by the same name
    assert len(objects) >= 3 and {o["class"] for o in objects} <= voted
    for o in objects:
        x0, y0, x1, y1 = o["box"]
        assert 0 <= x0 < x1 <= 160 and 0 <= y0 < y1 <= 120 and o["pixels"] <= (x1 - x0) * (y1 - y0)
        assert o["x"] > 0  # in front of the camera
    ranges = np.hypot([o["x"] for o in objects], [o["y"] for o in objects])
    assert np.median(ranges) == pytest.approx(1.0)  # a depth local map, normalised as the branch's
    for m in answer["matches"]:
        assert m["class"] == objects[m["query_object"]]["class"]
    # the Python side: the same query
    query, record = localize.read_photo(photo, models)
    assert record == made and query.labels == [o["class"] for o in objects]
    assert np.array_equal(query.xy, [[o["x"], o["y"]] for o in objects])


def test_bearings_and_ranges_follow_the_pixels(flat_depth, tmp_path):
    """On a precomputed label image of three objects and a depth model predicting one depth
    everywhere: each object's bearing is its box centre's ray (left of the centre: left, +y), its
    forward distance the same for all; objects in the watermark strip, moving things and specks
    are no objects."""
    h, w = 120, 160
    labels = np.zeros((h, w), np.uint8)  # 0: void
    names = ["void", "object--support--pole", "object--street-light", "object--trash-can", "human--person"]
    labels[10:60, 10:30] = 1  # left
    labels[20:50, 70:90] = 2  # centre
    labels[30:80, 130:150] = 3  # right
    labels[5:7, 50:52] = 3  # a speck of 4 px: left out at min_object_share 0.001 (20 px)
    labels[60:100, 40:60] = 4  # a person: masked, no object
    labels[116:120, 0:160] = 1  # in the watermark strip (the bottom 5 %)
    settings = precomputed(tmp_path / "labels", labels, names, flat_depth, min_object_share=0.001)
    made = photo_query.photo_query(save_photo(tmp_path / "street.jpg", focal_35mm=None), settings)
    assert [CLASSES[c] for c in made.cls] == names[1:4]
    assert made.left_out == {"specks": 1, "no_depth": 0, "beyond_max_objects": 0}
    assert made.focal_from == "images.photo.focal_35mm"
    f = made.focal_px
    for (x, y), (x0, _, x1, _) in zip(made.xy, made.boxes):
        assert math.atan2(y, x) == pytest.approx(math.atan2(w / 2 - (x0 + x1) / 2, f))
    assert np.allclose(made.xy[:, 0], made.xy[0, 0])  # one depth: the same distance ahead
    assert made.xy[0, 1] > 0 > made.xy[2, 1]


def test_the_largest_objects_are_kept_within_the_query_bound(flat_depth, tmp_path):
    """More regions than a query may hold (MAX_QUERY_OBJECTS, 100): the largest are kept, the others
    counted."""
    labels = np.zeros((120, 160), np.uint8)
    for k in range(120):  # 30 of 3 x 3 px, 90 of 2 x 2 px, 8 px apart
        r, c = 8 * (k // 15) + 2, 8 * (k % 15) + 2
        side = 3 if k % 4 == 0 else 2
        labels[r : r + side, c : c + side] = 1
    settings = precomputed(tmp_path / "labels", labels, ["void", "object--manhole"], flat_depth)
    made = photo_query.photo_query(save_photo(tmp_path / "street.jpg"), settings)
    assert len(made.cls) == 100 and made.left_out["beyond_max_objects"] == 20
    assert (made.pixels == 9).sum() == 30 and (made.pixels == 4).sum() == 70
    assert np.median(np.hypot(*made.xy.T)) == pytest.approx(1.0)


def test_a_turned_photo_is_turned_upright_first(tmp_path):
    """EXIF Orientation 6 (a phone held upright, its pixels stored sideways): the bearings run along
    the upright photo's columns."""
    path = save_photo(tmp_path / "turned.jpg", orientation=6)
    assert photo_query.orientation_of(path) == 6
    with Image.open(path) as im:
        assert photo_query.upright(im, 6).size == (120, 160)
    assert photo_query.orientation_of(save_photo(tmp_path / "plain.jpg")) == 1


def test_an_impossible_exif_focal_length_falls_back_to_the_default():
    assert photo_query.focal_length(None, 26.0) == (26.0, "images.photo.focal_35mm")
    assert photo_query.focal_length(0.0, 26.0)[0] == 26.0  # EXIF's "unknown"
    assert photo_query.focal_length(1e9, 26.0)[0] == 26.0
    assert photo_query.focal_length(35.0, 26.0) == (35.0, "EXIF FocalLengthIn35mmFilm")


# ---------------------------------------------------------------- one ERROR line
def test_the_default_backends_are_one_error_line_naming_backends_md(tiny_map, tmp_path):  # noqa: F811
    line = assert_one_error_line(
        command("--map", tiny_map, "--image", save_photo(tmp_path / "p.jpg")),
        "segment.backend",
        "offline labels no object class",
        "docs/backends.md",
    )
    assert "no object can come out of it" in line


def test_a_missing_checkpoint_is_one_error_line_naming_it(models, tiny_map, tmp_path):  # noqa: F811
    photo = save_photo(tmp_path / "p.jpg")
    missing = tmp_path / "no-such-model"
    config = write_config(
        tmp_path / "c.yaml", {**models, "segment": {"backend": "transformers", "weights": str(missing)}}
    )
    assert_one_error_line(
        command("--map", tiny_map, "--image", photo, "--configfile", config), str(missing), "docs/backends.md"
    )


def test_a_file_that_is_no_photo_is_one_error_line(models, tiny_map, tmp_path):  # noqa: F811
    text = tmp_path / "notes.jpg"
    text.write_text("not a photo\n")
    config = write_config(tmp_path / "c.yaml", models)
    assert_one_error_line(
        command("--map", tiny_map, "--image", text, "--configfile", config), str(text), "unreadable image"
    )


def test_other_refusals_are_one_error_line(models, tiny_map, tmp_path, capsys):  # noqa: F811
    photo = save_photo(tmp_path / "p.jpg")
    depth_missing = {**models, "images": {"depth": {"backend": "transformers", "weights": str(tmp_path / "nod")}}}
    cases = {
        "sparse depth": ({**models, "images": {"depth": {"backend": "sparse"}}}, [], ["sparse", "docs/backends.md"]),
        "depth checkpoint missing": (depth_missing, [], [str(tmp_path / "nod"), "docs/backends.md"]),
        "unknown key": ({**models, "segmnet": {}}, [], ["unknown key", "segmnet", "c.yaml"]),
        "gt map type": (models, ["--map-type", "gt"], ["--map-type", "depth"]),
        "and a query": (models, ["--query", tmp_path / "q.json"], ["--image", "one"]),
        "too few objects": (
            {**models, "images": {**models["images"], "min_objects": 100}},
            [],
            ["p.jpg", "objects found", "images.min_objects"],
        ),
    }
    for name, (settings, extra, says) in cases.items():
        config = write_config(tmp_path / "c.yaml", settings)
        status, err = run_cli(capsys, "--map", tiny_map, "--image", photo, "--configfile", config, *extra)
        lines = err.strip().splitlines()
        assert status == 1 and len(lines) == 1 and lines[0].startswith("ERROR: "), (name, err)
        for s in says:
            assert s in lines[0], (name, lines[0])
    status, err = run_cli(capsys, "--map", tiny_map, "--query", tmp_path / "q.json", "--configfile", config)
    assert status == 1 and "--configfile" in err and "--image" in err
    with pytest.raises(InputError, match="offline labels no object class"):
        localize.read_photo(photo)
