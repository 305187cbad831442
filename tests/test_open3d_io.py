"""PLY reading and writing by open3d: the published class clouds, classified SfM points, object boxes."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pandas as pd
import pytest
from conftest import data_root

from flatlandia.classes import CLASSES
from flatlandia.images import classify_points
from flatlandia.objects import cloud, clustering
from flatlandia.plumbing.errors import InputError

ROOT = data_root()
CLASS_CLOUD_SCENES = ["1", "2", "4", "5", "8", "9", "11", "12", "13", "14", "17", "18"]
#: Vertex layout of every published class cloud (written by Open3D: double x/y/z, uchar colour).
PUBLISHED_VERTEX = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("rgb", "u1", (3,))])


@pytest.mark.parametrize("scene", CLASS_CLOUD_SCENES)
@pytest.mark.slow  # the published data
def test_published_cloud_read_exactly(scene):
    """open3d's reader returns every vertex of the binary file bit for bit (checked against the
    raw body), and every colour is background or a macro-class colour."""
    path = ROOT / f"maps/{scene}/class_segmented_point_cloud.ply"
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:end].decode("ascii").splitlines()
    assert header[1] == "format binary_little_endian 1.0"
    n = int(next(ln for ln in header if ln.startswith("element vertex")).split()[2])
    body = np.frombuffer(raw, PUBLISHED_VERTEX, count=n, offset=end)
    assert len(raw) == end + n * PUBLISHED_VERTEX.itemsize
    pts, labels = cloud.read_classified_cloud(path)
    np.testing.assert_array_equal(pts, np.column_stack([body["x"], body["y"], body["z"]]))
    expected = [
        cloud.BACKGROUND if tuple(c) == cloud.BACKGROUND_RGB else cloud.MACRO_BY_RGB[tuple(c)].name for c in body["rgb"]
    ]
    assert list(labels) == expected


@pytest.mark.slow  # the published data
def test_truncated_published_cloud_raises(tmp_path):
    """A cut file: its header declares more rows than the body holds, refused before open3d reads it
    (open3d itself only logs a short read)."""
    whole = (ROOT / "maps/12/class_segmented_point_cloud.ply").read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(InputError, match="PLY header declares 9329 vertex rows of 27 bytes.*truncated or forged"):
        cloud.read_classified_cloud(cut)


def _sfm_points(n: int = 50) -> pd.DataFrame:
    rng = np.random.default_rng(5)
    cls = np.where(np.arange(n) % 3 == 0, CLASSES.index("object--street-light"), classify_points.NOT_AN_OBJECT)
    cls[1] = CLASSES.index("object--traffic-sign")
    xyz = rng.uniform(-30, 30, (n, 3))
    return pd.DataFrame({"point3D_id": np.arange(n), "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "class_id": cls})


def test_classified_ply_round_trip(tmp_path):
    """The classified SfM points keep their class_id (uchar) and a colour per class, the file is
    binary with the usual header, and the package reader folds the classes into macro-classes."""
    pts = _sfm_points()
    out = tmp_path / "classified_points.ply"
    classify_points.write_classified_ply(pts, out)
    raw = out.read_bytes()
    lines = raw[: raw.index(b"end_header")].decode("ascii").splitlines()
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"] and f"element vertex {len(pts)}" in lines
    assert "property uchar class_id" in lines and "property uchar red" in lines
    pc = o3d.t.io.read_point_cloud(str(out))
    assert pc.point.class_id.dtype == o3d.core.uint8
    np.testing.assert_array_equal(pc.point.class_id.numpy().ravel(), pts["class_id"])
    colours = pc.point.colors.numpy()
    assert (colours[pts["class_id"].to_numpy() == 255] == (51, 51, 51)).all()
    assert len({tuple(c) for c in colours[pts["class_id"].to_numpy() == CLASSES.index("object--street-light")]}) == 1
    xyz, labels = cloud.read_classified_cloud(out)
    np.testing.assert_array_equal(xyz, pts[["x", "y", "z"]].to_numpy())  # binary doubles: exact
    np.testing.assert_array_equal(labels, cloud.macro_of_class(pts["class_id"].to_numpy()))
    assert set(labels) == {"light", "sign", cloud.BACKGROUND}


def test_classified_ply_refuses_no_points(tmp_path):
    with pytest.raises(ValueError, match="no points"):
        classify_points.write_classified_ply(_sfm_points().iloc[:0], tmp_path / "none.ply")


def test_boxes_ply_exact_colours_and_corners(tmp_path):
    """Box corners keep full double precision and every macro-class colour comes back exactly."""
    rng = np.random.default_rng(6)
    names = [m.name for m in cloud.MACRO_CLASSES]
    pts = np.vstack([rng.normal([10.0 * k, 0, 0], 0.1, (6, 3)) for k in range(len(names))])
    labels = np.repeat(np.array(names, dtype=object), 6)
    objs = clustering.cluster_objects(pts, labels, metres_per_unit=1.0)
    assert len(objs) == len(names)
    out = tmp_path / "objects.ply"
    clustering.write_boxes_ply(objs, out)
    mesh = o3d.io.read_triangle_mesh(str(out))
    v, c = np.asarray(mesh.vertices), np.rint(np.asarray(mesh.vertex_colors) * 255).astype(int)
    assert len(v) == 8 * len(objs) and len(mesh.triangles) == 12 * len(objs)
    for k, row in enumerate(objs.itertuples(index=False)):
        np.testing.assert_array_equal(v[8 * k : 8 * k + 8], clustering.box_corners(row))
        assert (c[8 * k : 8 * k + 8] == cloud.MACRO_BY_NAME[row.macro_class].rgb).all()
    assert mesh.is_watertight()  # each box closed: viewers render solid boxes


def test_boxes_ply_without_objects(tmp_path):
    """open3d writes no empty mesh; a scene without objects still gets a valid PLY of no boxes."""
    out = tmp_path / "objects.ply"
    clustering.write_boxes_ply(pd.DataFrame(columns=clustering.OBJECT_COLUMNS), out)
    lines = out.read_text().splitlines()
    assert lines[0] == "ply" and "element vertex 0" in lines and "element face 0" in lines
    assert lines[-1] == "end_header"
