"""The registered images of an SfM model as the images stage reads them: intrinsics, pose and
observations (:class:`View`, from pycolmap), projection, the 3DoF pose on the map's ground plane and
a detection lifted by the sparse SfM depth.

Why apart: the queries (:mod:`flatlandia.images.image_queries`), the depth backends
(:mod:`flatlandia.images.depth`) and the GPS alignment (:mod:`flatlandia.images.gps_alignment`) all
read views; here none of them imports another to get them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class View:
    """One registered image: intrinsics, pose (camera from world), size and its observations."""

    name: str
    K: np.ndarray  # 3x3 (distortion ignored for box projection)
    R: np.ndarray  # 3x3 cam_from_world rotation
    t: np.ndarray  # 3 cam_from_world translation
    width: int
    height: int
    obs_point_ids: np.ndarray  # SfM point ids observed
    obs_xy: np.ndarray  # (n, 2) their pixel positions

    @property
    def centre(self) -> np.ndarray:
        return -self.R.T @ self.t

    @property
    def viewing_direction(self) -> np.ndarray:
        return self.R[2]  # the camera's +z axis in world coordinates


def views_from_colmap(rec) -> list[View]:
    out = []
    for img in rec.images.values():
        if not img.has_pose:
            continue
        cam = rec.cameras[img.camera_id]
        pose = img.cam_from_world() if callable(img.cam_from_world) else img.cam_from_world
        mat = np.asarray(pose.matrix())
        pts = [(p.point3D_id, p.xy) for p in img.points2D if p.has_point3D()]
        ids = np.array([p[0] for p in pts], dtype=np.int64)
        xy = np.array([p[1] for p in pts], dtype=float).reshape(-1, 2)
        out.append(
            View(
                img.name,
                np.asarray(cam.calibration_matrix()),
                mat[:, :3],
                mat[:, 3],
                int(cam.width),
                int(cam.height),
                ids,
                xy,
            )
        )
    return out


def pose_3dof(view: View, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Camera position on the map (metres) and heading (radians, CCW from east)."""
    xy = A @ view.centre + b
    d = A @ view.viewing_direction
    return xy, float(np.arctan2(d[1], d[0]))


def project(view: View, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions and depths of world points (pinhole)."""
    cam = X @ view.R.T + view.t
    z = cam[:, 2]
    uv = cam @ view.K.T
    return uv[:, :2] / np.where(np.abs(uv[:, 2:]) < 1e-12, 1e-12, uv[:, 2:]), z


def sparse_depth_point(view: View, box: list[float], point_xyz: dict[int, np.ndarray]) -> np.ndarray | None:
    """The detection centre lifted to the median depth of SfM points observed inside the box."""
    x0, y0, x1, y1 = box
    inside = (
        (view.obs_xy[:, 0] >= x0) & (view.obs_xy[:, 0] <= x1) & (view.obs_xy[:, 1] >= y0) & (view.obs_xy[:, 1] <= y1)
    )
    ids = view.obs_point_ids[inside]
    if len(ids) == 0:
        return None
    X = np.array([point_xyz[int(i)] for i in ids])
    depth = float(np.median((X @ view.R.T + view.t)[:, 2]))
    if depth <= 0:
        return None
    ray = np.linalg.solve(view.K, np.array([(x0 + x1) / 2, (y0 + y1) / 2, 1.0]))
    cam = ray * depth / ray[2]
    return view.R.T @ (cam - view.t)  # world (SfM) coordinates
