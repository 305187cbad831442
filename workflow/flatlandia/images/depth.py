"""Depth of detections for the depth local maps of images scenes.

Two backends behind one call, ``lift(view, box) -> world point or None``:
- ``sparse`` (offline default): the detection centre lifted to the median camera depth of the
  SfM points observed inside the detection (:func:`flatlandia.images.views.sparse_depth_point`);
- ``transformers``: a monocular depth model (DPT, MiDaS, Depth-Anything, ...) loaded with
  ``transformers`` from a local folder the user provides (nothing is downloaded). Such models
  predict depth up to scale (or inverse depth up to scale), so each image's prediction is
  scaled to the SfM depths of the points it observes (one robust factor per image), then the
  detection centre is lifted with the median scaled depth inside the box. The prediction is
  upsampled to the camera's size and the centre unprojected with kornia. See docs/backends.md.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from flatlandia import config
from flatlandia.images.segment import load_local_model
from flatlandia.images.views import View, sparse_depth_point
from flatlandia.plumbing.errors import InputError

#: Defaults: the `images.depth` section of workflow/schemas/config.schema.yaml.
_DEPTH = config.section_defaults("images.depth")


def fit_scale(pred_at_points: np.ndarray, sfm_depth: np.ndarray, inverse: bool) -> float:
    """Robust factor a with depth = a * pred (or a / pred for inverse-depth models).

    The median of per-point ratios ignores the outliers that monocular predictions have at
    depth edges. NaN when no point has a positive prediction and depth.
    """
    p = np.asarray(pred_at_points, float)
    d = np.asarray(sfm_depth, float)
    ok = np.isfinite(p) & np.isfinite(d) & (p > 0) & (d > 0)
    if not ok.any():
        return float("nan")
    return float(np.median(d[ok] * p[ok]) if inverse else np.median(d[ok] / p[ok]))


def scaled_depth(pred: np.ndarray, scale: float, inverse: bool) -> np.ndarray:
    pred = np.asarray(pred, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(pred > 0, scale / pred, np.nan) if inverse else scale * pred


def lift_box(view: View, box: list[float], depth_map: np.ndarray) -> np.ndarray | None:
    """World point of a detection: its centre pixel's ray at the box's median (scaled) depth."""
    h, w = depth_map.shape
    x0, y0, x1, y1 = (int(np.clip(round(v), 0, m)) for v, m in zip(box, (w, h, w, h)))
    patch = depth_map[y0 : max(y1, y0 + 1), x0 : max(x1, x0 + 1)]
    patch = patch[np.isfinite(patch) & (patch > 0)]
    if patch.size == 0:
        return None
    cam = unproject_centre(view.K, box, float(np.median(patch)))
    return view.R.T @ (cam - view.t)


def unproject_centre(K: np.ndarray, box: list[float], depth: float) -> np.ndarray:
    """Camera-frame point (x right, y down, z forward) of a box's centre pixel at ``depth`` (along
    the optical axis), by kornia; apart from :func:`lift_box` because one photo's query
    (:mod:`flatlandia.images.photo_query`) lifts its detections so too, without a pose."""
    import torch
    from kornia.geometry.camera import unproject_points

    centre = torch.tensor([[(box[0] + box[2]) / 2, (box[1] + box[3]) / 2]], dtype=torch.float64)
    d = torch.tensor([[float(depth)]], dtype=torch.float64)
    return unproject_points(centre, d, torch.from_numpy(np.asarray(K, float))[None])[0].numpy()


def upsample(pred, size: tuple[int, int]) -> np.ndarray:
    """A (h, w) prediction resized to ``size`` (kornia, bilinear: stays positive, unlike bicubic)."""
    from kornia.geometry.transform import resize

    return resize(pred, size, interpolation="bilinear", align_corners=False).double().cpu().numpy()


class MonocularDepth:
    """A local ``transformers`` depth-estimation checkpoint; predictions scaled per image to SfM."""

    def __init__(self, weights: str | Path | None, inverse: bool = _DEPTH["inverse"], device="cpu"):
        """``device``: where the model runs (a ``torch.device``, or the config's ``auto`` | ``cpu`` |
        ``cuda``); it is moved there once, each image's tensors go there and the depth map comes back."""
        if not weights:
            raise InputError(
                "config images.depth.weights",
                "the transformers depth backend needs a local checkpoint folder; nothing is downloaded",
            )
        self.weights = Path(weights)
        if not (self.weights / "config.json").exists():
            raise InputError(
                self.weights, "not a transformers checkpoint folder (no config.json); nothing is downloaded"
            )
        try:
            from transformers import AutoModelForDepthEstimation
        except ImportError as e:  # pragma: no cover - transformers is pinned in envs/requirements.txt
            raise InputError(
                self.weights, f"the transformers depth backend needs `pip install transformers` ({e})"
            ) from e
        # local files only, remote code never trusted, safetensors weights only (see load_local_model)
        from flatlandia import device as device_module

        self.device = device_module.torch_device(device)
        self.processor, self.model = load_local_model(self.weights, AutoModelForDepthEstimation)
        self.model.to(self.device)
        self.inverse = inverse

    def predict(self, image_path: str | Path, size: tuple[int, int]) -> np.ndarray:
        """The model's (relative) depth of an image, at ``size`` (the camera's height, width)."""
        from PIL import Image

        with Image.open(image_path) as im:
            rgb = im.convert("RGB")
        return self.predict_rgb(rgb, size)

    def predict_rgb(self, rgb, size: tuple[int, int]) -> np.ndarray:
        """:meth:`predict` of an image already read (an RGB PIL image: one photo's query reads it
        through the images' door, :func:`flatlandia.images.segment.read_rgb`)."""
        import torch

        with torch.no_grad():
            pred = self.model(**self.processor(images=rgb, return_tensors="pt").to(self.device)).predicted_depth
        return upsample(pred[0], size)

    def scaled_map(self, view: View, image_path: str | Path, point_xyz: dict[int, np.ndarray]) -> np.ndarray:
        """Depth map in SfM units of a view: the prediction times the factor fitted to its SfM points."""
        pred = self.predict(image_path, (view.height, view.width))
        h, w = pred.shape
        X = np.array([point_xyz[int(i)] for i in view.obs_point_ids]).reshape(-1, 3)
        d = (X @ view.R.T + view.t)[:, 2]
        c = np.clip(np.floor(view.obs_xy[:, 0]).astype(int), 0, w - 1)  # COLMAP: pixel k spans [k, k+1)
        r = np.clip(np.floor(view.obs_xy[:, 1]).astype(int), 0, h - 1)
        return scaled_depth(pred, fit_scale(pred[r, c], d, self.inverse), self.inverse)


def make_lifter(
    backend: str,
    point_xyz: dict[int, np.ndarray],
    images_dir: str | Path | None = None,
    weights: str | None = None,
    inverse: bool = _DEPTH["inverse"],
    device="cpu",
) -> Callable[[View, list[float]], np.ndarray | None]:
    """The ``lift(view, box)`` function of a backend (``sparse`` or ``transformers``, its model on
    ``device``, the config's ``device``)."""
    if backend == "sparse":
        return lambda view, box: sparse_depth_point(view, box, point_xyz)
    if backend == "transformers":
        model = MonocularDepth(weights, inverse=inverse, device=device)
        cache: dict[str, np.ndarray] = {}

        def lift(view: View, box: list[float]) -> np.ndarray | None:
            if view.name not in cache:
                cache[view.name] = model.scaled_map(view, Path(images_dir) / view.name, point_xyz)
            return lift_box(view, box, cache[view.name])

        return lift
    raise InputError("config images.depth.backend", f"unknown depth backend {backend!r} (sparse, transformers)")
