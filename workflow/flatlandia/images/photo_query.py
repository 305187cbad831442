"""One photo as a query (``flatlandia localize --image``): its objects from the configured
segmentation (one per connected region of an object class), their ranges from the configured
monocular depth model, their bearings from the photo's camera.

Why apart from the images branch's queries (:mod:`flatlandia.images.image_queries`): there an
image's objects are the SfM model's, projected into it, and their depths SfM's; one photo has no
model, so its objects are the regions its segmentation labels and its depths the depth model's, up
to scale: a depth local map (normalised to a median object range of 1, as the branch's), whose scale
the solver finds. What it shares with the branch is the branch's own code: the photo's door
(:func:`image_audit.read_exif_metadata`, :func:`image_audit.size_problem`, :func:`segment.read_rgb`),
the backends (:func:`segment.make_backend`, :class:`depth.MonocularDepth`), the class map
(:func:`segment.mask_and_classes`: the same watermark and moving things left out) and a detection's
lift (:func:`depth.unproject_centre`: its box centre at its median depth, as :func:`depth.lift_box`;
here the median of the region's own pixels, which one photo's segmentation gives exactly).

The camera: a level pinhole centred on the photo, its focal length from the EXIF
FocalLengthIn35mmFilm (a 35 mm equivalent is defined on the frame's diagonal) or, without one,
``images.photo.focal_35mm``. A photo its EXIF Orientation turns (a phone held upright) is turned
upright first, so that its columns run along the horizon and give the bearings.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flatlandia import config
from flatlandia.classes import CLASSES
from flatlandia.data.localmaps import normalise_depth_map
from flatlandia.images import depth, image_audit, segment
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

#: where the error lines send a user without a usable backend
BACKENDS_DOC = "docs/backends.md"
#: the diagonal of a 36 x 24 mm frame, on which a 35 mm-equivalent focal length is defined (CIPA DC-008)
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: EXIF Orientation -> the PIL transpose that turns the pixels upright (PIL.ImageOps.exif_transpose's)
UPRIGHT = {
    2: "FLIP_LEFT_RIGHT",
    3: "ROTATE_180",
    4: "FLIP_TOP_BOTTOM",
    5: "TRANSPOSE",
    6: "ROTATE_270",
    7: "TRANSVERSE",
    8: "ROTATE_90",
}
#: the EXIF tag of the orientation (main IFD)
EXIF_ORIENTATION = 0x0112


@dataclass
class PhotoQuery:
    """A photo's query: its objects' local map (``xy``: x forward, y left, a median range of 1),
    classes, boxes (x0, y0, x1, y1 in the upright photo's pixels) and pixel counts, and how it was made."""

    path: str
    width: int
    height: int
    orientation: int
    focal_px: float
    focal_35mm: float
    focal_from: str
    segment_backend: str
    xy: np.ndarray
    cls: np.ndarray
    boxes: np.ndarray
    pixels: np.ndarray
    left_out: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return Path(self.path).name

    def record(self) -> dict:
        """The JSON record of where the query came from (the answer's ``photo``)."""
        return {
            "image": self.path,
            "width": self.width,
            "height": self.height,
            "orientation": self.orientation,
            "focal_px": self.focal_px,
            "focal_35mm": self.focal_35mm,
            "focal_from": self.focal_from,
            "segment_backend": self.segment_backend,
            "depth_backend": "transformers",
            "objects": [
                {
                    "class": CLASSES[int(c)],
                    "x": float(p[0]),
                    "y": float(p[1]),
                    "box": [int(v) for v in b],
                    "pixels": int(n),
                }
                for c, p, b, n in zip(self.cls, self.xy, self.boxes, self.pixels)
            ],
            "left_out": dict(self.left_out),
        }


def resolved(settings: dict | None) -> dict:
    """The whole config of ``settings`` (any of its sections, e.g. ``segment`` and ``images``) over
    the schema's defaults, checked as the workflow checks it (:func:`flatlandia.config.resolve`)."""
    try:
        return config.resolve(settings or {})
    except config.ConfigError as e:
        raise InputError("config", str(e)) from None


def check_backends(cfg: dict) -> None:
    """Refuse, before any model loads, the settings no photo can give a query with: a segmentation
    that labels no object class (the default ``offline``, a ``labels.json`` or checkpoint without
    one), and the ``sparse`` depth, which needs an SfM model's points."""
    seg = cfg["segment"]
    if segment.labelled_classes(seg["backend"], seg["weights"], seg["labels_dir"]) == []:
        whose = {
            "precomputed": f" (no name in {Path(str(seg['labels_dir'])) / 'labels.json'} is an object class)",
            "transformers": f" (no class of the checkpoint {seg['weights']} is an object class)",
        }.get(seg["backend"], "")
        raise InputError(
            "config segment.backend",
            f"{seg['backend']}{whose} labels no object class, so no object can come out of it and a photo gives no "
            "query; give per-pixel Vistas labels (segment.backend transformers with a local checkpoint in "
            f"segment.weights, or precomputed with segment.labels_dir): {BACKENDS_DOC}",
        )
    if cfg["images"]["depth"]["backend"] == "sparse":
        raise InputError(
            "config images.depth.backend",
            "sparse places objects at the depths of an SfM model's points, and one photo has none; give a "
            "monocular depth checkpoint (images.depth.backend transformers with images.depth.weights): "
            f"{BACKENDS_DOC}",
        )


def _with_doc(step, source: str, failure: str = "not usable as a local checkpoint"):
    """``step()`` (a model loaded or run), its failures one :class:`InputError` naming the model
    folder (or setting) and :data:`BACKENDS_DOC`: a checkpoint folder is untrusted data, whatever
    transformers or torch raise about it (``failure`` says what went wrong). A missing package is
    left to the caller to name."""
    try:
        return step()
    except InputError as e:
        if BACKENDS_DOC in e.problem:
            raise
        raise InputError(e.path, f"{e.problem} ({BACKENDS_DOC})") from None
    except ImportError:
        raise
    except Exception as e:  # transformers and torch raise many types for a folder that is no checkpoint
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise InputError(source, f"{failure} ({type(e).__name__}: {first}) ({BACKENDS_DOC})") from None


@contextlib.contextmanager
def _quiet_loading():
    """No progress bar of transformers' loading while the models load (``flatlandia localize``'s
    stderr carries its ERROR and WARNING lines only), as it was afterwards."""
    try:
        from transformers.utils import logging
    except ImportError:  # the backends say so, naming the setting
        yield
        return
    shown = logging.is_progress_bar_enabled()
    logging.disable_progress_bar()
    try:
        yield
    finally:
        if shown:
            logging.enable_progress_bar()


def orientation_of(path: str | Path) -> int:
    """The photo's EXIF Orientation (1: upright; 1 where absent, unknown or unreadable)."""
    with image_audit.open_image(path) as im:
        try:
            value = int(im.getexif().get(EXIF_ORIENTATION, 1))
        except Exception:  # PIL raises many types for broken EXIF blocks
            return 1
    return value if value in UPRIGHT else 1


def upright(rgb, orientation: int):
    """The pixels turned as the EXIF Orientation says (unchanged when upright)."""
    from PIL import Image

    return rgb if orientation not in UPRIGHT else rgb.transpose(getattr(Image.Transpose, UPRIGHT[orientation]))


def focal_length(exif_35mm: float | None, default_35mm: float) -> tuple[float, str]:
    """(35 mm-equivalent focal length, where it came from): the EXIF's when it is within the schema's
    bounds of ``images.photo.focal_35mm`` (EXIF writes 0 for unknown), else ``default_35mm``."""
    node = config.schema()["properties"]["images"]["properties"]["photo"]["properties"]["focal_35mm"]
    if exif_35mm is not None and node["minimum"] <= exif_35mm <= node["maximum"]:
        return float(exif_35mm), "EXIF FocalLengthIn35mmFilm"
    shown = "" if exif_35mm is None else f" (EXIF FocalLengthIn35mmFilm {exif_35mm:g} is no focal length)"
    return float(default_35mm), f"images.photo.focal_35mm{shown}"


def camera_matrix(width: int, height: int, focal_35mm: float) -> np.ndarray:
    """A pinhole centred on the photo whose diagonal field of view is the 35 mm equivalent's."""
    f = focal_35mm * math.hypot(width, height) / FULL_FRAME_DIAGONAL_MM
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def object_regions(class_map: np.ndarray, min_pixels: int) -> tuple[list[tuple[int, tuple, np.ndarray]], int]:
    """([(class id, (row slice, column slice), region mask within them)], specks): each connected
    region (8-connected) of one object class with at least ``min_pixels`` pixels, left to right,
    and how many smaller ones were left out."""
    from scipy import ndimage

    regions, specks = [], 0
    for c in np.unique(class_map):
        if c == segment.NOT_AN_OBJECT:
            continue
        lab, n = ndimage.label(class_map == c, structure=np.ones((3, 3), bool))
        counts = np.bincount(lab.ravel(), minlength=n + 1)
        for k, sl in enumerate(ndimage.find_objects(lab), start=1):
            if counts[k] < min_pixels:
                specks += 1
                continue
            regions.append((int(c), sl, lab[sl] == k))
    regions.sort(key=lambda r: (r[1][1].start + r[1][1].stop, r[0]))
    return regions, specks


def local_map(regions, depth_map: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """(x forward, y left) of each region: its box centre's ray at the median depth of its own
    pixels (:func:`depth.unproject_centre`), and which regions have one (a region without a positive
    depth has no range and is left out)."""
    xy, kept = [], []
    for i, (_, (rows, cols), mask) in enumerate(regions):
        d = depth_map[rows, cols][mask]
        d = d[np.isfinite(d) & (d > 0)]
        if d.size == 0:
            continue
        box = [cols.start, rows.start, cols.stop, rows.stop]
        cam = depth.unproject_centre(K, box, float(np.median(d)))
        xy.append((cam[2], -cam[0]))  # camera: x right, z forward; the local map: x forward, y left
        kept.append(i)
    return np.asarray(xy, float).reshape(-1, 2), kept


def photo_query(path: str | Path, settings: dict | None = None) -> PhotoQuery:
    """The query of one photo under ``settings`` (the config, or any of its sections: ``segment``,
    ``images`` with ``images.depth`` and ``images.photo``, ``device``; None: the schema's defaults).

    Raises :class:`InputError`, one line: a file that is no photo, or too small or too large
    (``images.min_side_px``, ``images.max_megapixels``); a segmentation that labels no object class
    or the ``sparse`` depth (:func:`check_backends`); a checkpoint folder missing or unusable (naming
    it and docs/backends.md); fewer objects than ``images.min_objects``.
    """
    cfg = resolved(settings)
    images, seg, dep = cfg["images"], cfg["segment"], cfg["images"]["depth"]
    path = Path(path)
    meta = image_audit.read_exif_metadata(path, images["max_megapixels"])
    problem = image_audit.size_problem(meta["width"], meta["height"], images["min_side_px"], images["max_megapixels"])
    if problem:
        raise InputError(path, problem)
    check_backends(cfg)
    with _quiet_loading():
        backend = _with_doc(
            lambda: segment.make_backend(seg["backend"], seg["weights"], seg["labels_dir"], device=cfg["device"]),
            str(seg["weights"]),
        )
        model = _with_doc(
            lambda: depth.MonocularDepth(dep["weights"], inverse=bool(dep["inverse"]), device=cfg["device"]),
            str(dep["weights"]),
        )
    turn = orientation_of(path)
    rgb = upright(segment.read_rgb(path), turn)
    width, height = rgb.size
    if hasattr(backend, "labels_of"):
        ids, names = _with_doc(lambda: backend.labels_of(rgb), str(seg["weights"]), f"failed on {path}")
    else:  # precomputed: the label image of the upright photo
        ids, names = _with_doc(lambda: backend.labels(path), str(seg["labels_dir"]), f"failed on {path}")
        if ids.shape != (height, width):
            raise InputError(
                Path(str(seg["labels_dir"])) / f"{path.stem}.png",
                f"label image of {ids.shape[1]} x {ids.shape[0]} px for a photo of {width} x {height} px (upright)",
            )
    _, class_map, _ = segment.mask_and_classes(ids, names, seg["watermark_box"], seg["dilate_px"])
    photo = images["photo"]
    regions, specks = object_regions(class_map, max(1, math.ceil(photo["min_object_share"] * width * height)))
    focal_35mm, focal_from = focal_length(meta["focal_35mm"], photo["focal_35mm"])
    K = camera_matrix(width, height, focal_35mm)
    labels = sorted({CLASSES[c] for c, _, _ in regions})
    few = (
        f"; a query needs at least {images['min_objects']} (images.min_objects); the regions of object classes "
        f"count from images.photo.min_object_share of the pixels ({specks} smaller left out)"
    )
    if len(regions) < images["min_objects"]:
        raise InputError(path, f"{len(regions)} objects found{' (' + ', '.join(labels) + ')' if labels else ''}{few}")
    pred = _with_doc(lambda: model.predict_rgb(rgb, (height, width)), str(dep["weights"]), f"failed on {path}")
    xy, kept = local_map(regions, depth.scaled_depth(pred, 1.0, bool(dep["inverse"])), K)
    xy = normalise_depth_map(xy)[0] if len(xy) else xy
    ok = np.hypot(xy[:, 0], xy[:, 1]) <= validate.MAX_LOCAL_COORD  # a depth of ~0 in an inverse model: no range
    xy, kept = xy[ok], [k for k, o in zip(kept, ok) if o]
    no_depth = len(regions) - len(kept)
    if len(kept) < images["min_objects"]:
        raise InputError(path, f"{len(kept)} objects with a usable depth of {len(regions)} found{few}")
    largest = sorted(
        sorted(range(len(kept)), key=lambda i: -int(regions[kept[i]][2].sum()))[: validate.MAX_QUERY_OBJECTS]
    )
    chosen = [regions[kept[i]] for i in largest]
    return PhotoQuery(
        path=str(path),
        width=width,
        height=height,
        orientation=turn,
        focal_px=float(K[0, 0]),
        focal_35mm=focal_35mm,
        focal_from=focal_from,
        segment_backend=seg["backend"],
        xy=normalise_depth_map(xy[largest])[0],  # the objects kept at a median range of 1
        cls=np.array([c for c, _, _ in chosen], np.int64),
        boxes=np.array([[s[1].start, s[0].start, s[1].stop, s[0].stop] for _, s, _ in chosen], np.int64),
        pixels=np.array([int(m.sum()) for _, _, m in chosen], np.int64),
        left_out={"specks": specks, "no_depth": no_depth, "beyond_max_objects": len(kept) - len(chosen)},
    )
