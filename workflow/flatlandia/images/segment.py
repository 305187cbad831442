"""Segmentation backends behind one interface: label maps and masks of moving/changing content.

Every backend returns, per image, a *Vistas label-name map*: an integer image plus a table
``id -> Mapillary Vistas label name``. From it we derive
- the binary mask pycolmap reads (``<image name>.png``, 0 = ignore, 255 = use): people,
  riders, vehicles, animals, sky, vegetation, the capturing car and the configured watermark
  box are ignored;
- the Flatlandia object-class map (uint8, class id 0-41, 255 = not an object): Flatlandia's
  42 classes are Vistas labels, matched by name (see ``flatlandia_class_of``).

Backends:
- ``offline``: no downloaded weights. Sky = bright, low-texture pixels connected to the top
  border; vegetation = excess-green pixels; people = OpenCV's built-in HOG pedestrian
  detector (boxes scoring >= 1.0: finds upright people of 100+ px, misses small or partial
  ones). It finds **no vehicles and no object classes**: masks are partial and the object
  map of an images scene stays empty with it.
- ``precomputed``: label PNGs in Vistas ids from a folder (``<stem>.png``) + ``labels.json``
  (a list of label names, index = id, as in the Vistas config files).
- ``transformers``: a Vistas semantic-segmentation checkpoint (Mask2Former, MaskFormer) loaded
  with ``transformers`` from a local folder the user provides; nothing is downloaded. The public
  checkpoints name their classes by the Vistas v1.2 *readable* names ("Street Light"): they are
  translated to label names (``vistas_names``). See docs/backends.md.

Masks of moving content (people, riders, vehicles, animals) can be grown by ``dilate_px``
(kornia's morphological dilation): segmenters miss their blurred rims and shadows, whose
features would otherwise enter SfM.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from flatlandia import config
from flatlandia.classes import CLASSES
from flatlandia.images import image_audit
from flatlandia.plumbing.errors import InputError

#: Vistas label-name prefixes of things that move (their masks can be dilated).
MOVING_PREFIXES = ("human--", "object--vehicle--", "animal--")
#: Vistas label-name prefixes whose pixels are moving or changing content, or the capturing car (masked out).
DYNAMIC_PREFIXES = (*MOVING_PREFIXES, "nature--sky", "nature--vegetation", "void--ego-vehicle", "void--car-mount")

#: Flatlandia class names that are not literally Vistas v2.0 names, with the v2.0 name(s).
#: Vistas v1.2 has none of the marking--discrete subclasses (only marking--general) and
#: no object--sign--information/ object--traffic-sign--information-parking/ direction split.
VISTAS_ALIASES = {
    "driveway": ["construction--flat--driveway"],
    "crosswalk-plain": ["construction--flat--crosswalk-plain"],
    "crosswalk-zebra": ["marking--discrete--crosswalk-zebra", "marking--crosswalk-zebra"],
    "give-way-row": ["marking--discrete--give-way-row"],
    "give-way-single": ["marking--discrete--give-way-single"],
    "stop-line": ["marking--discrete--stop-line"],
    "other-marking": ["marking--discrete--other-marking", "marking--general"],
    "banner": ["object--banner"],
    "object--sign--advertisement": ["object--billboard"],  # v1.2 has one billboard class for all signs
    "object--traffic-sign": ["object--traffic-sign--front"],
    "object--traffic-sign--direction": ["object--traffic-sign--direction-front"],
    "object--traffic-light--general-upright": ["object--traffic-light"],  # v1.2: one class; upright is the commonest
    "object--traffic-light--general-other": ["object--traffic-light--other"],
}

#: Vistas v1.2 readable names (the ``id2label`` of the public Mask2Former Vistas checkpoints) -> label names.
VISTAS_V12_READABLE = {
    "Bird": "animal--bird",
    "Ground Animal": "animal--ground-animal",
    "Curb": "construction--barrier--curb",
    "Fence": "construction--barrier--fence",
    "Guard Rail": "construction--barrier--guard-rail",
    "Barrier": "construction--barrier--other-barrier",
    "Wall": "construction--barrier--wall",
    "Bike Lane": "construction--flat--bike-lane",
    "Crosswalk - Plain": "construction--flat--crosswalk-plain",
    "Curb Cut": "construction--flat--curb-cut",
    "Parking": "construction--flat--parking",
    "Pedestrian Area": "construction--flat--pedestrian-area",
    "Rail Track": "construction--flat--rail-track",
    "Road": "construction--flat--road",
    "Service Lane": "construction--flat--service-lane",
    "Sidewalk": "construction--flat--sidewalk",
    "Bridge": "construction--structure--bridge",
    "Building": "construction--structure--building",
    "Tunnel": "construction--structure--tunnel",
    "Person": "human--person",
    "Bicyclist": "human--rider--bicyclist",
    "Motorcyclist": "human--rider--motorcyclist",
    "Other Rider": "human--rider--other-rider",
    "Lane Marking - Crosswalk": "marking--crosswalk-zebra",
    "Lane Marking - General": "marking--general",
    "Mountain": "nature--mountain",
    "Sand": "nature--sand",
    "Sky": "nature--sky",
    "Snow": "nature--snow",
    "Terrain": "nature--terrain",
    "Vegetation": "nature--vegetation",
    "Water": "nature--water",
    "Banner": "object--banner",
    "Bench": "object--bench",
    "Bike Rack": "object--bike-rack",
    "Billboard": "object--billboard",
    "Catch Basin": "object--catch-basin",
    "CCTV Camera": "object--cctv-camera",
    "Fire Hydrant": "object--fire-hydrant",
    "Junction Box": "object--junction-box",
    "Mailbox": "object--mailbox",
    "Manhole": "object--manhole",
    "Phone Booth": "object--phone-booth",
    "Pothole": "object--pothole",
    "Street Light": "object--street-light",
    "Pole": "object--support--pole",
    "Traffic Sign Frame": "object--support--traffic-sign-frame",
    "Utility Pole": "object--support--utility-pole",
    "Traffic Light": "object--traffic-light",
    "Traffic Sign (Back)": "object--traffic-sign--back",
    "Traffic Sign (Front)": "object--traffic-sign--front",
    "Trash Can": "object--trash-can",
    "Bicycle": "object--vehicle--bicycle",
    "Boat": "object--vehicle--boat",
    "Bus": "object--vehicle--bus",
    "Car": "object--vehicle--car",
    "Caravan": "object--vehicle--caravan",
    "Motorcycle": "object--vehicle--motorcycle",
    "On Rails": "object--vehicle--on-rails",
    "Other Vehicle": "object--vehicle--other-vehicle",
    "Trailer": "object--vehicle--trailer",
    "Truck": "object--vehicle--truck",
    "Wheeled Slow": "object--vehicle--wheeled-slow",
    "Car Mount": "void--car-mount",
    "Ego Vehicle": "void--ego-vehicle",
    "Unlabeled": "void--unlabeled",
}

NOT_AN_OBJECT = 255


def flatlandia_class_of(vistas_names: list[str]) -> np.ndarray:
    """Flatlandia class id (0-41) of each Vistas label name; 255 where it is not one of them."""
    lookup = {}
    for cid, name in enumerate(CLASSES):
        for alias in [name] + VISTAS_ALIASES.get(name, []):
            lookup[alias] = cid
    return np.array([lookup.get(n, NOT_AN_OBJECT) for n in vistas_names], dtype=np.uint8)


def missing_classes(vistas_names: list[str]) -> list[str]:
    """Flatlandia classes that no label of a label set maps to: object maps built with it lack them."""
    have = set(flatlandia_class_of(vistas_names).tolist())
    return [c for cid, c in enumerate(CLASSES) if cid not in have]


def vistas_names(id2label: dict[int, str]) -> list[str]:
    """Vistas label names of a checkpoint's classes (index = class id), readable v1.2 names translated."""
    return [VISTAS_V12_READABLE.get(id2label[i], id2label[i]) for i in range(len(id2label))]


def dynamic_of(vistas_names: list[str]) -> np.ndarray:
    return np.array([n.startswith(DYNAMIC_PREFIXES) for n in vistas_names], dtype=bool)


def moving_of(vistas_names: list[str]) -> np.ndarray:
    return np.array([n.startswith(MOVING_PREFIXES) for n in vistas_names], dtype=bool)


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """A boolean mask grown by ``radius`` pixels (disk structuring element, kornia morphology)."""
    if radius <= 0 or not mask.any():
        return mask
    import torch
    from kornia.morphology import dilation

    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    disk = torch.from_numpy((xx**2 + yy**2 <= radius**2).astype(np.float32))
    grown = dilation(torch.from_numpy(mask.astype(np.float32))[None, None], disk)
    return grown[0, 0].numpy() > 0.5


def watermark_mask(shape: tuple[int, int], box: list[float] | None) -> np.ndarray:
    """Pixels inside a watermark box given as fractions [x0, y0, x1, y1] of the image."""
    h, w = shape
    m = np.zeros((h, w), dtype=bool)
    if box:
        x0, y0, x1, y1 = box
        m[int(round(y0 * h)) : int(round(y1 * h)), int(round(x0 * w)) : int(round(x1 * w))] = True
    return m


#: the shortest image side the backends process (the offline colour rules filter over 9 pixels);
#: the audit's images.min_side_px (at least this) drops smaller images before they get here
MIN_SIDE_PX = 16


def read_rgb(path: Path) -> Image.Image:
    """An image to segment, as RGB: a regular file only (:func:`flatlandia.images.image_audit.open_image`), refused
    with one :class:`InputError` naming it when its shorter side is under :data:`MIN_SIDE_PX`."""
    with image_audit.open_image(path) as im:
        if min(im.size) < MIN_SIDE_PX:
            raise InputError(
                path,
                f"image of {im.size[0]} x {im.size[1]} px is too small to segment (the shorter side must be "
                f"at least {MIN_SIDE_PX} px; the audit drops such images: images.min_side_px)",
            )
        try:
            return im.convert("RGB")
        except Exception as e:  # PIL raises many types for broken files
            raise InputError(path, f"unreadable image ({e})") from None


# ----------------------------------------------------------------------- offline backend
OFFLINE_NAMES = ["void", "nature--sky", "nature--vegetation", "human--person"]
HOG_MIN_SCORE = 1.0  # on Lund: true pedestrians score 2-3, facade false positives below 1
#: OpenCV's default people detector window (width, height): no one smaller can be found, and
#: ``detectMultiScale`` on a smaller image corrupts memory (OpenCV 4.14: a 64 x 48 image segfaults)
HOG_WINDOW = (64, 128)


def detect_people(rgb: np.ndarray, min_score: float = HOG_MIN_SCORE) -> list[tuple[int, int, int, int]]:
    """Upright people as (x, y, w, h) boxes, from OpenCV's HOG + linear SVM pedestrian detector
    (none in an image smaller than its :data:`HOG_WINDOW`)."""
    import cv2

    if rgb.shape[1] < HOG_WINDOW[0] or rgb.shape[0] < HOG_WINDOW[1]:
        return []
    hog = cv2.HOGDescriptor()
    hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    boxes, scores = hog.detectMultiScale(grey, winStride=(8, 8), padding=(8, 8), scale=1.05)
    return [tuple(int(v) for v in b) for b, s in zip(boxes, np.ravel(scores)) if s >= min_score]


def offline_labels(rgb: np.ndarray) -> np.ndarray:
    """Sky and vegetation by colour rules (ids into OFFLINE_NAMES)."""
    from scipy import ndimage

    img = rgb.astype(np.float32) / 255.0
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    grey = img.mean(axis=-1)
    grad = np.hypot(*np.gradient(ndimage.uniform_filter(grey, 3)))
    texture = ndimage.uniform_filter(grad, 9)
    blue_sky = (b > r + 0.04) & (b > g - 0.02) & (grey > 0.35)
    cloud = (grey > 0.7) & (np.abs(b - r) < 0.12)
    sky_like = (blue_sky | cloud) & (texture < 0.03)
    sky_like = ndimage.binary_closing(sky_like, iterations=2)
    lab, _ = ndimage.label(sky_like)
    top = np.unique(lab[:4][lab[:4] > 0])  # closing erodes the very border
    sky = np.isin(lab, top)
    exg = 2 * g - r - b
    sat = (img.max(axis=-1) - img.min(axis=-1)) / (img.max(axis=-1) + 1e-6)
    veg = (exg > 0.10) & (g > 0.15) & (sat > 0.2) & ~sky  # saturated: not greenish stone or bronze
    veg = ndimage.binary_opening(veg, iterations=2)
    out = np.zeros(rgb.shape[:2], dtype=np.uint8)
    out[sky] = 1
    out[veg] = 2
    for x, y, w, h in detect_people(rgb):
        out[y : y + h, x : x + w] = 3
    return out


# ----------------------------------------------------------------------- backends
class Backend:
    """Interface: ``labels(path) -> (id map (H, W) int, names list)``."""

    name = "base"

    def labels(self, path: Path) -> tuple[np.ndarray, list[str]]:
        raise NotImplementedError


class OfflineBackend(Backend):
    name = "offline"

    def labels(self, path: Path) -> tuple[np.ndarray, list[str]]:
        return offline_labels(np.asarray(read_rgb(path))), OFFLINE_NAMES


def read_label_names(path: Path) -> list[str]:
    """The label names of a ``labels.json`` (a list, or the Vistas config layout ``{"labels":
    [{"name": ...}]}``), each checked: a non-empty name without path separators or control
    characters, so no label name can ever steer a path."""
    try:
        names = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(path, f"not a readable JSON list of label names ({e})") from None
    if isinstance(names, dict) and isinstance(names.get("labels"), list):  # the Vistas config file layout
        names = [lab.get("name") if isinstance(lab, dict) else None for lab in names["labels"]]
    if not isinstance(names, list) or not names:
        raise InputError(path, "must be a non-empty list of Vistas label names (index = id)")
    for i, n in enumerate(names):
        if not isinstance(n, str) or not n.strip() or any(c in n for c in "/\\") or any(ord(c) < 32 for c in n):
            raise InputError(
                path,
                f"label {i} ({n!r}) is not a label name (a non-empty text without '/', '\\' or control characters)",
            )
    return names


class PrecomputedBackend(Backend):
    name = "precomputed"

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        names_path = self.folder / "labels.json"
        if not names_path.exists():
            raise InputError(names_path, "precomputed labels need labels.json (list of Vistas label names, index = id)")
        self.names = read_label_names(names_path)

    def labels(self, path: Path) -> tuple[np.ndarray, list[str]]:
        lab_path = self.folder / f"{Path(path).stem}.png"
        if not lab_path.exists():
            raise InputError(lab_path, f"no precomputed label image for {Path(path).name}")
        with Image.open(lab_path) as im:
            ids = np.asarray(im)
        if ids.ndim != 2:
            raise InputError(lab_path, "label image must be single-channel ids")
        if ids.max() >= len(self.names):
            raise InputError(lab_path, f"label id {int(ids.max())} beyond the {len(self.names)} names of labels.json")
        return ids, self.names


class TransformersBackend(Backend):
    name = "transformers"

    def __init__(self, weights: str | Path | None, device="cpu"):
        """``device``: where the model runs (a ``torch.device``, or the config's ``auto`` | ``cpu``
        | ``cuda``); it is moved there once, each image's tensors go there and the label map comes back."""
        if not weights:
            raise InputError("config segment.weights", "the transformers backend needs a local checkpoint folder")
        self.weights = Path(weights)
        if not (self.weights / "config.json").exists():
            raise InputError(
                self.weights, "not a transformers checkpoint folder (no config.json); nothing is downloaded"
            )
        try:
            import torch
            from transformers import AutoModelForUniversalSegmentation
        except ImportError as e:
            raise InputError(self.weights, f"the transformers backend needs `pip install transformers` ({e})") from e
        from flatlandia import device as device_module

        self.torch = torch
        self.device = device_module.torch_device(device)
        self.processor, self.model = load_local_model(self.weights, AutoModelForUniversalSegmentation)
        self.model.to(self.device)
        self.names = vistas_names(self.model.config.id2label)
        if not any("--" in n for n in self.names):
            raise InputError(self.weights, "the checkpoint's classes are not Mapillary Vistas labels")

    def labels(self, path: Path) -> tuple[np.ndarray, list[str]]:
        return self.labels_of(read_rgb(path))

    def labels_of(self, rgb: Image.Image) -> tuple[np.ndarray, list[str]]:
        """:meth:`labels` of an RGB image already read (one photo's query turns it upright first)."""
        with self.torch.no_grad():
            out = self.model(**self.processor(images=rgb, return_tensors="pt").to(self.device))
        scores = semantic_scores(out.class_queries_logits[0], out.masks_queries_logits[0])
        return label_map(scores, (rgb.height, rgb.width)), self.names


def load_local_model(folder: Path, model_class) -> tuple[object, object]:
    """(image processor, model in eval mode) of a local ``transformers`` checkpoint folder.

    The folder is untrusted data, never code: local files only (``local_files_only=True``:
    nothing is downloaded), remote code never trusted (``trust_remote_code=False``: a folder whose
    config asks for its own Python code, ``auto_map``, is refused, that code never imported), and
    weights from ``*.safetensors`` only (``use_safetensors=True``: no pickled ``.bin`` weights).
    The PIL processor backend preprocesses alike with or without torchvision: same outputs everywhere.
    """
    from transformers import AutoImageProcessor

    folder = Path(folder)
    if not any(folder.glob("*.safetensors")):
        raise InputError(
            folder,
            "no *.safetensors weights: only safetensors checkpoints are loaded (pickled .bin weights can "
            "run code); save the model with save_pretrained, which writes model.safetensors",
        )
    try:
        processor = AutoImageProcessor.from_pretrained(
            folder, local_files_only=True, trust_remote_code=False, backend="pil"
        )
        model = model_class.from_pretrained(
            folder, local_files_only=True, trust_remote_code=False, use_safetensors=True
        ).eval()
    except (OSError, ValueError, KeyError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(
            folder, f"not loadable as a local transformers checkpoint without remote code ({first})"
        ) from None
    return processor, model


def semantic_scores(class_logits, mask_logits):
    """Per-class score maps (C, h, w) of a mask-classification model: each query's class
    probabilities (the trailing no-object class dropped) weighted by its mask, summed over queries."""
    import torch

    return torch.einsum("qc,qhw->chw", class_logits.softmax(-1)[:, :-1], mask_logits.sigmoid())


def label_map(scores, size: tuple[int, int]) -> np.ndarray:
    """Class id per image pixel: scores upsampled straight to the image size (kornia), then arg-max.

    Straight, not through the fixed 384 x 384 of transformers' post-processing, which drops
    detail wherever the model's masks are larger than that.
    """
    from kornia.geometry.transform import resize

    up = resize(scores, size, interpolation="bilinear", align_corners=False)
    return up.argmax(0).cpu().numpy().astype(np.int32)


def make_backend(name: str, weights: str | None = None, labels_dir: str | None = None, device="cpu") -> Backend:
    """The backend ``name`` (config ``segment.backend``); ``device`` (config ``device``) is where the
    transformers model runs: the offline and precomputed backends use no model."""
    if name == "offline":
        return OfflineBackend()
    if name == "precomputed":
        if not labels_dir:
            raise InputError("config segment.labels_dir", "the precomputed backend needs a folder of label images")
        return PrecomputedBackend(labels_dir)
    if name == "transformers":
        return TransformersBackend(weights, device)
    raise InputError("config segment.backend", f"unknown backend {name!r} (offline, precomputed, transformers)")


def labelled_classes(backend: str, weights: str | None = None, labels_dir: str | None = None) -> list[str] | None:
    """The Flatlandia classes the configured backend (config ``segment``) can label, told before any
    job from a small file at most: ``offline`` none; ``precomputed`` those of its ``labels.json``;
    ``transformers`` those of its checkpoint's ``config.json`` (``id2label``). None where it cannot be
    told yet (a file missing or unreadable: rule segment says what is wrong with it)."""
    from flatlandia.plumbing import files

    if backend == "offline":
        return []
    try:
        if backend == "precomputed" and labels_dir:
            names = read_label_names(Path(labels_dir) / "labels.json")
        elif backend == "transformers" and weights:
            id2label = files.read_json(Path(weights) / "config.json", max_bytes=16 * 2**20)["id2label"]
            names = vistas_names({int(k): str(v) for k, v in id2label.items()})
        else:
            return None
    except (InputError, OSError, KeyError, TypeError, ValueError, AttributeError):
        return None
    have = set(flatlandia_class_of(names).tolist()) - {NOT_AN_OBJECT}
    return [c for cid, c in enumerate(CLASSES) if cid in have]


#: the rules that are about to build an images scene's SfM model: the warning below comes before them
SFM_RULES = frozenset({"fetch_images", "image_audit", "segment", "sfm"})


def empty_map_warning(settings: dict, scenes: list[str], planned_rules: set[str] | None = None) -> str | None:
    """One line for the run's start when this run builds the SfM model of images ``scenes`` with a
    segmentation backend (``settings``: config ``segment``) that labels no object class: the map
    would end with 0 objects and 0 queries after minutes of SfM, said only by the run's summary.
    None when no images scene is selected, the backend labels classes (or cannot be told yet), or
    ``planned_rules`` (the rules of the jobs about to run; None: unknown) build no SfM."""
    if not scenes or (planned_rules is not None and not planned_rules & SFM_RULES):
        return None
    backend = settings["backend"]
    if labelled_classes(backend, settings["weights"], settings["labels_dir"]) != []:
        return None
    whose = {
        "precomputed": f" (no name in {Path(str(settings['labels_dir'])) / 'labels.json'} is an object class)",
        "transformers": f" (no class of the checkpoint {settings['weights']} is an object class)",
    }.get(backend, "")
    return (
        f"WARNING: segment.backend {backend}{whose} labels no object classes: images scene(s) "
        f"{', '.join(map(str, scenes))} will get SfM and masks but an empty map (0 objects, 0 queries); for "
        "objects give per-pixel Vistas labels (segment.backend precomputed or transformers): docs/backends.md"
    )


def mask_and_classes(
    ids: np.ndarray,
    names: list[str],
    watermark_box: list[float] | None,
    dilate_px: int = config.section_defaults("segment")["dilate_px"],
) -> tuple[np.ndarray, np.ndarray, dict]:
    """(pycolmap mask uint8 0/255, Flatlandia class map uint8, pixel shares per masked kind).

    ``dilate_px`` grows the masks of moving things (people, riders, vehicles, animals) only: sky
    and vegetation edges border buildings whose features SfM needs.
    """
    dyn = dynamic_of(names)[ids] | dilate(moving_of(names)[ids], dilate_px)
    wm = watermark_mask(ids.shape, watermark_box)
    ignore = dyn | wm
    cls = flatlandia_class_of(names)[ids]
    cls[ignore] = NOT_AN_OBJECT
    shares = {"masked": float(ignore.mean()), "watermark": float(wm.mean())}
    for kind in ("human--", "object--vehicle--", "nature--sky", "nature--vegetation"):
        sel = np.array([n.startswith(kind) for n in names])
        shares[kind.strip("-")] = float(sel[ids].mean()) if sel.any() else 0.0
    shares["objects"] = float((cls != NOT_AN_OBJECT).mean())
    return np.where(ignore, 0, 255).astype(np.uint8), cls, shares


def ignore_iou(ours: np.ndarray, reference: np.ndarray) -> float:
    """IoU of the ignored (0) pixels of two masks; NaN when neither ignores anything."""
    a, b = np.asarray(ours) == 0, np.asarray(reference) == 0
    union = int((a | b).sum())
    return float((a & b).sum() / union) if union else float("nan")
