"""What `flatlandia localize` says beyond the pose (flatlandia.localize): a fix that rules out every
place says so, and a fix or --near position that looks swapped or lies off the map is a WARNING
(as `flatlandia score` warns on swapped coordinates); `--sequence` is of depth maps by default;
answers name their scene and city. On the tiny scene written as the workflow writes it (fast)."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import TINY_SCENE
from tiny_results import tiny_scene

from flatlandia import cli, geo, localize, score
from flatlandia.data import localmaps, reference_map
from flatlandia.plumbing import files

#: metres per degree of latitude (for a fix moved north)
M_PER_DEG_LAT = 111_200.0


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """results/0/maps/reference_map.parquet of a results folder holding the tiny scene, its queries
    and the benchmark record naming its city; and the test queries."""
    results = tmp_path_factory.mktemp("answers") / "results"
    tiny = tiny_scene()
    q = tiny.queries
    path = tiny.write(results)
    files.write_parquet(pd.DataFrame({"scene": [TINY_SCENE], "city": ["Flatland"]}), results / score.BENCHMARK_RECORD)
    return path, q


def _query(tmp_path, r, map_type="gt"):
    path = tmp_path / "q.json"
    path.write_text(json.dumps(localize.query_json(localmaps.local_map(r, map_type), r.classes)))
    return path


def _cli(capsys, *args):
    status = cli.main(["localize", *map(str, args)])
    out = capsys.readouterr()
    return status, out.out, out.err


def test_a_fix_that_rules_out_every_place_says_so(tiny, tmp_path, capsys):
    """A fix 400 m north of the camera (sigma 25 m): no pose, and the reason names the fix, its
    4 sigma and the nearest map object; the command warns that the fix lies beyond its reach.
    At the camera: a pose, no warning."""
    path, q = tiny
    r = q[q["split"] == "test"].iloc[0]
    far = (r.lon, r.lat + 400.0 / M_PER_DEG_LAT)
    status, out, err = _cli(
        capsys, "--map", path, "--query", _query(tmp_path, r), "--gps", f"{far[0]},{far[1]}", "--gps-sigma-m", 25
    )
    answer = json.loads(out)
    assert status == 0 and not answer["found"]
    assert answer["reason"].startswith(f"no pose: no map object within 4 sigma (100 m) of the fix at {far[0]}, ")
    assert "(the nearest is " in answer["reason"] and answer["reason"].endswith("is the fix right? lon/lat swapped?")
    assert err.startswith(f"WARNING: --gps {far[0]},{far[1]} is ") and "beyond its reach (250 m" in err
    assert answer["warnings"] and answer["warnings"][0] in err
    status, out, err = _cli(
        capsys, "--map", path, "--query", _query(tmp_path, r), "--gps", f"{r.lon},{r.lat}", "--gps-sigma-m", 25
    )
    answer = json.loads(out)
    assert status == 0 and answer["found"] and answer["warnings"] == [] and err == ""


def test_swapped_coordinates_are_a_warning(tiny, tmp_path, capsys):
    """lon and lat given the other way round (a fix, or --near): a WARNING naming the swap and how
    near the map the other reading lies; the fix's no-pose reason asks about it too."""
    path, q = tiny
    r = q[q["split"] == "test"].iloc[0]
    status, out, err = _cli(
        capsys, "--map", path, "--query", _query(tmp_path, r), "--gps", f"{r.lat},{r.lon}", "--gps-sigma-m", 25
    )
    answer = json.loads(out)
    assert status == 0 and not answer["found"] and "lon/lat swapped?" in answer["reason"]
    assert err.startswith(f"WARNING: --gps {r.lat},{r.lon}: lon and lat look swapped: read as {r.lon},{r.lat}")
    status, out, err = _cli(
        capsys, "--map", path, "--query", _query(tmp_path, r), "--near", f"{r.lat},{r.lon}", "--radius-m", 200
    )
    assert status == 0 and "WARNING: --near" in err and "look swapped" in err
    m = localize.load_map(path)
    assert localize.prior_warnings(m, near=(r.lon, r.lat), radius_m=200.0) == []


def test_a_sequence_is_of_depth_maps_by_default(tiny, tmp_path, capsys):
    """`--sequence` without --map-type localizes depth frames; --map-type gt is refused."""
    path, q = tiny
    a, b = list(q[q["split"] == "train"].itertuples(index=False))[:2]
    rel = geo.wrap_angle(np.radians(b.theta_deg - a.theta_deg))
    c, s = math.cos(math.radians(a.theta_deg)), math.sin(math.radians(a.theta_deg))
    dx, dy = b.x_m - a.x_m, b.y_m - a.y_m
    pose = {"x": c * dx + s * dy, "y": -s * dx + c * dy, "theta_deg": math.degrees(rel)}
    frames = [
        localize.query_json(localmaps.local_map(a, "depth"), a.classes),
        {**localize.query_json(localmaps.local_map(b, "depth"), b.classes), "pose": pose},
    ]
    seq = tmp_path / "seq.json"
    seq.write_text(json.dumps({"frames": frames}))
    status, out, err = _cli(capsys, "--map", path, "--sequence", seq)
    answer = json.loads(out)
    assert status == 0, out + err
    assert answer["map_type"] == "depth" and answer["priors"]["sequence"] == {"frames": 2}
    assert answer["found"] and math.hypot(answer["x_m"] - a.x_m, answer["y_m"] - a.y_m) < 5.0
    assert [f["scene"] for f in answer["frames"]] == [TINY_SCENE, TINY_SCENE]
    status, _, out = _cli(capsys, "--map", path, "--sequence", seq, "--map-type", "gt")
    assert status == 1 and out.startswith("ERROR: --map-type: a sequence is of depth local maps")


def test_answers_name_their_scene_and_city(tiny, tmp_path):
    """A scene map's answer (and each alternative) names the workflow's scene and its city (the
    benchmark record, tables/dataset_stats_per_scene.parquet); a map outside a results folder has none."""
    path, q = tiny
    m = localize.load_map(path)
    r = q[q["split"] == "test"].iloc[0]
    answer = localize.localize(m, localize.read_queries(_query(tmp_path, r, "depth"))[0][0], "depth", alternatives=3)
    assert (answer["scene"], answer["city"]) == (TINY_SCENE, "Flatland")
    assert all((a["scene"], a["city"]) == (TINY_SCENE, "Flatland") for a in answer["alternatives"])
    foreign = tmp_path / "mine.geojson"
    ref = pd.read_parquet(path)
    reference_map.write_geojson(ref, files.read_parquet_metadata(path), foreign)
    other = localize.localize(localize.load_map(foreign), localize.read_queries(_query(tmp_path, r))[0][0])
    assert other["found"] and (other["scene"], other["city"]) == (None, None)
