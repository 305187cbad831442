"""The city index: where in a large reference map a query can be, from its classes and bearings.

Why views rather than the map alone: a depth query is 3-17 objects whose bearings are accurate but
whose ranges and scale are not, so a map-only vote (pairs of same-class objects, each giving a
camera pose through its noisy ranges) puts the right 40 m cell in the top 10 for too few validation
queries of the 20-scene city (docs/measurements.md, "City search"). The mapping views (the training
split's cameras and the objects each saw) carry what the detector finds from a place, and a query is
taken near one of them: ranking views by the query's classes (an idf-weighted bag of classes) and
then by how well its bearings line up with a view's objects puts the right place among the 10 best
distinct places for most queries (measured: docs/measurements.md, "City search").

The index holds the map (positions, classes, ``obj_idx``), the views (pose, seen objects as
rows of the map) and the class weights; it is built once per map and saved as one ``.npz``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import sparse
from scipy.spatial import cKDTree

from flatlandia import classes
from flatlandia.city import view_kernels
from flatlandia.plumbing import files

#: arrays of the saved index
_FIELDS = ("obj_xy", "obj_cls", "obj_id", "cam", "view_ptr", "view_obj", "idf")


@dataclass
class ViewIndex:
    """A reference map and its mapping views, with what retrieval reads derived once."""

    obj_xy: np.ndarray  # (N, 2) metres
    obj_cls: np.ndarray  # (N,) class ids
    obj_id: np.ndarray  # (N,) the map's obj_idx
    cam: np.ndarray  # (P, 3) view x, y (m), heading (rad)
    view_ptr: np.ndarray  # (P + 1,) view p saw map rows view_obj[view_ptr[p]:view_ptr[p + 1]]
    view_obj: np.ndarray  # (E,)
    idf: np.ndarray  # (C,) -log share of the map's objects of each class

    def __post_init__(self):
        n_views, n_cls = len(self.cam), len(self.idf)
        rows = np.repeat(np.arange(n_views), np.diff(self.view_ptr))
        #: (P, C) class counts of every view, and its idf-weighted size
        self.hist = sparse.csr_matrix(
            (np.ones(len(self.view_obj)), (rows, self.obj_cls[self.view_obj])), shape=(n_views, n_cls)
        )
        self.hist.sum_duplicates()
        self.view_mass = np.asarray(self.hist @ self.idf).ravel()
        rel = self.obj_xy[self.view_obj] - self.cam[rows, :2]
        #: per seen object: bearing from its view (relative to the view's heading) and log range
        self.view_bear = np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - self.cam[rows, 2])))
        self.view_logr = np.log(np.hypot(rel[:, 0], rel[:, 1]) + view_kernels.RANGE_FLOOR_M)
        self.obj_tree = cKDTree(self.obj_xy)
        self.cam_tree = cKDTree(self.cam[:, :2]) if n_views else None

    @property
    def n_objects(self) -> int:
        return len(self.obj_xy)

    def nbytes(self) -> int:
        """Size of the saved arrays (what a query batch loads)."""
        return int(sum(getattr(self, f).nbytes for f in _FIELDS))

    def save(self, path: str | Path) -> None:
        with files.atomic_path(path, suffix=".npz") as tmp:
            np.savez(tmp, **{f: getattr(self, f) for f in _FIELDS})

    @classmethod
    def load(cls, path: str | Path) -> ViewIndex:
        """The index saved at ``path``, checked before anything uses it (:func:`flatlandia.plumbing.validate.city_index`:
        a crafted pointer would send the compiled kernels out of bounds); InputError naming the file."""
        from flatlandia.plumbing import validate
        from flatlandia.plumbing.errors import InputError

        validate.npz_members(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                missing = [f for f in _FIELDS if f not in z.files]
                if missing:
                    raise InputError(path, f"not a city index: no {', '.join(missing)}")
                arrays = {f: z[f] for f in _FIELDS}
        except InputError:
            raise
        except Exception as e:  # numpy and zipfile raise several types for a file that is not an index
            raise InputError(path, f"not a city index ({type(e).__name__}: {str(e)[:200]})") from None
        validate.city_index(arrays, path, classes.N_CLASSES)
        # unsigned ids and pointers (checked in range above) as int64: numpy will not cast uint64 to
        # the signed counts np.repeat takes (the fuzz suite's long profile found it)
        arrays = {f: a.astype(np.int64) if a.dtype.kind == "u" else a for f, a in arrays.items()}
        return cls(**arrays)

    def seen(self, view: int) -> np.ndarray:
        """Map rows that view ``view`` saw."""
        return self.view_obj[self.view_ptr[view] : self.view_ptr[view + 1]]


def build(ref: pd.DataFrame, views: pd.DataFrame) -> ViewIndex:
    """The index of a reference map (``obj_idx, class_id, x_m, y_m``) and its mapping views (query
    rows with ``x_m, y_m, theta_deg`` and ``ref_idx``, the objects each saw; the training split)."""
    obj_id = ref["obj_idx"].to_numpy(np.int64)
    cls = ref["class_id"].to_numpy(np.int64)
    row = {int(o): k for k, o in enumerate(obj_id)}
    seen = [np.array([row[int(o)] for o in objs if int(o) in row], np.int64) for objs in views["ref_idx"]]
    n_cls = max(classes.N_CLASSES, int(cls.max()) + 1 if len(cls) else 0)
    share = np.bincount(cls, minlength=n_cls) / max(len(cls), 1)
    return ViewIndex(
        obj_xy=ref[["x_m", "y_m"]].to_numpy(float),
        obj_cls=cls,
        obj_id=obj_id,
        cam=np.column_stack([views["x_m"], views["y_m"], np.radians(views["theta_deg"])]).astype(float).reshape(-1, 3),
        view_ptr=np.r_[0, np.cumsum([len(s) for s in seen])].astype(np.int64),
        view_obj=np.concatenate(seen + [np.zeros(0, np.int64)]),
        idf=-np.log(np.maximum(share, 1.0 / max(len(cls), 1))),
    )
