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


# ---------------------------------------------------------------- --plot: one answer drawn on its map


def _drawn(path) -> np.ndarray:
    """A PNG's pixels (rows, columns, channels)."""
    from matplotlib import image

    return image.imread(path)


def test_plot_draws_the_answer_as_png_or_svg(tiny, tmp_path, capsys):
    """`--plot FILE` writes the answer drawn on its map, PNG or SVG by the suffix, beside the JSON on
    stdout: a file that is not empty and, for a PNG, not blank (the map's objects, the pose, the rays
    in colours of their own, not one colour); a sequence's answer and an answer without a pose too."""
    path, q = tiny
    r = q[q["split"] == "test"].iloc[0]
    for map_type, name in (("gt", "answer.png"), ("depth", "answer.svg")):
        plot = tmp_path / name
        status, out, err = _cli(
            capsys, "--map", path, "--query", _query(tmp_path, r, map_type), "--map-type", map_type, "--plot", plot
        )
        assert status == 0, out + err
        assert json.loads(out)["found"] and plot.stat().st_size > 0
    pixels = _drawn(tmp_path / "answer.png")
    assert pixels.ndim == 3 and pixels.shape[0] > 300 and pixels.shape[1] > 300
    colours = np.unique(np.round(pixels[..., :3].reshape(-1, 3), 2), axis=0)
    assert len(colours) > 20, len(colours)  # not blank: classes, the pose, rays, text
    dark = (pixels[..., :3].mean(axis=2) < 0.5).mean()
    assert 0.001 < dark < 0.5, dark
    svg = (tmp_path / "answer.svg").read_text()
    assert "<svg" in svg
    far = (r.lon, r.lat + 400.0 / M_PER_DEG_LAT)  # no pose: the map and the reason are drawn
    plot = tmp_path / "no_pose.png"
    gps = ("--gps", f"{far[0]},{far[1]}", "--gps-sigma-m", 25)
    status, out, err = _cli(capsys, "--map", path, "--query", _query(tmp_path, r), *gps, "--plot", plot)
    assert status == 0 and not json.loads(out)["found"] and plot.stat().st_size > 0


def test_plot_of_a_sequence_draws_its_frames(tiny, tmp_path, capsys):
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
    plot = tmp_path / "seq.png"
    status, out, err = _cli(capsys, "--map", path, "--sequence", seq, "--plot", plot)
    assert status == 0, out + err
    assert len(json.loads(out)["frames"]) == 2 and plot.stat().st_size > 0


def test_the_figure_lays_the_query_at_the_pose_with_its_alternatives(tiny, tmp_path):
    """The figure's marks: the query's objects laid at the answered pose (the truth's own local map
    at the truth lands on the map objects it saw), a ray from the camera to each, every alternative
    in the legend with its probability, the status and probability in the title."""
    from flatlandia.localize import answer_figure
    from flatlandia.report import figures

    path, q = tiny
    r = q[q["split"] == "test"].iloc[0]
    m = localize.load_map(path)
    query = localize.read_queries(_query(tmp_path, r))[0][0]
    truth = {"x_m": r.x_m, "y_m": r.y_m, "theta_deg": r.theta_deg, "scale": 1.0}
    seen = m.xy[[int(np.flatnonzero(m.obj_idx == o)[0]) for o in r.ref_idx]]
    assert np.allclose(answer_figure.placed(query, truth), seen, atol=0.5)
    answer = localize.localize(m, query, "gt", alternatives=3)
    fig = answer_figure.answer_figure(m, query, answer)
    try:
        title = fig._suptitle.get_text()
        assert answer["status"] in title and f"probability {answer['probability']:.2f}" in title
        ax = fig.axes[0]
        rays = [ln for ln in ax.lines if len(ln.get_xdata()) == 2 and ln.get_xdata()[0] == answer["x_m"]]
        assert len(rays) == len(query.cls)
        legend = [t.get_text() for t in fig.legends[0].get_texts()]
        alts = [t for t in legend if t.startswith("alternative ")]
        assert len(alts) == len(answer["alternatives"])
        for t, alt in zip(alts, answer["alternatives"], strict=True):
            assert f"probability {alt['probability']:.2f}" in t
    finally:
        figures.pyplot().close(fig)


@pytest.mark.parametrize(
    "extra, says",
    [
        (("--plot", "answer.jpg"), "answer.jpg: a plot is .png or .svg"),
        (("--plot", "answer.png", "--batch", "results", "--out", "poses.csv"), "--batch: localizes a whole split"),
        (("--plot", "folder.png"), "ERROR: --plot: folder.png "),  # the write door: a folder in the way
    ],
)
def test_a_bad_plot_is_one_error_line(tiny, tmp_path, capsys, monkeypatch, extra, says):
    path, q = tiny
    r = q[q["split"] == "test"].iloc[0]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder.png").mkdir()
    status, out, err = _cli(capsys, "--map", path, "--query", _query(tmp_path, r), *extra)
    assert status == 1 and out == "" and err.count("\n") == 1 and err.startswith("ERROR: ") and says in err, err
    assert not list(tmp_path.glob("answer.*")) and not (tmp_path / "poses.csv").exists()


def test_a_plot_of_many_queries_is_refused(tiny, tmp_path, capsys):
    path, q = tiny
    rows = list(q[q["split"] == "test"].itertuples(index=False))[:1] * 2
    many = tmp_path / "many.json"
    many.write_text(
        json.dumps(
            {
                "queries": [
                    {"id": str(k), **localize.query_json(localmaps.local_map(r, "gt"), r.classes)}
                    for k, r in enumerate(rows)
                ]
            }
        )
    )
    status, out, err = _cli(capsys, "--map", path, "--query", many, "--plot", tmp_path / "a.png")
    assert status == 1 and err.startswith("ERROR: --plot: draws one answer") and "holds 2 queries" in err, err
    assert not (tmp_path / "a.png").exists()


def test_without_matplotlib_the_plot_says_what_to_install(tiny, tmp_path, capsys, monkeypatch):
    """The localizer alone installs without matplotlib: --plot is then one ERROR line naming the
    extra that brings it, before any work, and nothing is written."""
    import sys

    path, q = tiny
    r = q[q["split"] == "test"].iloc[0]
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib raises ImportError
    plot = tmp_path / "answer.png"
    status, out, err = _cli(capsys, "--map", path, "--query", _query(tmp_path, r), "--plot", plot)
    assert status == 1 and out == "" and not plot.exists()
    assert err.count("\n") == 1 and err.startswith("ERROR: --plot: needs matplotlib") and "flatlandia[plot]" in err, err
