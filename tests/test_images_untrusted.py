"""A user's photo folder is untrusted input: what a probe of one found, each refused with one clear line.

1. entries that pass the audit and then crash or exhaust the run: a FIFO named ``x.jpg`` (opening
   it blocks), a 1 x 1 JPEG (crashed rule segment), a JPEG whose header declares 12000 x 12000
   pixels (9.3 GB in the offline segmentation): the audit drops them with a reason, reading the
   size from the header only; segment itself refuses an image too small to process;
2. a malformed ``metadata.csv``: one error naming the file, the line, the column and the value;
3. GPS positions without headings: the GPS alignment succeeds, the compass comparison is null.

Every hostile file is built here, in the test's temporary folder.
"""

from __future__ import annotations

import logging
import os
import runpy
import shutil
import threading
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import berlin_images, lund_images
from PIL import Image, ImageFile
from snakemake.iocontainers import Namedlist
from snakemake_runner import smk

from flatlandia import config, geo
from flatlandia.images import gps_alignment, image_audit, segment
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError

REPO = Path(__file__).resolve().parents[1]
IMAGES = config.section_defaults("images")


def _photos(dest: Path, n: int = 3) -> Path:
    """Copies of the first ``n`` Lund photos (1024 x 768, geotagged)."""
    dest.mkdir(exist_ok=True)
    for k in range(1, n + 1):
        shutil.copy(lund_images() / f"{k:02d}.jpg", dest / f"{k:02d}.jpg")
    return dest


def _jpeg_declaring(path: Path, width: int, height: int) -> Path:
    """A small JPEG whose frame header (SOF0) is patched to declare ``width`` x ``height`` pixels:
    a few kB on disk, gigabytes once decoded."""
    Image.new("RGB", (64, 48), (90, 120, 200)).save(path, quality=80)
    data = bytearray(path.read_bytes())
    i = 2
    while data[i + 1] != 0xC0:  # walk the marker segments up to the baseline frame header
        i += 2 + int.from_bytes(data[i + 2 : i + 4], "big")
    data[i + 5 : i + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    path.write_bytes(bytes(data))
    return path


def _named(**paths: str) -> Namedlist:
    """A job's input or output as Snakemake gives a rule script: a list of paths, each also by name."""
    return Namedlist(fromdict=paths)


def _run_script(name: str, snakemake: SimpleNamespace, capsys) -> list[str]:
    """Run a rule script as Snakemake would, with a stand-in ``snakemake`` object; its ERROR lines."""
    with pytest.raises(SystemExit):
        runpy.run_path(str(REPO / "workflow" / "scripts" / name), init_globals={"snakemake": snakemake})
    return [line for line in capsys.readouterr().err.splitlines() if line.startswith("ERROR:")]


# ----------------------------------------------------------------------------- 1. the images themselves


@pytest.mark.slow  # the published data
def test_every_lund_and_berlin_photo_is_within_the_size_limits():
    for folder in (lund_images(), berlin_images() / "images"):
        df = image_audit.read_folder_metadata(folder)
        assert df["problem"].isna().all(), df[["name", "problem"]]
        assert (df[["width", "height"]].min(axis=1) >= IMAGES["min_side_px"]).all()
        assert (df["width"] * df["height"] <= IMAGES["max_megapixels"] * 1e6).all()


@pytest.mark.slow  # the published data
def test_a_fifo_named_like_a_photo_is_dropped_without_being_opened(tmp_path):
    photos = _photos(tmp_path / "photos")
    fifo = photos / "x.jpg"
    os.mkfifo(fifo)
    (photos / "folder.jpg").mkdir()
    (photos / "dangling.jpg").symlink_to(tmp_path / "nowhere.jpg")
    (photos / "link.jpg").symlink_to(lund_images() / "04.jpg")  # a link to a regular file is fine
    result = {}
    worker = threading.Thread(
        target=lambda: result.update(df=image_audit.audit_table(photos, IMAGES["dedup_threshold"])), daemon=True
    )
    worker.start()
    worker.join(timeout=60)
    if worker.is_alive():  # the audit is blocked opening the FIFO: a writer releases it
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        pytest.fail("the audit blocked on a FIFO named x.jpg")
    df = result["df"].set_index("name")
    assert df.loc["x.jpg", "drop_reason"] == "not a regular file: a FIFO (named pipe)"
    assert df.loc["folder.jpg", "drop_reason"] == "not a regular file: a folder"
    assert df.loc["dangling.jpg", "drop_reason"].startswith("not readable")
    assert df.loc["link.jpg", "kept"] and df.loc[["01.jpg", "02.jpg", "03.jpg"], "kept"].all()
    with pytest.raises(InputError, match=r"x\.jpg: not a regular file"):
        with image_audit.open_image(fifo):
            pass


@pytest.mark.slow  # the published data (via _photos)
def test_tiny_images_are_dropped_and_segment_refuses_them(tmp_path, capsys):
    photos = _photos(tmp_path / "photos")
    Image.new("RGB", (1, 1), (200, 10, 10)).save(photos / "pixel.jpg")
    Image.new("RGB", (400, 20), (20, 200, 10)).save(photos / "strip.png")
    df = image_audit.audit_table(photos, IMAGES["dedup_threshold"]).set_index("name")
    reason = f"smaller than images.min_side_px ({IMAGES['min_side_px']} px on the shorter side)"
    assert df.loc["pixel.jpg", "drop_reason"] == reason and df.loc["strip.png", "drop_reason"] == reason
    assert df.loc[["01.jpg", "02.jpg", "03.jpg"], "kept"].all()
    assert (df.loc["pixel.jpg", "width"], df.loc["pixel.jpg", "height"]) == (1, 1)
    # nothing usable left: the existing one-line stop
    only = tmp_path / "only_tiny"
    only.mkdir()
    shutil.copy(photos / "pixel.jpg", only / "pixel.jpg")
    with pytest.raises(InputError, match=r"no image is left after the audit \(1 images; dropped: \{'smaller than"):
        image_audit.check_alignment_inputs(image_audit.audit_table(only, 0.02), only)
    # one that reaches rule segment anyway (an audit table of older settings): one ERROR line, no output
    with pytest.raises(InputError, match=r"pixel\.jpg: image of 1 x 1 px is too small to segment"):
        segment.OfflineBackend().labels(photos / "pixel.jpg")
    table = tmp_path / "images.parquet"
    files.write_parquet(pd.DataFrame({"name": ["01.jpg", "pixel.jpg"], "kept": [True, True]}), table)
    out = tmp_path / "segment"
    smk_ = SimpleNamespace(
        input=_named(table=str(table), images=str(photos)),
        output=_named(masks=str(out / "masks"), classes=str(out / "classes"), stats=str(out / "stats.parquet")),
        params={
            "segment.backend": "offline",
            "segment.weights": None,
            "segment.labels_dir": None,
            "segment.watermark_box": None,
            "segment.dilate_px": 0,
        },
        config={"device": "cpu"},
        log=[str(tmp_path / "segment.log")],
    )
    errors = _run_script("segment.py", smk_, capsys)
    assert errors == [
        f"ERROR: {photos / 'pixel.jpg'}: image of 1 x 1 px is too small to segment (the shorter side must be at "
        f"least {segment.MIN_SIDE_PX} px; the audit drops such images: images.min_side_px)"
    ]
    assert not out.exists() or not any(out.iterdir())  # no half-written masks


@pytest.mark.parametrize("size", [(16, 16), (32, 32), (64, 48), (100, 127), (63, 400)])
def test_people_detector_skips_images_smaller_than_its_window(size):
    """OpenCV's HOG detector corrupts memory on an image smaller than its 64 x 128 window (a 64 x 48
    image segfaulted): such images, which the audit keeps (min_side_px 32), find no one."""
    rgb = np.random.default_rng(0).integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
    assert segment.detect_people(rgb) == []
    assert segment.offline_labels(rgb).shape == rgb.shape[:2]


@pytest.mark.slow  # the published data (via _photos)
def test_huge_images_are_dropped_from_their_header_never_decoded(tmp_path, monkeypatch):
    photos = _photos(tmp_path / "photos")
    _jpeg_declaring(photos / "huge.jpg", 12000, 12000)  # the probe's 144 MP photo
    _jpeg_declaring(photos / "bomb.jpg", 30000, 30000)  # over PIL's own decompression-bomb limit
    decoded = []
    load = ImageFile.ImageFile.load

    def recording_load(im):
        decoded.append(im.size)
        return load(im)

    monkeypatch.setattr(ImageFile.ImageFile, "load", recording_load)
    t0 = time.perf_counter()
    df = image_audit.audit_table(photos, IMAGES["dedup_threshold"]).set_index("name")
    assert time.perf_counter() - t0 < 30
    reason = f"larger than images.max_megapixels ({IMAGES['max_megapixels']:g} MP); its pixels were not decoded"
    for name, side in (("huge.jpg", 12000), ("bomb.jpg", 30000)):
        assert df.loc[name, "drop_reason"] == reason  # not PIL's DecompressionBombError
        assert (df.loc[name, "width"], df.loc[name, "height"]) == (side, side)
    assert df.loc[["01.jpg", "02.jpg", "03.jpg"], "kept"].all()
    assert all(w * h <= IMAGES["max_megapixels"] * 1e6 for w, h in decoded) and (1024, 768) in decoded
    # a lower cap drops the Lund photos alike, still without decoding them
    decoded.clear()
    low = image_audit.audit_table(photos, 0.02, max_megapixels=0.5).set_index("name")
    assert low.loc["01.jpg", "drop_reason"].startswith("larger than images.max_megapixels (0.5 MP)")
    assert decoded == []


def test_the_audit_rule_stops_with_one_line_when_nothing_usable_is_left(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    Image.new("RGB", (1, 1)).save(photos / "pixel.jpg")
    _jpeg_declaring(photos / "huge.jpg", 12000, 12000)
    os.mkfifo(photos / "x.jpg")
    table = tmp_path / "images.parquet"
    smk_ = SimpleNamespace(
        input=_named(images=str(photos)),
        output=_named(table=str(table)),
        params={  # the config keys rule image_audit names
            "images.dedup_threshold": 0.02,
            "images.missing_gps": "keep",
            "images.align.mode": "gps",
            "images.min_side_px": IMAGES["min_side_px"],
            "images.max_megapixels": IMAGES["max_megapixels"],
        },
        config={"images": IMAGES},
        log=[str(tmp_path / "audit.log")],
    )
    errors = _run_script("image_audit.py", smk_, capsys)
    assert len(errors) == 1 and errors[0].startswith(f"ERROR: {photos}: no image is left after the audit (3 images")
    assert "smaller than images.min_side_px" in errors[0] and "larger than images.max_megapixels" in errors[0]
    assert "not a regular file" in errors[0]
    assert not table.exists()


# ----------------------------------------------------------------------------- 2. metadata.csv


@pytest.mark.parametrize(
    ("text", "want"),
    [
        ("name,lat,lon\n01.jpg,55.7,13.19\n02.jpg,north,13.19\n", "line 3, column lat: 'north' is not a number"),
        ("name,lat,lon,alt\n01.jpg,55.7,13.19,abc\n", "line 2, column alt: 'abc' is not a number"),
        (
            "name,lat,lon\n01.jpg,55.7,13.19\n\n01.jpg,55.8,13.2\n",
            "line 4, column name: image name '01.jpg' repeats line 2",
        ),
        ("name,lat,lon\n01.jpg,55.7,13.19\n02.jpg,55.7,13.19,9\n", "line 3: 4 fields, but the header (line 1) has 3"),
        ("name,lat,lon\n01.jpg,55.7\n", "line 2: 2 fields, but the header (line 1) has 3"),
        ("name,lat,lon\n01.jpg,95.0,13.19\n", "line 2, column lat: '95.0' is outside [-90, 90]"),
        ("name,lat,lon\n01.jpg,55.7,-181\n", "line 2, column lon: '-181' is outside [-180, 180]"),
        ("name,lat,lon,heading\n01.jpg,55.7,13.19,nan\n", "line 2, column heading: 'nan' is not a finite number"),
        ("name,lat,lon,heading\n01.jpg,55.7,13.19,inf\n", "line 2, column heading: 'inf' is not a finite number"),
        ("name,lat,lon,capture_time\n01.jpg,55.7,13.19,yesterday\n", "line 2, column capture_time: 'yesterday'"),
        ("name,lat,lon\nzzz.jpg,1,2\n", "names not in the folder: ['zzz.jpg'] (line 2, column name)"),
        (
            "name,lat,lng\n01.jpg,55.7,13.19\n",
            "line 1: unknown column 'lng' (did you mean 'lon'?); valid columns: name,",
        ),
        ("name,lat,lat\n01.jpg,55.7,55.7\n", "line 1: column 'lat' appears twice"),
        ("file,lat,lon\n01.jpg,55.7,13.19\n", "needs a 'name' column"),
        ('name,lat,lon\n01.jpg,"55.7\n', "line 2: not valid CSV (unexpected end of data)"),
    ],
)
@pytest.mark.slow  # the published data (via _photos)
def test_a_malformed_metadata_csv_is_one_error_naming_line_column_and_value(tmp_path, capsys, text, want):
    photos = _photos(tmp_path / "photos")
    csv = photos / "metadata.csv"
    csv.write_text(text)
    with pytest.raises(InputError) as err:
        image_audit.read_folder_metadata(photos)
    assert str(err.value).startswith(f"{csv}: ") and want in str(err.value), str(err.value)
    # through the rule: that one line, no traceback, no table
    table = tmp_path / "images.parquet"
    smk_ = SimpleNamespace(
        input=_named(images=str(photos)),
        output=_named(table=str(table)),
        params={  # the config keys rule image_audit names
            "images.dedup_threshold": 0.02,
            "images.missing_gps": "keep",
            "images.align.mode": "gps",
            "images.min_side_px": IMAGES["min_side_px"],
            "images.max_megapixels": IMAGES["max_megapixels"],
        },
        config={"images": IMAGES},
        log=[str(tmp_path / "audit.log")],
    )
    assert _run_script("image_audit.py", smk_, capsys) == [f"ERROR: {err.value}"]
    assert not table.exists()


@pytest.mark.slow  # the published data (via _photos)
def test_metadata_csv_bytes_that_are_not_text_are_one_error(tmp_path):
    photos = _photos(tmp_path / "photos")
    (photos / "metadata.csv").write_bytes(b"name,lat,lon\n01.jpg,55.7,13.19\n\xff\xfe\x00garbage\n")
    with pytest.raises(InputError, match=r"metadata\.csv: line \d: not UTF-8 text"):
        image_audit.read_folder_metadata(photos)
    (photos / "metadata.csv").unlink()
    os.mkfifo(photos / "metadata.csv")
    with pytest.raises(InputError, match=r"metadata\.csv: not a regular file: a FIFO"):
        image_audit.read_folder_metadata(photos)


@pytest.mark.slow  # the published data (via _photos)
def test_metadata_csv_values_are_typed_and_empty_cells_keep_the_exif(tmp_path):
    photos = _photos(tmp_path / "photos")
    exif = image_audit.read_folder_metadata(photos).set_index("name")
    (photos / "metadata.csv").write_text(
        "\ufeff name , lat , lon , alt , heading , capture_time \n"  # a BOM and spaces, as spreadsheets write
        "01.jpg, 55.5 , 13.1 , , 350 , 2020:01:02 03:04:05\n"  # a heading in range (450: refused)
        "02.jpg,,,12.5,,\n"
    )
    df = image_audit.read_folder_metadata(photos).set_index("name")
    assert df.loc["01.jpg", ["lat", "lon", "heading"]].tolist() == [55.5, 13.1, 350.0]
    assert df.loc["01.jpg", "alt"] == exif.loc["01.jpg", "alt"]  # empty: the EXIF altitude stays
    assert df.loc["01.jpg", "capture_time"] == "2020-01-02T03:04:05"
    assert (
        df.loc["02.jpg", ["lat", "lon", "heading"]].tolist() == exif.loc["02.jpg", ["lat", "lon", "heading"]].tolist()
    )
    assert df.loc["02.jpg", "alt"] == 12.5 and df.loc["02.jpg", "capture_time"] == exif.loc["02.jpg", "capture_time"]
    for col in ("lat", "lon", "alt", "heading"):
        assert df[col].dtype == float


# ----------------------------------------------------------------------------- 3. GPS without headings


def _upright(yaw: float) -> np.ndarray:
    """cam_from_world rotation of a level camera looking along yaw (world z up)."""
    f = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    d = np.array([0.0, 0.0, -1.0])
    return np.vstack([np.cross(d, f), d, f])


def _camera_table(n: int = 12, seed: int = 0) -> tuple[pd.DataFrame, dict]:
    """Cameras along a street with GPS (no heading, no altitude: a metadata.csv of name, lat, lon) and
    their SfM views (centre, R) in a frame scaled and shifted from the metric one."""
    rng = np.random.default_rng(seed)
    frame = geo.MetricFrame(lon0=13.195, lat0=55.698)
    s = np.linspace(0, 120, n)
    xy = np.column_stack([s * np.cos(0.4), s * np.sin(0.4)])
    yaws = 0.4 + rng.uniform(-0.5, 0.5, n)
    gps = frame.to_lonlat(xy + rng.normal(0, 2.0, (n, 2)))
    names = [f"{k:02d}.jpg" for k in range(n)]
    views = {
        name: SimpleNamespace(centre=0.05 * np.array([x, y, 1.6]) + [1.0, 2.0, 3.0], R=_upright(yaw))
        for name, (x, y), yaw in zip(names, xy, yaws)
    }
    cams = pd.DataFrame({"name": names, "lat": gps[:, 1], "lon": gps[:, 0], "alt": np.nan, "heading": np.nan})
    return cams, views


def test_gps_alignment_without_headings_has_no_compass_comparison(tmp_path, caplog):
    cams, views = _camera_table()
    align = config.section_defaults("images.align")
    log = logging.getLogger("test_gps_no_heading")
    caplog.set_level(logging.INFO, logger=log.name)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # numpy's "All-NaN slice" came before the crash
        used, out = gps_alignment.align_camera_table(cams, views, align, seed=0, source="cameras.parquet", log=log)
    assert len(used) == 12 and out["inliers"] == 12 and out["metres_per_sfm_unit"] == pytest.approx(20.0, rel=0.05)
    assert out["compass_cameras"] == 0
    assert out["compass_median_diff_deg"] is None and out["compass_within_30deg"] is None
    assert "no compass headings were given" in caplog.text
    files.write_json(out, tmp_path / "gps_alignment.json")  # JSON-compliant: nulls, no NaN
    assert files.read_json(tmp_path / "gps_alignment.json")["compass_median_diff_deg"] is None
    # headings for some cameras only: compared over those
    cams.loc[:4, "heading"] = 90.0 - np.degrees([np.arctan2(*views[n].R[2, 1::-1]) for n in cams["name"][:5]])
    _, some = gps_alignment.align_camera_table(cams, views, dict(align, use_heading=True), 0, "cameras.parquet", log)
    assert some["compass_cameras"] == 5 and some["compass_median_diff_deg"] < 1.0 and not some["heading_used"]
    assert "only 5 of 12 cameras give a heading" in caplog.text


@pytest.mark.slow
def test_lund_placed_by_a_metadata_csv_without_headings_builds_its_map(repo, flat_root, lund, tmp_path):
    """Lund's photos stripped of EXIF, placed by a metadata.csv of the documented columns name, lat,
    lon only: the workflow builds the scene's map (`maps`), its GPS alignment with the compass
    comparison null and said so."""
    photos = tmp_path / "photos"
    photos.mkdir()
    rows = ["name,lat,lon"]
    for p in sorted(lund.glob("*.jpg"))[:12]:  # a dozen: enough for SfM and a GPS alignment
        rec = image_audit.read_exif_metadata(p)
        rows.append(f"{p.name},{rec['lat']},{rec['lon']}")
        with Image.open(p) as im:
            im.convert("RGB").save(photos / p.name, quality=90)  # no EXIF: no GPS, no heading
    (photos / "metadata.csv").write_text("\n".join(rows) + "\n")
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(f"scene\tsource\tcity\tname\tpath\turl\tsubfolder\nmine\timages\tLund\tmine\t{photos}\t\t\n")
    target = "results/mine/sfm/gps_alignment.json"
    res = smk(repo, tmp_path, "--cores", "2", "maps", "--config", f"flatlandia_root={flat_root}", f"scenes={sheet}")
    assert res.returncode == 0, res.stderr[-3000:]
    for built in ("maps/reference_map.parquet", "maps/reference_map.geojson", "queries/queries.parquet"):
        assert (tmp_path / "results/mine" / built).exists(), built
    al = files.read_json(tmp_path / target)
    assert al["compass_cameras"] == 0 and al["compass_median_diff_deg"] is None
    assert al["inliers"] >= 9 and al["inlier_median_residual_m"] < 10
    assert "no compass headings were given" in (tmp_path / "logs/gps_alignment/mine.log").read_text()
