"""Beyond one frame (issue "Beyond one frame"): a GPS fix and sequences of frames.

Hand-made maps (fast): a constellation that appears at two places, so that one depth frame
cannot tell them apart, and a second frame (its pose from odometry) or a GPS fix that can; the
same through the city search, the localize API and `flatlandia localize` (--gps, --compass,
--sequence, and their bad values as one ERROR line); the protocol of the table (sequence rule,
simulated odometry and GPS, what the priors may hold) and the table itself. On the published
data (slow): the rows of rule beyond_scene on a few anchors of scene 7."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import published_scene

from flatlandia import cli, config, geo, localize, solver
from flatlandia.city import index, search
from flatlandia.classes import CLASSES
from flatlandia.sequences import evaluation, protocol, sequence_table
from flatlandia.solver.sequence import anchor_of, compose, relative_pose

# ---------------------------------------------------------------- hand-made scenes
LIGHT, POLE, SIGN = (
    CLASSES.index(c) for c in ("object--street-light", "object--support--pole", "object--traffic-sign")
)
BENCH, BIN, HYDRANT = (CLASSES.index(c) for c in ("object--bench", "object--trash-can", "object--fire-hydrant"))
#: the repeated constellation, in the frame of the anchor's camera at place A (at the origin, looking along +x)
PATTERN = np.array([[12.0, 4.0], [18.0, -5.0], [25.0, 7.0], [30.0, -2.0], [8.0, -9.0]])
PATTERN_CLS = np.array([LIGHT, POLE, SIGN, LIGHT, POLE])
#: a second constellation, of other classes, seen from the companion frame only
OTHER = np.array([[-6.0, 22.0], [2.0, 28.0], [10.0, 20.0], [-3.0, 32.0]])
OTHER_CLS = np.array([BENCH, BIN, HYDRANT, BENCH])
#: the anchor's true pose at place A and the companion's, 3.2 m away and turned 25 deg
ANCHOR = np.array([0.0, 0.0, 0.0])
COMPANION = np.array([3.0, 1.0, math.radians(25.0)])
#: where a scene with lon/lat lies
FRAME = geo.MetricFrame(2.3704, 48.8981)


class Rigid:
    """A rotation by ``theta`` then a translation by ``t``: of map points and of camera poses."""

    def __init__(self, theta_deg: float, t):
        self.theta = math.radians(theta_deg)
        c, s = math.cos(self.theta), math.sin(self.theta)
        self.r, self.t = np.array([[c, -s], [s, c]]), np.asarray(t, float)

    def points(self, xy) -> np.ndarray:
        return np.asarray(xy, float) @ self.r.T + self.t

    def pose(self, p) -> np.ndarray:
        p = np.asarray(p, float)
        return np.r_[self.r @ p[:2] + self.t, float(geo.wrap_angle(p[2] + self.theta))]


IDENTITY = Rigid(0.0, [0.0, 0.0])


def local_map(xy, pose) -> np.ndarray:
    """Objects seen from a camera at ``pose`` (x along its heading, y to its left), metres."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = np.asarray(xy, float) - np.asarray(pose[:2], float)
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def depth(local: np.ndarray) -> np.ndarray:
    """A depth local map as the solver takes it: bearings true, ranges divided by an unknown
    factor (here: normalised to a median range of 1)."""
    return local / np.median(np.hypot(local[:, 0], local[:, 1]))


def pose_error(x: float, y: float, theta: float, truth) -> tuple[float, float]:
    """(metres, degrees) between a pose and the truth (x, y, theta radians)."""
    return math.hypot(x - truth[0], y - truth[1]), math.degrees(abs(float(geo.wrap_angle(theta - truth[2]))))


def twin_places(companion_at: Rigid, b: Rigid):
    """A map holding the constellation at A (as given) and at B (moved by ``b``), and the second
    constellation only at the place ``companion_at`` (IDENTITY: A, or ``b``); the rows of the
    repeated constellation come first, in the same order whichever place holds the second. Returns
    (ref_xy, ref_cls, the anchor's true pose, the companion's)."""
    xy = np.vstack([PATTERN, b.points(PATTERN), companion_at.points(OTHER)])
    cls = np.r_[PATTERN_CLS, PATTERN_CLS, OTHER_CLS]
    return xy, cls, companion_at.pose(ANCHOR), companion_at.pose(COMPANION)


#: place B of the sequence's map: the constellation turned 90 deg, 224 m away
SEQ_B = Rigid(90.0, [200.0, 100.0])
#: place B of the GPS map: the constellation turned -40 deg, 300 m away
GPS_B = Rigid(-40.0, [300.0, 0.0])


def frames_of(place: Rigid):
    """The anchor's frame (the repeated constellation) and the companion's (the second one) at
    ``place`` (IDENTITY: A, or SEQ_B), as depth maps, at their true poses."""
    anchor, companion = place.pose(ANCHOR), place.pose(COMPANION)
    return (
        (depth(local_map(place.points(PATTERN), anchor)), PATTERN_CLS),
        (depth(local_map(place.points(OTHER), companion)), OTHER_CLS),
    )


# ---------------------------------------------------------------- one frame is ambiguous, two are not
def test_one_frame_cannot_tell_two_places_and_two_frames_can():
    """The anchor sees only the repeated constellation: its single-frame answer is the same pose
    whichever place is true (so wrong for one of them), and the other place is tied with it; the
    anchor with a companion frame that sees the second constellation (its true relative pose, told
    as odometry of sigma 5 cm / 0.5 deg) lands on the true place, within 1 m / 2 deg, both ways."""
    single = []
    for place in (IDENTITY, SEQ_B):
        ref_xy, ref_cls, anchor, companion = twin_places(place, SEQ_B)
        f0, f1 = frames_of(place)
        one = solver.locate(*f0, ref_xy, ref_cls, metric=False, alternatives=3)
        assert one.best is not None and one.alternatives
        best, runner = one.best, one.alternatives[0]
        at_a = pose_error(best.x, best.y, best.theta, ANCHOR)
        at_b = pose_error(best.x, best.y, best.theta, SEQ_B.pose(ANCHOR))
        assert min(at_a[0], at_b[0]) < 0.01 and min(at_a[1], at_b[1]) < 0.01  # one of the two places
        other = SEQ_B.pose(ANCHOR) if at_a[0] < 0.01 else ANCHOR
        assert max(pose_error(runner.x, runner.y, runner.theta, other)) < 0.01  # the runner-up: the other
        assert abs(runner.cost - best.cost) < 1e-6 and runner.behind < 1e-6  # tied: nothing tells them apart
        single.append((best.x, best.y, best.theta))

        rel = np.array([np.zeros(3), relative_pose(anchor, companion)])
        sigma = np.array([[0.0, 0.0], [0.05, math.radians(0.5)]])
        seq = solver.locate_sequence([f0, f1], rel, ref_xy, ref_cls, None, None, None, sigma, None, 2)
        assert seq.best is not None
        e_m, e_deg = pose_error(seq.best.x, seq.best.y, seq.best.theta, anchor)
        assert e_m < 1.0 and e_deg < 2.0, (place is IDENTITY, e_m, e_deg)
        assert len(seq.frames) == 2
        c_m, c_deg = pose_error(seq.frames[1].x, seq.frames[1].y, seq.frames[1].theta, companion)
        assert c_m < 1.0 and c_deg < 2.0
        # the wrong place is not even a close second: its companion explains nothing there
        wrong = SEQ_B.pose(ANCHOR) if place is IDENTITY else ANCHOR
        for alt in seq.alternatives:
            if pose_error(alt.x, alt.y, alt.theta, wrong)[0] < 1.0:
                assert alt.cost > seq.best.cost + 10.0
    assert np.allclose(single[0], single[1])  # the same answer for either truth: wrong for one of them


@pytest.mark.parametrize("with_model", [False, True])
def test_two_identical_places_are_ambiguous_until_a_fix_or_a_second_frame(with_model):
    """One frame of the repeated constellation: the best pose and its first alternative are the two
    places, each with a probability of about 0.5, so the answer is `ambiguous` with both; a GPS fix
    or the companion frame leaves one place, `ok` at a probability near 1. With and without the
    likelihood ratio against chance (a flat model: p_d 0.3 everywhere)."""
    from test_likelihood import flat_model

    priors = solver.TrainingPriors(likelihood=flat_model()) if with_model else None
    threshold = config.section_defaults("solver")["answer_probability"]
    ref_xy, ref_cls, anchor, companion = twin_places(IDENTITY, SEQ_B)
    f0, f1 = frames_of(IDENTITY)
    one = solver.locate(*f0, ref_xy, ref_cls, metric=False, priors=priors, alternatives=3)
    best, runner = one.best, one.alternatives[0]
    places = sorted(
        min(pose_error(s.x, s.y, s.theta, p)[0] for s in (best, runner)) for p in (ANCHOR, SEQ_B.pose(ANCHOR))
    )
    assert places[1] < 0.01  # the two answers are the two places
    assert best.probability == pytest.approx(0.5, abs=0.05) and runner.probability == pytest.approx(0.5, abs=0.05)
    status = localize.answer_status(best, threshold)
    assert status["status"] == "ambiguous" and status["probability"] == pytest.approx(best.probability)

    fix = solver.Fix(anchor[0] + 15.0, anchor[1] - 10.0, 25.0)
    fixed = solver.locate(*f0, ref_xy, ref_cls, metric=False, priors=priors, alternatives=3, fix=fix)
    assert max(pose_error(fixed.best.x, fixed.best.y, fixed.best.theta, anchor)) < 1.0
    assert fixed.best.probability > 0.95 and localize.answer_status(fixed.best, threshold)["status"] == "ok"

    rel = np.array([np.zeros(3), relative_pose(anchor, companion)])
    sigma = np.array([[0.0, 0.0], [0.05, math.radians(0.5)]])
    seq = solver.locate_sequence([f0, f1], rel, ref_xy, ref_cls, None, priors, None, sigma, None, 2)
    assert max(pose_error(seq.best.x, seq.best.y, seq.best.theta, anchor)) < 1.0
    assert seq.best.probability > 0.95 and localize.answer_status(seq.best, threshold)["status"] == "ok"


def test_a_sequence_tolerates_odometry_noise():
    """The companion's relative pose off by 10 cm and 1 deg (its sigma saying so): still the
    true place, within 1 m / 2 deg."""
    ref_xy, ref_cls, anchor, companion = twin_places(SEQ_B, SEQ_B)
    f0, f1 = frames_of(SEQ_B)
    rel = np.array([np.zeros(3), relative_pose(anchor, companion) + [0.08, -0.06, math.radians(1.0)]])
    sigma = np.array([[0.0, 0.0], [0.15, math.radians(1.5)]])
    seq = solver.locate_sequence([f0, f1], rel, ref_xy, ref_cls, None, None, None, sigma)
    e_m, e_deg = pose_error(seq.best.x, seq.best.y, seq.best.theta, anchor)
    assert e_m < 1.0 and e_deg < 2.0


# ---------------------------------------------------------------- a GPS fix picks the place
def gps_map():
    """Two copies of the constellation 300 m apart (B turned by -40 deg) and the query seen at A."""
    ref_xy = np.vstack([PATTERN, GPS_B.points(PATTERN)])
    ref_cls = np.r_[PATTERN_CLS, PATTERN_CLS]
    return ref_xy, ref_cls, (depth(local_map(PATTERN, ANCHOR)), PATTERN_CLS)


def test_a_gps_fix_picks_the_right_one_of_two_identical_places():
    ref_xy, ref_cls, q = gps_map()
    none = solver.locate(*q, ref_xy, ref_cls, metric=False, alternatives=2)
    poses = [none.best, *none.alternatives]
    found = sorted(min(pose_error(s.x, s.y, s.theta, t)[0] for s in poses[:2]) for t in (ANCHOR, GPS_B.pose(ANCHOR)))
    assert found[1] < 0.01  # the two best answers are the two places
    assert none.alternatives[0].behind < 1e-6  # tied
    for truth in (ANCHOR, GPS_B.pose(ANCHOR)):
        fix = solver.Fix(truth[0] + 15.0, truth[1] - 10.0, 25.0)
        with_fix = solver.locate(*q, ref_xy, ref_cls, metric=False, alternatives=2, fix=fix)
        e_m, e_deg = pose_error(with_fix.best.x, with_fix.best.y, with_fix.best.theta, truth)
        assert e_m < 1.0 and e_deg < 2.0
        # the other copy lies beyond the fix's gate (4 sigma): no alternative there
        assert all(math.hypot(a.x - fix.x, a.y - fix.y) < fix.gate_m + 1 for a in with_fix.alternatives)


def test_a_gps_fix_picks_the_place_in_the_city_search():
    """The same two places as a city: an index with a training view at each; the fix's region is
    searched and the camera lands at the copy the fix is near."""
    ref_xy, ref_cls, q = gps_map()
    ref = pd.DataFrame(
        {"obj_idx": np.arange(len(ref_xy)), "class_id": ref_cls, "x_m": ref_xy[:, 0], "y_m": ref_xy[:, 1]}
    )
    view_a = np.array([2.0, 1.0, math.radians(5.0)])
    view_b = GPS_B.pose(view_a)
    views = pd.DataFrame(
        {
            "token": ["a", "b"],
            "x_m": [view_a[0], view_b[0]],
            "y_m": [view_a[1], view_b[1]],
            "theta_deg": np.degrees([view_a[2], view_b[2]]),
            "ref_idx": [list(range(5)), list(range(5, 10))],
        }
    )
    ix = index.build(ref, views)
    cfg, settings = search.SearchConfig.from_dict({}), solver.SolverConfig.from_dict({})
    for truth in (ANCHOR, GPS_B.pose(ANCHOR)):
        fix = solver.Fix(truth[0] + 15.0, truth[1] - 10.0, 25.0)
        found = search.search_city(ix, *q, cfg, settings, None, False, 2, fix=fix)
        assert found.solution is not None
        e_m, e_deg = pose_error(found.solution.x, found.solution.y, found.solution.theta, truth)
        assert e_m < 1.0 and e_deg < 2.0
        assert set(found.rows.tolist()) == (set(range(5)) if truth is ANCHOR else set(range(5, 10)))


# ---------------------------------------------------------------- the protocol
def protocol_queries() -> pd.DataFrame:
    """A scene's queries: the test anchor t0 at the origin, others around it (two tied at 7 m)."""
    rows = [
        ("t0", "test", 0.0, 0.0),
        ("train5", "train", 5.0, 0.0),
        ("val2", "val", 0.0, 2.0),
        ("tie-b", "train", 0.0, -7.0),
        ("tie-a", "train", -7.0, 0.0),
        ("t10", "test", 10.0, 0.0),
        ("far", "train", 40.0, 0.0),
    ]
    q = pd.DataFrame(rows, columns=["token", "split", "x_m", "y_m"])
    return q.assign(scene="9", theta_deg=np.arange(len(q)) * 10.0, ref_idx=[[k % 3, 3] for k in range(len(q))])


def test_sequence_rows_pick_the_nearest_companions():
    q = protocol_queries()
    rows = protocol.sequence_rows(q, "test", companions=10, radius_m=30.0)
    tokens = [[q["token"][j] for j in r] for r in rows]
    assert tokens == [
        ["t0", "val2", "train5", "tie-a", "tie-b", "t10"],  # nearest first, ties by token, any split, not "far"
        ["t10", "train5", "t0", "val2", "tie-b", "tie-a", "far"],  # "far" is exactly 30 m away: within
    ]
    assert protocol.sequence_rows(q, "test", companions=2, radius_m=30.0)[0] == [0, 2, 1]
    assert protocol.sequence_rows(q, "test", companions=5, radius_m=1.0) == [[0], [5]]  # an anchor alone
    assert [r[0] for r in protocol.sequence_rows(q, "train", 1, 30.0)] == [1, 3, 4, 6]  # only the split's anchors


def chain_poses() -> np.ndarray:
    return np.array([[3.0, -2.0, 0.3], [7.0, 1.0, 0.5], [10.0, 6.0, 1.2], [8.0, 12.0, 2.0]])


def test_odometry_without_noise_is_the_true_relative_poses():
    p = chain_poses()
    odo = protocol.odometry(p, np.random.default_rng(0), 0.0, 0.0)
    assert np.all(odo.rel[0] == 0) and np.all(odo.sigma[0] == 0)
    for f in range(1, len(p)):
        np.testing.assert_allclose(odo.rel[f], relative_pose(p[0], p[f]), atol=1e-12)
        np.testing.assert_allclose(compose(p[0], odo.rel[f])[0], p[f], atol=1e-12)
        np.testing.assert_allclose(anchor_of(p[f], odo.rel[f])[0], p[0], atol=1e-12)
        assert odo.sigma[f, 0] == protocol.MIN_SIGMA_M and odo.sigma[f, 1] == pytest.approx(
            math.radians(protocol.MIN_SIGMA_DEG)
        )


def test_odometry_is_seeded_and_its_noise_as_documented():
    p = chain_poses()

    def draw(seed, token="t0"):
        return protocol.odometry(p, protocol.rng_for(seed, protocol.ODOMETRY, "9", token), 2.0, 1.0)

    a, b = draw(0), draw(0)
    np.testing.assert_array_equal(a.rel, b.rel)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    assert not np.allclose(a.rel, draw(1).rel) and not np.allclose(a.rel, draw(0, "t10").rel)
    assert np.all(np.diff(a.sigma[1:, 0]) > 0) and np.all(np.diff(a.sigma[1:, 1]) > 0)  # grows along the chain
    # one step of 10 m: sigma 2 % of it (0.2 m) on forward and left, 1 deg on the turn
    step = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    draws = np.array([protocol.odometry(step, protocol.rng_for(s, 1, "9", "x"), 2.0, 1.0).rel[1] for s in range(2000)])
    err = draws - [10.0, 0.0, 0.0]
    assert np.std(err[:, 0]) == pytest.approx(0.2, rel=0.1) and np.std(err[:, 1]) == pytest.approx(0.2, rel=0.1)
    assert np.degrees(np.std(err[:, 2])) == pytest.approx(1.0, rel=0.1)
    assert abs(np.mean(err[:, 0])) < 0.03
    assert protocol.odometry(step, protocol.rng_for(0, 1, "9", "x"), 2.0, 1.0).sigma[1] == pytest.approx(
        [0.2, math.radians(1.0)]
    )


def test_gps_draws_are_shared_by_the_sigmas():
    truth = np.array([12.0, -3.0])
    d = protocol.gps_draw(0, "9", "t0")
    np.testing.assert_array_equal(d, protocol.gps_draw(0, "9", "t0"))
    assert not np.allclose(d, protocol.gps_draw(1, "9", "t0")) and not np.allclose(d, protocol.gps_draw(0, "9", "t1"))
    assert not np.allclose(d, protocol.rng_for(0, protocol.ODOMETRY, "9", "t0").normal(0.0, 1.0, 2))
    f10, f50 = protocol.gps_fix(truth, d, 10.0), protocol.gps_fix(truth, d, 50.0)
    assert (f10.sigma_m, f50.sigma_m) == (10.0, 50.0) and f10.heading is None
    np.testing.assert_allclose(f50.xy - truth, 5.0 * (f10.xy - truth), atol=1e-12)  # the sigma alone
    np.testing.assert_allclose(f10.xy - truth, 10.0 * d, atol=1e-12)
    offsets = np.array([protocol.gps_draw(0, "9", f"t{k}") for k in range(2000)])
    assert np.std(offsets, axis=0) == pytest.approx([1.0, 1.0], rel=0.1)


def test_leave_out_removes_exactly_the_companions_cameras():
    q = protocol_queries()
    ref = pd.DataFrame({"obj_idx": np.arange(4)})
    full = solver.scene_priors(ref, q, {"covis_weight": 2.0}, solver.LearnedPriors(scale=(2.0, 0.5)))
    train = q[q["split"] == "train"].reset_index(drop=True)
    assert len(full.cameras) == len(train) == 4
    out = protocol.leave_out(full, q, ["tie-b", "val2", "t10"])  # a train companion, a val and a test one
    kept = train[train["token"] != "tie-b"]
    np.testing.assert_array_equal(out.cameras[:, :2], kept[["x_m", "y_m"]].to_numpy())
    np.testing.assert_array_equal(out.seen, full.seen[kept.index.to_numpy()])
    assert out.scale == full.scale
    assert protocol.leave_out(full, q, ["val2", "t10"]) is full  # no training camera among them
    gone = protocol.leave_out(full, q, train["token"])
    assert gone.cameras is None and gone.seen is None and gone.scale == full.scale
    assert protocol.leave_out(None, q, ["tie-b"]) is None


# ---------------------------------------------------------------- the API and the command
def write_map(path: Path, xy, cls) -> Path:
    """A map of classed points with lon/lat (GeoJSON, no metadata: a user's map)."""
    lonlat = FRAME.to_lonlat(xy)
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [float(lo), float(la)]},
            "properties": {"class": CLASSES[int(c)]},
        }
        for (lo, la), c in zip(lonlat, cls)
    ]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    return path


def lonlat_error(out: dict, truth) -> tuple[float, float]:
    """(metres, degrees) between an answer (lon, lat, compass heading) and a true pose of FRAME."""
    xy = FRAME.to_xy(np.array([[out["lon"], out["lat"]]]))[0]
    heading = (90.0 - math.degrees(truth[2])) % 360.0
    return math.hypot(*(xy - truth[:2])), abs((out["heading_deg"] - heading + 180.0) % 360.0 - 180.0)


def lonlat_of(xy) -> tuple[float, float]:
    lon, lat = FRAME.to_lonlat(np.asarray(xy, float)[None])[0]
    return float(lon), float(lat)


def run_cli(capsys, *args) -> tuple[int, str, str]:
    status = cli.main(["localize", *map(str, args)])
    out = capsys.readouterr()
    return status, out.out, out.err


@pytest.fixture(scope="module")
def gps_files(tmp_path_factory):
    """The two-copies map as a GeoJSON and the query seen at A (GT, metres)."""
    tmp = tmp_path_factory.mktemp("gps")
    ref_xy, ref_cls, _ = gps_map()
    q = tmp / "q.json"
    q.write_text(json.dumps(localize.query_json(local_map(PATTERN, ANCHOR), PATTERN_CLS)))
    return write_map(tmp / "twins.geojson", ref_xy, ref_cls), q


def test_the_command_with_a_gps_fix_picks_the_copy(gps_files, capsys):
    twins, q = gps_files
    status, text, _ = run_cli(capsys, "--map", twins, "--query", q)
    plain = json.loads(text)
    assert status == 0 and plain["found"] and "gps" not in plain["priors"]
    places = [plain, *plain["alternatives"]][:2]
    assert sorted(min(lonlat_error(p, t)[0] for p in places) for t in (ANCHOR, GPS_B.pose(ANCHOR)))[1] < 0.05
    for truth in (ANCHOR, GPS_B.pose(ANCHOR)):
        lon, lat = lonlat_of(truth[:2] + [15.0, -10.0])
        status, text, err = run_cli(capsys, "--map", twins, "--query", q, "--gps", f"{lon},{lat}", "--gps-sigma-m", 25)
        out = json.loads(text)
        assert status == 0 and out["found"] and err == ""
        e_m, e_deg = lonlat_error(out, truth)
        assert e_m < 1.0 and e_deg < 2.0
        assert out["priors"]["gps"] == {"lon": lon, "lat": lat, "sigma_m": 25.0}
    # a compass heading too: recorded with the fix, the pose the same
    heading = (90.0 - math.degrees(GPS_B.theta)) % 360.0
    lon, lat = lonlat_of(GPS_B.pose(ANCHOR)[:2])
    status, text, _ = run_cli(
        capsys,
        "--map",
        twins,
        "--query",
        q,
        "--gps",
        f"{lon},{lat}",
        "--gps-sigma-m",
        25,
        "--compass",
        heading,
        "--compass-sigma-deg",
        15,
    )
    out = json.loads(text)
    assert status == 0 and max(lonlat_error(out, GPS_B.pose(ANCHOR))) < 1.0
    assert out["priors"]["gps"]["compass_deg"] == pytest.approx(heading)
    assert out["priors"]["gps"]["compass_sigma_deg"] == 15.0


def sequence_doc(place: Rigid, unit: float = 3.7) -> dict:
    """A sequence file's JSON: the anchor's objects and the companion's, in some unit (depth), the
    companion's pose in the anchor's camera frame (what odometry reports)."""
    (x0, c0), (x1, c1) = frames_of(place)
    rel = relative_pose(place.pose(ANCHOR), place.pose(COMPANION))
    return {
        "frames": [
            {"id": "anchor", **localize.query_json(x0 * unit, c0)},
            {
                "id": "next",
                **localize.query_json(x1 * unit, c1),
                "pose": {"x": float(rel[0]), "y": float(rel[1]), "theta_deg": math.degrees(rel[2])},
            },
        ]
    }


@pytest.fixture(scope="module")
def sequence_files(tmp_path_factory):
    """The sequence's map (the second constellation at B: the true place) and its files."""
    tmp = tmp_path_factory.mktemp("seq")
    ref_xy, ref_cls, anchor, companion = twin_places(SEQ_B, SEQ_B)
    doc = sequence_doc(SEQ_B)
    seq = tmp / "seq.json"
    seq.write_text(json.dumps(doc))
    q = tmp / "q.json"
    q.write_text(json.dumps({"objects": doc["frames"][0]["objects"]}))
    return write_map(tmp / "twins.geojson", ref_xy, ref_cls), seq, q, anchor, companion


def test_the_command_localizes_a_sequence(sequence_files, capsys):
    m, seq, q, anchor, companion = sequence_files
    status, text, err = run_cli(capsys, "--map", m, "--sequence", seq, "--map-type", "depth")
    out = json.loads(text)
    assert status == 0 and out["found"] and err == ""
    assert [f["id"] for f in out["frames"]] == ["anchor", "next"]
    assert (out["lon"], out["lat"]) == pytest.approx((out["frames"][0]["lon"], out["frames"][0]["lat"]), abs=1e-9)
    assert max(lonlat_error(out, anchor)) < 1.0
    assert max(lonlat_error(out["frames"][0], anchor)) < 1.0 and max(lonlat_error(out["frames"][1], companion)) < 1.0
    assert out["frames"][0]["scale"] == pytest.approx(out["scale"])
    assert out["priors"]["sequence"] == {"frames": 2} and out["map_type"] == "depth"
    # the API gives the same; the anchor alone is one of the two places, tied with the other
    api = localize.localize_sequence(localize.load_map(m), localize.read_sequence(seq))
    assert (api["lon"], api["lat"]) == (out["lon"], out["lat"])
    status, text, _ = run_cli(capsys, "--map", m, "--query", q, "--map-type", "depth")
    one = json.loads(text)
    assert status == 0 and one["alternatives"][0]["behind"] < 1e-6
    places = sorted(lonlat_error(one, t)[0] for t in (ANCHOR, SEQ_B.pose(ANCHOR)))
    assert places[0] < 0.05 and places[1] > 100.0


def bad_values(tmp: Path, twins: Path, q: Path, seq: Path) -> dict:
    """name -> (arguments, what the one ERROR line says)."""
    doc = json.loads(seq.read_text())
    no_pose = tmp / "no_pose.json"
    no_pose.write_text(
        json.dumps({"frames": [doc["frames"][0], {k: v for k, v in doc["frames"][1].items() if k != "pose"}]})
    )
    m, g = ["--map", twins], ["--query", q]
    fix = ["--gps", "2.3704,48.8981", "--gps-sigma-m", "25"]
    return {
        "gps off the globe": ([*m, *g, "--gps", "1000,0", "--gps-sigma-m", "25"], ["--gps", "not lon, lat in degrees"]),
        "negative sigma": ([*m, *g, "--gps", "2.37,48.89", "--gps-sigma-m", "-1"], ["--gps-sigma-m", "not a positive"]),
        "sigma alone": ([*m, *g, "--gps-sigma-m", "-1"], ["--gps", "needs both"]),
        "gps without sigma": ([*m, *g, "--gps", "2.37,48.89"], ["--gps", "needs both"]),
        "gps not numbers": ([*m, *g, "--gps", "east,north", "--gps-sigma-m", "25"], ["--gps", "is not LON,LAT"]),
        "gps one number": ([*m, *g, "--gps", "2.37", "--gps-sigma-m", "25"], ["--gps", "is not LON,LAT"]),
        "sigma not a number": ([*m, *g, "--gps", "2.37,48.89", "--gps-sigma-m", "ten"], ["--gps-sigma-m", "'ten'"]),
        "sigma nan": ([*m, *g, "--gps", "2.37,48.89", "--gps-sigma-m", "nan"], ["--gps-sigma-m"]),
        "compass without sigma": ([*m, *g, *fix, "--compass", "90"], ["--compass", "needs both"]),
        "compass without gps": ([*m, *g, "--compass", "90", "--compass-sigma-deg", "10"], ["--compass", "GPS fix"]),
        "compass sigma zero": ([*m, *g, *fix, "--compass", "90", "--compass-sigma-deg", "0"], ["--compass-sigma-deg"]),
        "compass not a number": ([*m, *g, *fix, "--compass", "north", "--compass-sigma-deg", "5"], ["--compass"]),
        "gps and near": ([*m, *g, *fix, "--near", "2.37,48.89", "--radius-m", "50"], ["--gps", "not both"]),
        "radius not a number": ([*m, *g, "--near", "2.37,48.89", "--radius-m", "far"], ["--radius-m", "'far'"]),
        "alternatives not a number": ([*m, *g, "--alternatives", "many"], ["--alternatives", "'many'"]),
        "sequence on gt": ([*m, "--sequence", seq, "--map-type", "gt"], ["--map-type", "depth"]),
        "query and sequence": ([*m, *g, "--sequence", seq, "--map-type", "depth"], ["--query", "one of them"]),
        "neither": ([*m, "--map-type", "depth"], ["--query", "--sequence"]),
        "sequence and near": (
            [*m, "--sequence", seq, "--map-type", "depth", "--near", "2.37,48.89", "--radius-m", "50"],
            ["--near", "GPS fix"],
        ),
        "frame without pose": (
            [*m, "--sequence", no_pose, "--map-type", "depth"],
            ["no_pose.json", "frame 1", '"pose"'],
        ),
        "missing sequence": ([*m, "--sequence", tmp / "nope.json", "--map-type", "depth"], ["nope.json", "missing"]),
    }


def test_bad_values_are_one_error_line(sequence_files, tmp_path, capsys):
    twins, seq, q, _, _ = sequence_files
    for name, (args, says) in bad_values(tmp_path, twins, q, seq).items():
        status, out, text = run_cli(capsys, *args)
        lines = text.strip().splitlines()
        assert status == 1 and len(lines) == 1 and lines[0].startswith("ERROR: ") and out == "", (name, text, out)
        for s in says:
            assert s in lines[0], (name, lines[0])


def test_the_installed_command_has_no_traceback(sequence_files):
    twins, _, q, _, _ = sequence_files
    run = subprocess.run(
        [sys.executable, "-m", "flatlandia.cli", "localize", "--map", str(twins), "--query", str(q)]
        + ["--gps", "1000,0", "--gps-sigma-m", "25"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 1 and run.stdout == ""
    assert run.stderr.splitlines() == ["ERROR: --gps: (1000.0, 0.0) is not lon, lat in degrees"]


# ---------------------------------------------------------------- the table
def summary_row(map_name: str, frames: int, gps: float | None, camera: str, **over) -> dict:
    row = dict.fromkeys(sequence_table.COLUMNS, 50.0)
    row.update(
        map=map_name,
        objects=118 if map_name == "scene" else 2354,
        frames=frames,
        gps_sigma_m=float("nan") if gps is None else gps,
        camera_prior=camera,
        queries=215,
        mean_frames=float(frames),
        median_m=1.5,
        median_deg=2.0,
    )
    row.update(over)
    return row


def test_the_table_orders_its_rows():
    want = [
        ("scene", 1, None, "on"),
        ("scene", 2, None, "on"),
        ("scene", 5, None, "on"),
        ("scene", 1, 10.0, "on"),
        ("scene", 5, 10.0, "on"),
        ("scene", 1, 50.0, "on"),
        ("scene", 1, None, "off"),
        ("scene", 5, None, "off"),
        ("city-20", 1, None, "on"),
        ("city-20", 1, 25.0, "on"),
        ("simulated-100000", 1, None, "on"),
    ]
    shuffled = [want[k] for k in np.random.default_rng(3).permutation(len(want))]
    df = sequence_table.table([summary_row(*w) for w in shuffled])
    assert list(df.columns) == sequence_table.COLUMNS
    got = [
        (r.map, r.frames, None if np.isnan(r.gps_sigma_m) else r.gps_sigma_m, r.camera_prior) for r in df.itertuples()
    ]
    assert got == want


def test_the_markdown_escapes_and_quotes_orienternet_as_another_task():
    rows = [
        summary_row("scene", 5, None, "on", mean_frames=3.2, median_m=float("inf")),
        summary_row("scene", 1, 25.0, "off <b>|*x*"),
    ]
    df = sequence_table.table(rows)
    text = sequence_table.markdown(df, sequence_table.note("test", config.section_defaults("beyond")))
    lines = text.splitlines()
    table = [ln for ln in lines if ln.startswith("| ") and "OrienterNet" not in ln]
    n_cols = table[0].count(" | ") + 1
    body = [ln for ln in table[1:] if ln.startswith("| scene")]
    assert len(body) == 2 and all(ln.replace("\\|", "").count(" | ") + 1 == n_cols for ln in body)
    assert "<b>" not in text and "&lt;b&gt;" in text and "\\*x\\*" in text
    assert "| 5 (3.20) |" in body[0] and "| – / 2.00 |" in body[0]  # fewer frames on average; no finite median
    assert "| 25 |" in body[1] and "|  |" in body[0]  # the GPS sigma; empty without a fix
    assert "## OrienterNet, for scale: another task" in text and "Not a baseline of this task" in text
    assert "| single image with a prior | 1 | 14.4 / 48.7 / 61.7 | 21.0 / 55.0 / 70.2 |" in lines
    assert "| sequential | 10 | 29.7 / 73.3 / 91.2 | 46.6 / 88.3 / 96.5 |" in lines
    assert "30 m" in text and "2 %" in text  # the protocol in the note, from the config


def test_the_risk_coverage_and_reliability_figures_draw_each_map_and_frame_count():
    """Synthetic anchors of two maps at 1 and 5 frames (and rows the figures leave out: a fix, the
    camera prior off): one line per (map, frames) on each risk panel and on the reliability diagram,
    the threshold's dot where anchors are answered, labels from the data escaped for mathtext."""
    from flatlandia.sequences import sequence_figures

    rng = np.random.default_rng(0)
    rows = []
    for m in ("scene", "city-$20"):
        for k, gps, cam in ((1, None, "on"), (5, None, "on"), (1, 25.0, "on"), (5, None, "off")):
            p = rng.random(50)
            right = rng.random(50) < p
            rows.append(
                pd.DataFrame(
                    {
                        "map": m,
                        "frames": k,
                        "gps_sigma_m": np.nan if gps is None else gps,
                        "camera_prior": cam,
                        "probability": p,
                        "error_m": np.where(right, 1.0, np.where(rng.random(50) < 0.5, 800.0, 20.0)),
                        "error_deg": np.where(right, 1.0, 30.0),
                    }
                )
            )
    errors = pd.concat(rows, ignore_index=True)
    assert len(sequence_figures.curves(errors)) == 4
    fig = sequence_figures.risk_coverage_figure(errors, 0.7)
    for ax in fig.axes:
        solid = [ln for ln in ax.lines if ln.get_marker() in ("None", None, "")]
        assert len(solid) == 4 and len([ln for ln in ax.lines if ln.get_marker() == "o"]) == 4
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "city-\\$20, 5 frames" in labels and "scene, 1 frame" in labels
    scene_only = sequence_figures.risk_coverage_figure(errors[errors["map"] == "scene"], 0.7)
    assert len(scene_only.axes) == 1 and len(scene_only.axes[0].get_legend().get_texts()) == 2  # no other scene
    rel = sequence_figures.reliability_figure(errors)
    assert len(rel.axes[0].lines) == 5  # the diagonal and four curves
    assert all("ECE" in t.get_text() for t in rel.axes[0].get_legend().get_texts())
    sequence_figures.figures.pyplot().close("all")


# ---------------------------------------------------------------- the published data (slow)
@pytest.mark.slow  # the published data (flat_root)
def test_scene_rows_on_a_published_scene(flat_root):
    """Rule beyond_scene's rows on a few anchors of scene 7 (25 test queries): one frame is the single-frame solver
    with the scene's priors (the benchmark's path), a fix keeps the pose within its gate, the
    companions lie within the sequence radius, and the summaries make the table."""
    ref, q = published_scene(flat_root, "7")
    beyond = config.section_defaults("beyond")
    settings = [evaluation.Setting(1), evaluation.Setting(2), evaluation.Setting(2, 25.0)]
    n_test = int((q["split"] == "test").sum())
    every = max(1, n_test // 5)
    errors = evaluation.scene_errors([(ref, q)], settings, {}, beyond, None, seed=0, every=every)
    anchors = evaluation.anchors(q, "test", beyond, 0)[::every]
    assert len(errors) == 3 * len(anchors) and len(anchors) >= 4
    ref_xy, ref_cls = ref[["x_m", "y_m"]].to_numpy(float), ref["class_id"].to_numpy()
    priors = solver.scene_priors(ref, q, {}, None)
    for a in anchors:
        rows = errors[errors["token"] == a.token]
        rows = rows.assign(gps=rows["gps_sigma_m"].fillna(0.0)).set_index(["frames", "gps"])
        assert np.hypot(*(a.truth[1:, :2] - a.truth[0, :2]).T).max(initial=0.0) <= beyond["sequence_radius_m"]
        one = solver.locate(*a.frames[0], ref_xy, ref_cls, metric=False, priors=priors).best
        r1 = rows.loc[(1, 0.0)]
        assert (r1["x"], r1["y"]) == (one.x, one.y)
        assert rows.loc[(2, 0.0), "frames_used"] == min(2, len(a.frames))
        fix = protocol.gps_fix(a.truth[0, :2], a.draw, 25.0)
        r = rows.loc[(2, 25.0)]
        assert math.hypot(r["x"] - fix.x, r["y"] - fix.y) <= fix.gate_m + 1e-6
    assert errors["bound_error_m"].median() < 2.0  # the true matches place the anchors
    df = sequence_table.table(evaluation.summaries(errors, {"scene": len(ref)}))
    assert len(df) == 3 and list(df["frames"]) == [1, 2, 2] and df["queries"].eq(len(anchors)).all()
