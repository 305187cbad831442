"""Images branch, front half: metadata, audit, dedup, segmentation backends and masks."""

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from flatlandia.images import image_audit, segment
from flatlandia.plumbing.errors import InputError


@pytest.mark.slow  # the Lund photos
def test_exif_metadata_of_a_real_mapillary_image(lund):
    rec = image_audit.read_exif_metadata(lund / "01.jpg")
    assert (rec["width"], rec["height"]) == (1024, 768)
    assert rec["lat"] == pytest.approx(55.698167, abs=1e-5) and rec["lon"] == pytest.approx(13.195389, abs=1e-5)
    assert rec["alt"] == pytest.approx(37.0)
    assert rec["heading"] == pytest.approx(179.2156)  # from MAPCompassHeading.TrueHeading
    assert rec["capture_time"].startswith("2014-06-07T10:24:05")


@pytest.mark.slow  # the Lund photos
def test_audit_table_of_lund_keeps_distinct_images(lund):
    df = image_audit.audit_table(lund, dedup_threshold=0.02)
    assert len(df) == 29 and df["kept"].all()
    assert df["capture_time"].is_monotonic_increasing


@pytest.mark.slow  # the Lund photos
def test_near_duplicate_missing_gps_and_broken_files(lund, tmp_path):
    for n in ("01.jpg", "02.jpg"):
        shutil.copy(lund / n, tmp_path / n)
    shutil.copy(lund / "02.jpg", tmp_path / "02b.jpg")  # the same picture again
    Image.new("RGB", (64, 48), (120, 120, 120)).save(tmp_path / "nogps.jpg")
    data = (lund / "03.jpg").read_bytes()
    (tmp_path / "truncated.jpg").write_bytes(data[: len(data) // 3])
    (tmp_path / "garbage.jpg").write_bytes(b"not a jpeg at all")
    df = image_audit.audit_table(tmp_path, dedup_threshold=0.02).set_index("name")
    assert df.loc["02b.jpg", "drop_reason"] == "near-duplicate of previous image"
    assert df.loc["nogps.jpg", "kept"] and not df.loc["nogps.jpg", "has_gps"]  # kept for SfM, not for GPS
    assert df.loc["truncated.jpg", "drop_reason"].startswith("unreadable image")
    assert df.loc["garbage.jpg", "drop_reason"].startswith("unreadable image")
    assert df.loc["01.jpg", "kept"] and df.loc["02.jpg", "kept"] and df.loc["01.jpg", "has_gps"]
    dropped = image_audit.audit_table(tmp_path, 0.02, missing_gps="drop").set_index("name")
    assert dropped.loc["nogps.jpg", "drop_reason"] == "no GPS position"
    with pytest.raises(InputError, match=r"images without a GPS position: \['nogps.jpg'\]"):
        image_audit.audit_table(tmp_path, 0.02, missing_gps="stop")


def test_metadata_csv_overrides_and_is_checked(tmp_path):
    Image.new("RGB", (64, 48), (10, 200, 30)).save(tmp_path / "a.jpg")
    (tmp_path / "metadata.csv").write_text("name,lat,lon,heading\na.jpg,55.7,13.19,90\n")
    df = image_audit.read_folder_metadata(tmp_path)
    assert df.loc[0, "lat"] == 55.7 and df.loc[0, "heading"] == 90
    (tmp_path / "metadata.csv").write_text("name,lat,lon\nzzz.jpg,1,2\n")
    with pytest.raises(InputError, match="metadata.csv: names not in the folder"):
        image_audit.read_folder_metadata(tmp_path)


def test_empty_or_missing_folder_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="no images"):
        image_audit.list_images(tmp_path)
    with pytest.raises(InputError, match="does not exist"):
        image_audit.list_images(tmp_path / "nope")


@pytest.mark.slow  # the Lund photos
def test_offline_people_detector_finds_the_pedestrian_of_lund_01(lund):
    rgb = np.asarray(Image.open(lund / "01.jpg").convert("RGB"))
    boxes = segment.detect_people(rgb)
    assert len(boxes) == 1
    x, y, w, h = boxes[0]
    assert 380 < x + w / 2 < 480 and h > 100  # the walker in the middle of the street
    assert segment.detect_people(np.asarray(Image.open(lund / "10.jpg").convert("RGB"))) == []


@pytest.mark.slow  # the Lund photos
def test_offline_backend_masks_sky_but_claims_no_objects(lund):
    ids, names = segment.make_backend("offline").labels(lund / "15.jpg")
    mask, cls, shares = segment.mask_and_classes(ids, names, [0.0, 0.95, 1.0, 1.0])
    assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
    assert 0.15 < shares["nature--sky"] < 0.6  # the top of this street view is sky
    assert mask[:20].mean() < 128 and mask[400:700].mean() > 128  # top mostly ignored, street kept
    assert (mask[-10:] == 0).all()  # watermark strip
    assert (cls == segment.NOT_AN_OBJECT).all()


def test_precomputed_backend_maps_vistas_names_to_flatlandia_classes(tmp_path):
    names = [
        "void",
        "human--person",
        "object--street-light",
        "object--support--pole",
        "nature--sky",
        "marking--discrete--crosswalk-zebra",
    ]
    (tmp_path / "labels.json").write_text(json.dumps({"labels": [{"name": n} for n in names]}))
    ids = np.zeros((20, 30), dtype=np.uint8)
    ids[:5] = 4
    ids[5:10, :10] = 1
    ids[10:, :10] = 2
    ids[10:, 10:20] = 3
    ids[10:, 20:] = 5
    Image.fromarray(ids).save(tmp_path / "img.png")
    backend = segment.make_backend("precomputed", labels_dir=str(tmp_path))
    got, got_names = backend.labels(Path("img.jpg"))
    mask, cls, _ = segment.mask_and_classes(got, got_names, None)
    assert (mask[:10, :10] == 0).all() and (mask[:5] == 0).all()  # sky and person ignored
    assert cls[15, 5] == segment.CLASSES.index("object--street-light")
    assert cls[15, 15] == segment.CLASSES.index("object--support--pole")
    assert cls[15, 25] == segment.CLASSES.index("crosswalk-zebra")
    with pytest.raises(InputError, match="no precomputed label image"):
        backend.labels(Path("other.jpg"))


def test_every_flatlandia_class_has_a_vistas_name():
    assert (segment.flatlandia_class_of(segment.CLASSES) == np.arange(42)).all()


def test_backends_fail_clearly_without_their_inputs(tmp_path):
    with pytest.raises(InputError, match="needs a local checkpoint"):
        segment.make_backend("transformers")
    with pytest.raises(InputError, match="no config.json"):
        segment.make_backend("transformers", weights=str(tmp_path))
    with pytest.raises(InputError, match="labels.json"):
        segment.make_backend("precomputed", labels_dir=str(tmp_path))
    with pytest.raises(InputError, match="unknown backend"):
        segment.make_backend("magic")


def test_the_classes_a_backend_labels_are_told_before_any_job(tmp_path):
    """What the run's start reads of a backend (segment.labelled_classes): no model is loaded, no
    image read; a file that cannot be read yet is "unknown" (None), left to rule segment to refuse."""
    assert segment.labelled_classes("offline") == []
    labels, model = tmp_path / "labels", tmp_path / "model"
    labels.mkdir()
    model.mkdir()
    assert segment.labelled_classes("precomputed", labels_dir=str(labels)) is None  # no labels.json yet
    (labels / "labels.json").write_text(json.dumps(["void", "nature--sky", "human--person"]))
    assert segment.labelled_classes("precomputed", labels_dir=str(labels)) == []
    (labels / "labels.json").write_text(json.dumps(["void", "object--street-light", "nature--vegetation"]))
    assert segment.labelled_classes("precomputed", labels_dir=str(labels)) == ["object--street-light"]
    assert segment.labelled_classes("transformers", weights=str(model)) is None
    (model / "config.json").write_text(json.dumps({"id2label": {"0": "Sky", "1": "Street Light", "2": "Pole"}}))
    assert segment.labelled_classes("transformers", weights=str(model)) == [
        "object--street-light",
        "object--support--pole",
    ]
    (model / "config.json").write_text(json.dumps({"id2label": {"0": "Sky", "1": "Person"}}))
    assert segment.labelled_classes("transformers", weights=str(model)) == []


def test_a_backend_without_object_classes_is_said_before_sfm(tmp_path):
    """With the default segmentation an images scene ended, after minutes of SfM, with 0 objects and 0
    queries, said only by the run's summary (issue 45): the run's start says it in one line, naming the
    backend and docs/backends.md, when it is about to build an images scene's model."""
    offline = {"backend": "offline", "weights": None, "labels_dir": None}
    line = segment.empty_map_warning(offline, ["mine"], {"image_audit", "segment", "sfm", "objects"})
    assert line == (
        "WARNING: segment.backend offline labels no object classes: images scene(s) mine will get SfM and masks "
        "but an empty map (0 objects, 0 queries); for objects give per-pixel Vistas labels (segment.backend "
        "precomputed or transformers): docs/backends.md"
    )
    assert "\n" not in line
    assert segment.empty_map_warning(offline, ["mine"], None) == line  # the plan unknown: said
    assert segment.empty_map_warning(offline, [], {"sfm"}) is None  # no images scene selected
    assert segment.empty_map_warning(offline, ["mine"], {"fine_eval", "objects"}) is None  # its SfM is built
    (tmp_path / "labels.json").write_text(json.dumps(["void", "nature--sky"]))
    precomputed = {"backend": "precomputed", "weights": None, "labels_dir": str(tmp_path)}
    line = segment.empty_map_warning(precomputed, ["a", "b"], {"sfm"})
    assert f"segment.backend precomputed (no name in {tmp_path / 'labels.json'} is an object class)" in line
    assert "images scene(s) a, b will get" in line
    (tmp_path / "labels.json").write_text(json.dumps(["void", "object--street-light"]))
    assert segment.empty_map_warning(precomputed, ["a"], {"sfm"}) is None
    transformers = {"backend": "transformers", "weights": str(tmp_path / "absent"), "labels_dir": None}
    assert segment.empty_map_warning(transformers, ["a"], {"sfm"}) is None  # rule segment says what is missing


def test_ignore_iou_on_hand_made_masks():
    a = np.full((4, 4), 255, np.uint8)
    b = a.copy()
    a[:2, :2] = 0  # 4 ignored pixels
    b[:2, :] = 0  # 8 ignored pixels, 4 shared
    assert segment.ignore_iou(a, b) == pytest.approx(0.5)
    assert np.isnan(segment.ignore_iou(np.full((2, 2), 255), np.full((2, 2), 255)))


@pytest.mark.slow
def test_offline_masks_overlap_the_published_berlin_masks(berlin):
    """Published masks (OpenSfM's data/berlin/masks) outline the crowd; ours (HOG boxes + colour rules)
    must overlap them."""
    backend = segment.make_backend("offline")
    for name in ("01.jpg", "02.jpg"):
        ref = np.asarray(Image.open(berlin / "masks" / f"{name}.png").convert("L"))
        ids, names = backend.labels(berlin / "images" / name)
        ours, _, _ = segment.mask_and_classes(ids, names, None)
        assert segment.ignore_iou(ours, ref) > 0.1  # measured 0.17-0.18


def _audit_rows(lonlat, kept=True):
    return pd.DataFrame(
        {
            "name": [f"{k:02d}.jpg" for k in range(len(lonlat))],
            "lon": [p[0] for p in lonlat],
            "lat": [p[1] for p in lonlat],
            "has_gps": [p[0] is not None for p in lonlat],
            "kept": kept,
            "drop_reason": "" if kept else "no GPS position",
        }
    )


def test_alignment_inputs_are_checked_before_sfm(tmp_path):
    spread = [(13.190, 55.700), (13.191, 55.700), (13.190, 55.701)]  # about 60-110 m apart
    image_audit.check_alignment_inputs(_audit_rows(spread), tmp_path)
    with pytest.raises(InputError, match="2 of the 3 kept images carry a GPS position.*metadata.csv"):
        image_audit.check_alignment_inputs(_audit_rows([*spread[:2], (None, None)]), tmp_path)
    with pytest.raises(InputError, match="spread over 0 m"):  # every photo at one spot
        image_audit.check_alignment_inputs(_audit_rows([spread[0]] * 4), tmp_path)
    with pytest.raises(InputError, match="no image is left after the audit"):
        image_audit.check_alignment_inputs(_audit_rows([(None, None)] * 3, kept=False), tmp_path)
