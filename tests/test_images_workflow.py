"""The images branch end to end on the real Lund images (pycolmap SfM on 2 CPU cores, ~1 min)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import pandas as pd
import pycolmap
import pytest
from snakemake_runner import smk

from flatlandia import geo, scaled_rigid
from flatlandia.classes import CLASSES
from flatlandia.images import classify_points, gps_alignment, image_queries
from flatlandia.images.views import project, views_from_colmap
from flatlandia.objects import clustering, labels
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError

#: every test here runs Snakemake jobs or reads the published data (the slow lane)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def lund_run(repo, flat_root, lund, tmp_path_factory):
    wd = tmp_path_factory.mktemp("lund")
    sheet = pd.read_csv(repo / "config" / "scenes.tsv", sep="\t", dtype=str, keep_default_na=False)
    sheet.loc[sheet["scene"] == "lund", "path"] = str(lund)  # ../shared/images/lund, else as fetched
    sheet.to_csv(wd / "scenes.tsv", sep="\t", index=False)
    res = smk(
        repo,
        wd,
        "--cores",
        "2",
        "results/lund/sfm/classified_points.parquet",
        "results/lund/sfm/sfm_summary.png",
        "results/lund/queries/queries.parquet",
        "results/lund/maps/reference_map.geojson",
        "results/lund/localization/localization.parquet",
        "--configfile",
        str(repo / "config/test/images_lund.yaml"),  # the solver only: no benchmark model to train here
        "--config",
        f"flatlandia_root={flat_root}",
        f"scenes={wd / 'scenes.tsv'}",
    )
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
    ply = o3d.t.io.read_point_cloud(str(wd / "results/lund/sfm/classified_points.ply"))
    assert len(ply.point.positions) == len(pts) and (ply.point["class_id"].numpy().ravel() == 255).all()


@pytest.mark.slow
def test_points_take_the_majority_class_of_their_observations(lund_run):
    model = pycolmap.Reconstruction(str(lund_run / "results/lund/sfm/model"))
    maps = {}
    for img in model.images.values():
        cam = model.cameras[img.camera_id]
        m = np.full((cam.height, cam.width), 255, dtype=np.uint8)
        m[:, : cam.width // 2] = 24  # left half of every image: street light
        maps[img.name] = m
    pts = classify_points.point_votes(model, maps).set_index("point3D_id")
    checked = 0
    for pid, p in list(model.points3D.items())[:300]:
        xs = [
            model.images[e.image_id].points2D[e.point2D_idx].xy[0]
            - model.cameras[model.images[e.image_id].camera_id].width / 2
            for e in p.track.elements
        ]
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

    model = pycolmap.Reconstruction(str(lund_run / "results/lund/sfm/model"))
    views = views_from_colmap(model)
    assert len(views) == model.num_reg_images()
    for v in views[:5]:
        img = model.find_image_with_name(v.name)
        assert np.allclose(v.centre, img.projection_center(), atol=1e-6)
        assert np.allclose(v.viewing_direction, img.viewing_direction(), atol=1e-6)
        uv, z = project(v, np.array([model.points3D[i].xyz for i in v.obs_point_ids[:20]]))
        assert (z > 0).all() and np.median(np.linalg.norm(uv - v.obs_xy[:20], axis=1)) < 5  # pixels


@pytest.mark.slow
def test_lund_gps_alignment(lund_run):
    al = json.loads((lund_run / "results/lund/sfm/gps_alignment.json").read_text())
    stats = pd.read_parquet(lund_run / "results/lund/sfm/sfm_stats.parquet").iloc[0]
    assert al["cameras_with_gps"] == stats["registered"]  # every Lund image is geotagged
    assert al["median_residual_m"] < 7.0  # the target; consumer GPS errs by ~5 m
    assert al["inliers"] >= 0.8 * al["cameras_with_gps"]
    assert 0.1 < al["metres_per_sfm_unit"] < 100
    assert "compass_median_diff_deg" in al  # reported, not trusted (Lund's compasses disagree)


@pytest.mark.slow
def test_lund_offline_backend_gives_a_documented_empty_map(lund_run):
    wd = lund_run
    meta = files.read_parquet_metadata(wd / "results/lund/objects/objects.parquet")
    assert "no SfM point carries an object class" in meta["empty_because"]
    assert len(pd.read_parquet(wd / "results/lund/objects/objects.parquet")) == 0
    assert len(pd.read_parquet(wd / "results/lund/maps/reference_map.parquet")) == 0
    q = pd.read_parquet(wd / "results/lund/queries/queries.parquet")
    assert len(q) == 0 and {"token", "x_m", "theta_deg", "gt_local_xy_m", "split"} <= set(q.columns)
    assert "object points, 0 objects" in (wd / "logs/objects/lund.log").read_text()
    loc = wd / "results/lund/localization/localization.parquet"
    assert len(pd.read_parquet(loc)) == 0 and "no query" in files.read_parquet_metadata(loc)["empty_because"]
    assert "no localization rows" in (wd / "results/summary.md").read_text()


def _painted_label_maps(model, radius_sfm, n_objects=5, radius_px=12, min_sep_px=120, one_class=False):
    """Label images the test makes: groups of real SfM points (dense spots co-visible in one
    image, chosen far apart in it) painted with object classes around every observation of
    their points in every image (``one_class``: all groups the same class). Returns the label
    maps, the number of groups and instance maps (group k painted k + 1, 0 elsewhere)."""
    views = views_from_colmap(model)
    best = max(views, key=lambda v: len(v.obs_point_ids))
    all_ids = np.array(list(model.points3D.keys()))
    all_xyz = np.array([model.points3D[int(i)].xyz for i in all_ids])
    xyz = np.array([model.points3D[int(i)].xyz for i in best.obs_point_ids])
    dense = np.array([(np.linalg.norm(all_xyz - x, axis=1) < radius_sfm).sum() for x in xyz])
    chosen = []
    for k in np.argsort(-dense, kind="stable"):
        if all(np.linalg.norm(best.obs_xy[k] - best.obs_xy[c]) > min_sep_px for c in chosen):
            chosen.append(k)
        if len(chosen) == n_objects:
            break
    classes = [CLASSES.index(c) for c in ("object--support--pole", "object--street-light", "object--traffic-sign")]
    groups, group_of = {}, {}
    for g, c in enumerate(chosen):
        for pid in all_ids[np.linalg.norm(all_xyz - xyz[c], axis=1) < radius_sfm]:
            groups.setdefault(int(pid), classes[0 if one_class else g % len(classes)])
            group_of.setdefault(int(pid), g)
    yy, xx = np.mgrid[-radius_px : radius_px + 1, -radius_px : radius_px + 1]
    disk = yy**2 + xx**2 <= radius_px**2
    maps, instances = {}, {}
    for img in model.images.values():
        cam = model.cameras[img.camera_id]
        m = np.full((cam.height, cam.width), 255, dtype=np.uint8)
        inst = np.zeros((cam.height, cam.width), dtype=np.uint16)
        for p2 in img.points2D:
            if p2.has_point3D() and int(p2.point3D_id) in groups:
                ys, xs = int(round(p2.xy[1])) + yy[disk], int(round(p2.xy[0])) + xx[disk]
                ok = (ys >= 0) & (ys < cam.height) & (xs >= 0) & (xs < cam.width)
                m[ys[ok], xs[ok]] = groups[int(p2.point3D_id)]
                inst[ys[ok], xs[ok]] = group_of[int(p2.point3D_id)] + 1
        maps[img.name], instances[img.name] = m, inst
    return maps, len(chosen), instances


@pytest.mark.slow
def test_lund_with_label_images_gives_objects_and_queries(lund_run):
    """The images back half on the real Lund model with label images made here."""
    wd = lund_run
    model = pycolmap.Reconstruction(str(wd / "results/lund/sfm/model"))
    alignment = json.loads((wd / "results/lund/sfm/gps_alignment.json").read_text())
    maps, _, _ = _painted_label_maps(model, radius_sfm=1.5 / alignment["metres_per_sfm_unit"])
    pts = classify_points.point_votes(model, maps)
    assert (pts["class_id"] != 255).sum() >= 20
    objs, member = labels.images_scene_objects("lund", pts, alignment, clustering.ClusterParams(eps_m=1.0), CLASSES)
    assert len(objs) >= 3 and set(objs["class_id"]) <= {
        CLASSES.index("object--support--pole"),
        CLASSES.index("object--street-light"),
        CLASSES.index("object--traffic-sign"),
    }
    cams = np.array([v.centre for v in views_from_colmap(model)])
    cam_xy = geo.alignment_points(alignment, cams)
    d = np.linalg.norm(objs[["x_m", "y_m"]].to_numpy()[:, None] - cam_xy[None], axis=2).min(1)
    assert (d < 60).all()  # objects sit along the walk, in metres on the aligned map
    objs["corners"] = [clustering.box_corners(r).tolist() for r in objs.itertuples(index=False)]
    point_object = {int(p): int(o) for p, o in zip(pts["point3D_id"], member) if o >= 0}
    point_xyz = {int(pid): np.asarray(p.xyz) for pid, p in model.points3D.items()}
    q = image_queries.scene_queries(
        "lund",
        views_from_colmap(model),
        objs,
        point_object,
        point_xyz,
        np.asarray(alignment["A"]),
        np.asarray(alignment["b"]),
        dict(zip(objs["object_id"], objs[["x_m", "y_m"]].to_numpy())),
        dict(zip(objs["object_id"], objs["class_id"])),
    )
    assert len(q) >= 1
    for r in q.itertuples(index=False):
        gt = np.asarray(r.gt_local_xy_m)
        assert gt.shape == (r.n_objects, 2) and (gt[:, 0] > 0).mean() >= 0.5  # objects mostly ahead (+x)
        dep = np.asarray(r.depth_local_xy_m)
        ok = np.isfinite(dep).all(1)
        ang = np.degrees(np.abs(np.arctan2(dep[ok, 1], dep[ok, 0]) - np.arctan2(gt[ok, 1], gt[ok, 0])))
        assert np.median(np.minimum(ang, 360 - ang)) < 10  # sparse depth keeps the bearings


@pytest.mark.slow
def test_local_frame_is_the_gps_map_up_to_a_rotation_and_scale(lund_run):
    """images.align.mode none on the real Lund model: the map on the SfM ground plane differs
    from the GPS-aligned one by a proper rotation, the SfM scale and a shift (no reflection), and
    objects keep their places on it with lon/lat NaN."""
    wd = lund_run
    model = pycolmap.Reconstruction(str(wd / "results/lund/sfm/model"))
    gps = json.loads((wd / "results/lund/sfm/gps_alignment.json").read_text())
    views = views_from_colmap(model)
    local = gps_alignment.local_frame(np.array([v.centre for v in views]), np.array([v.R for v in views]))
    assert geo.alignment_is_local(local) and geo.alignment_frame(local) is None
    X = np.array([p.xyz for p in model.points3D.values()])
    a, b = geo.alignment_points(local, X), geo.alignment_points(gps, X)
    fit = scaled_rigid.least_squares(a, b, allow_reflection=True)
    assert not fit.reflection
    assert fit.scale == pytest.approx(gps["metres_per_sfm_unit"], rel=1e-6)
    assert np.abs(fit.apply(a) - b).max() < 1e-6 * np.ptp(b)
    assert np.allclose(geo.alignment_points(local, np.array([v.centre for v in views])).mean(0), 0, atol=1e-9)
    maps, _, _ = _painted_label_maps(model, radius_sfm=1.5 / gps["metres_per_sfm_unit"])
    pts = classify_points.point_votes(model, maps)
    objs, _ = labels.images_scene_objects("lund", pts, local, clustering.ClusterParams(eps_m=1.0), CLASSES)
    assert len(objs) >= 3 and objs[["lon", "lat"]].isna().all().all()
    assert np.allclose(objs[["x_m", "y_m"]].to_numpy(), geo.alignment_points(local, objs[["cx", "cy", "cz"]]))


def test_photos_without_gps_in_local_frame_mode_give_a_local_map(repo, flat_root, lund, tmp_path):
    """The way forward the audit names for photos without GPS: images.align.mode none ends in an
    SfM model and a reference map in the SfM frame (unit stated, no lon/lat, no CRS)."""
    import geopandas as gpd

    photos = tmp_path / "photos"
    _photos_without_gps(lund, photos, [f"{k:02d}.jpg" for k in range(1, 6)])
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(f"scene\tsource\tcity\tname\tpath\turl\tsubfolder\nmine\timages\tLund\tmine\t{photos}\t\t\n")
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "2",
        "maps",
        "--config",
        f"flatlandia_root={flat_root}",
        f"scenes={sheet}",
        "select=[mine]",
        "images={align: {mode: none}}",
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Traceback" not in res.stderr
    model = pycolmap.Reconstruction(str(tmp_path / "results/mine/sfm/model"))
    assert model.num_reg_images() >= 3
    al = json.loads((tmp_path / "results/mine/sfm/gps_alignment.json").read_text())
    assert al["mode"] == "none" and al["crs"] is None and al["unit"] == "SfM unit"
    meta = files.read_parquet_metadata(tmp_path / "results/mine/maps/reference_map.parquet")
    assert meta["frame"] == "local" and meta["crs"] is None and "SfM unit" in meta["axes"]
    assert gpd.read_parquet(tmp_path / "results/mine/maps/reference_map.parquet").crs is None
    geo = json.loads((tmp_path / "results/mine/maps/reference_map.geojson").read_text())
    assert geo["flatlandia"]["frame"] == "local"
    q = files.read_parquet_metadata(tmp_path / "results/mine/queries/queries.parquet")
    assert q["frame"] == "local" and q["crs"] is None
    summary = (tmp_path / "results/summary.md").read_text()
    assert "local frame (SfM unit, no lon/lat)" in summary


@pytest.mark.slow
def test_lund_instance_images_split_merged_objects(lund_run, tmp_path):
    """Same-class objects that one cluster merges (a radius larger than the street) come apart
    again with instance images: one object per painted instance, through the PNG folder the
    workflow reads (segment.instances_dir) and the rule's files."""
    wd = lund_run
    model = pycolmap.Reconstruction(str(wd / "results/lund/sfm/model"))
    alignment = json.loads((wd / "results/lund/sfm/gps_alignment.json").read_text())
    maps, n_groups, inst_maps = _painted_label_maps(
        model, radius_sfm=1.5 / alignment["metres_per_sfm_unit"], one_class=True
    )
    from PIL import Image

    for name, ids in inst_maps.items():
        Image.fromarray(ids).save(tmp_path / f"{name.rsplit('.', 1)[0]}.png")
    names = [img.name for img in model.images.values()]
    obs = classify_points.point_instances(model, classify_points.load_instance_maps(tmp_path, names))
    assert set(obs["instance"]) == set(range(1, n_groups + 1)) and obs["key"].nunique() >= n_groups
    pts = classify_points.point_votes(model, maps)
    wide = clustering.ClusterParams(eps_m=500.0, eps_m_by_class={})  # every pole point in one cluster
    merged, _ = labels.images_scene_objects("lund", pts, alignment, wide, CLASSES)
    split, member = labels.images_scene_objects("lund", pts, alignment, wide, CLASSES, instances=obs)
    assert n_groups == 5 and len(merged) == 1 and len(split) == n_groups
    # each object holds the points of one painted instance
    inst_of = obs.groupby("point3D_id")["instance"].agg(lambda v: set(v))
    for oid in split["object_id"]:
        ids = pts["point3D_id"].to_numpy()[member == oid]
        seen = set().union(*(inst_of[i] for i in ids if i in inst_of.index))
        assert len(seen) == 1
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no instance image"):
        classify_points.load_instance_maps(empty, names)
    with pytest.raises(InputError, match="not a folder"):
        classify_points.load_instance_maps(tmp_path / "absent", names)


def test_editing_the_photo_folder_reruns_the_audit(repo, flat_root, lund, tmp_path):
    """The images folder is fingerprinted (names, sizes, times): metadata.csv edits and new photos
    rerun the audit; an untouched folder is up to date."""
    import shutil

    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("01.jpg", "02.jpg", "03.jpg"):
        shutil.copy(lund / name, photos / name)
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(f"scene\tsource\tcity\tname\tpath\turl\tsubfolder\nmine\timages\tLund\tmine\t{photos}\t\t\n")
    target = "results/mine/images/images.parquet"
    args = ["--config", f"flatlandia_root={flat_root}", f"scenes={sheet}"]
    assert smk(repo, tmp_path, "--cores", "1", target, *args).returncode == 0
    assert "Nothing to be done" in smk(repo, tmp_path, "-n", target, *args).stdout
    (photos / "metadata.csv").write_text("name,lat,lon\n01.jpg,55.70,13.19\n")
    assert "image_audit" in smk(repo, tmp_path, "-n", target, *args).stdout
    assert smk(repo, tmp_path, "--cores", "1", target, *args).returncode == 0
    # an edit in place leaves the folder's own time alone: the fingerprint param sees it
    with open(photos / "metadata.csv", "a") as f:
        f.write("02.jpg,55.71,13.19\n")
    res = smk(repo, tmp_path, "-n", target, *args)
    assert "image_audit" in res.stdout and "params" in res.stdout.lower(), res.stdout[-2000:]
    assert smk(repo, tmp_path, "--cores", "1", target, *args).returncode == 0
    shutil.copy(lund / "04.jpg", photos / "04.jpg")
    assert "image_audit" in smk(repo, tmp_path, "-n", target, *args).stdout
    # a manifest of this run, whose target is one artifact, not `all`
    flatlandia = str(Path(sys.executable).parent / "flatlandia")
    res = subprocess.run([flatlandia, "audit", "--write", "m.parquet"], cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 0 and res.stdout.startswith("wrote m.parquet: 1 artifacts"), res.stdout + res.stderr
    man = pd.read_parquet(tmp_path / "m.parquet")
    assert list(man["artifact"]) == [target] and man["rule"].iloc[0] == "image_audit"


def _photos_without_gps(src, dest, names):
    """Copies of photos with every EXIF tag (GPS included) stripped, as a privacy tool leaves them."""
    from PIL import Image

    dest.mkdir()
    for name in names:
        with Image.open(src / name) as im:
            im.convert("RGB").save(dest / name, quality=90)


@pytest.mark.parametrize("missing_gps", ["keep", "drop"])
def test_photos_without_gps_stop_at_the_audit_with_one_error(repo, flat_root, lund, tmp_path, missing_gps):
    photos = tmp_path / "photos"
    _photos_without_gps(lund, photos, [f"{k:02d}.jpg" for k in range(1, 6)])
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(f"scene\tsource\tcity\tname\tpath\turl\tsubfolder\nmine\timages\tLund\tmine\t{photos}\t\t\n")
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "1",
        "results/mine/maps/reference_map.parquet",
        "--config",
        f"flatlandia_root={flat_root}",
        f"scenes={sheet}",
        f"images={{missing_gps: {missing_gps}}}",
    )
    assert res.returncode != 0
    errors = [line for line in res.stderr.splitlines() if line.startswith("ERROR:")]
    want = "no image is left after the audit" if missing_gps == "drop" else "0 of the 5 kept images carry a GPS"
    assert len(errors) == 1 and want in errors[0], errors
    assert "metadata.csv" in errors[0] or missing_gps == "drop"  # keep: says how to give positions
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "results/mine/images").exists() and not (tmp_path / "results/mine/sfm").exists()
