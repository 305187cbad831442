"""The images branch end to end on the real Lund images (pycolmap SfM on 2 CPU cores, ~1 min)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pycolmap
import pytest

from flatlandia import classify
from snakemake_runner import smk


@pytest.fixture(scope="module")
def lund_run(repo, flat_root, tmp_path_factory):
    wd = tmp_path_factory.mktemp("lund")
    res = smk(repo, wd, "--cores", "2", "results/lund/sfm/classified_points.parquet", "results/lund/sfm/sfm_summary.png",
              "--config", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return wd


@pytest.mark.slow
def test_lund_audit_masks_and_sfm(lund_run):
    wd = lund_run
    audit = pd.read_parquet(wd / "results/lund/images/images.parquet")
    assert len(audit) == 29 and audit["kept"].all() and audit["heading"].notna().all()
    masks = sorted(p.name for p in (wd / "results/lund/segment/masks").glob("*.png"))
    assert len(masks) == 29 and masks[0] == "01.jpg.png"  # the naming pycolmap's mask_path reads
    stats = pd.read_parquet(wd / "results/lund/sfm/sfm_stats.parquet").iloc[0]
    assert stats["registered"] >= 27 and stats["points3D"] > 800
    assert stats["mean_reprojection_error_px"] < 1.0
    model = pycolmap.Reconstruction(str(wd / "results/lund/sfm/model"))  # a COLMAP binary model
    assert model.num_reg_images() == stats["registered"]
    log = (wd / "logs/sfm/lund.log").read_text()
    assert "global_pipeline" in log  # COLMAP's own output lands in the rule's log
    pts = pd.read_parquet(wd / "results/lund/sfm/classified_points.parquet")
    assert len(pts) == model.num_points3D()
    assert (pts["class_id"] == 255).all()  # the offline backend claims no object classes
    assert (wd / "results/lund/sfm/sfm_summary.png").read_bytes()[:4] == b"\x89PNG"
    ply = (wd / "results/lund/sfm/classified_points.ply").read_text().splitlines()
    assert ply[0] == "ply" and f"element vertex {len(pts)}" in ply


@pytest.mark.slow
def test_points_take_the_majority_class_of_their_observations(lund_run):
    model = pycolmap.Reconstruction(str(lund_run / "results/lund/sfm/model"))
    maps = {}
    for img in model.images.values():
        cam = model.cameras[img.camera_id]
        m = np.full((cam.height, cam.width), 255, dtype=np.uint8)
        m[:, : cam.width // 2] = 24  # left half of every image: street light
        maps[img.name] = m
    pts = classify.point_votes(model, maps).set_index("point3D_id")
    checked = 0
    for pid, p in list(model.points3D.items())[:300]:
        xs = [model.images[e.image_id].points2D[e.point2D_idx].xy[0] - model.cameras[
            model.images[e.image_id].camera_id].width / 2 for e in p.track.elements]
        if min(abs(x) for x in xs) < 2:  # an observation on the border of the two halves
            continue
        share = np.mean([x < 0 for x in xs])
        if share > 0.5:
            assert pts.loc[pid, "class_id"] == 24
            checked += 1
        elif share < 0.5:
            assert pts.loc[pid, "class_id"] == 255
    assert checked > 10


@pytest.mark.slow
def test_views_from_the_lund_model(lund_run):
    from flatlandia import imagequeries

    model = pycolmap.Reconstruction(str(lund_run / "results/lund/sfm/model"))
    views = imagequeries.views_from_colmap(model)
    assert len(views) == model.num_reg_images()
    for v in views[:5]:
        img = model.find_image_with_name(v.name)
        assert np.allclose(v.centre, img.projection_center(), atol=1e-6)
        assert np.allclose(v.viewing_direction, img.viewing_direction(), atol=1e-6)
        uv, z = imagequeries.project(v, np.array([model.points3D[i].xyz for i in v.obs_point_ids[:20]]))
        assert (z > 0).all() and np.median(np.linalg.norm(uv - v.obs_xy[:20], axis=1)) < 5  # pixels
