"""The fuzz suite of the input doors (issue 42): for every reader of docs/security.md's doors table, a
valid file built as the workflow writes it (the tiny scene, tests/data/tiny), mutated (cut, wrong
types, NaN/inf, 1e308 and 5,000 digits, deep nesting, YAML aliases and twice-given keys,
dictionary-encoded Parquet bombs, deflated zip members, FIFOs, folders, links, names with controls,
bidi overrides, ``..`` and ``/``) and read through the door's public entry.

The property, every door: the reader returns a checked object (what the test checks of it is written
beside each door) or raises the project's error (:class:`flatlandia.plumbing.errors.InputError`,
the config's ConfigError), one line without control characters; any other exception is a hole; the
reading within 2 s of CPU (stopped at 20 s of wall time), adding at most 900 MB to the process's peak
RSS (about 1.5 GB in all), and nothing written beside the input or in the working folder (each
example runs in a folder of its own; tests/fuzz_strategies.py: the budgets, the mutations).
Hypothesis keeps no database (``.hypothesis`` is never written).

Profiles (tests/fuzz_strategies.py): "fast", the default (a few hundred examples per door,
deterministic, the fast lane), and "long" (at least 20,000 examples over all doors, random):
``HYPOTHESIS_PROFILE=long pytest tests/test_fuzz_doors.py``, ``pytest -p fuzz_strategies
--hypothesis-profile=long ...`` (the profiles must be registered before pytest configures
Hypothesis), or ``python benchmarks/fuzz_doors.py``, which counts each door's examples and findings."""

from __future__ import annotations

import contextlib
import json
import math
import os
import pickle
import shutil
import tempfile
import unicodedata
from pathlib import Path

import fuzz_strategies as fz
import numpy as np
import pytest
import torch
from hypothesis import event, given, reject
from hypothesis import strategies as st

from flatlandia import checkpoints, config, localize, score, solver
from flatlandia.city import index
from flatlandia.classes import CLASSES
from flatlandia.data import localmaps, reference_map
from flatlandia.fine import models
from flatlandia.images import image_audit
from flatlandia.localize import batch
from flatlandia.plumbing import escape, names, provenance, validate
from flatlandia.plumbing.errors import InputError
from flatlandia.solver import calibration, likelihood, noise, verify

N_CLASSES = len(CLASSES)
#: characters no name and no terminal line may hold (escape.HIDDEN_CATEGORIES, written out here)
HIDDEN = {"Cc", "Cf", "Cs", "Zl", "Zp"}


# ----------------------------------------------------------------------------- the seeds


@pytest.fixture(scope="module", autouse=True)
def no_hypothesis_database():
    """The profiles keep no example database: no ``.hypothesis`` folder appears in the checkout."""
    repo = Path(__file__).resolve().parents[1]
    before = {p for p in (repo / ".hypothesis", repo / "tests" / ".hypothesis") if p.exists()}
    yield
    assert {p for p in (repo / ".hypothesis", repo / "tests" / ".hypothesis") if p.exists()} == before


class Seeds(dict):
    """A fixture's dict of seeds, shown by its keys (Hypothesis prints a failing test's arguments)."""

    def __repr__(self) -> str:
        return f"<seeds: {', '.join(map(str, self))}>"


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    """Where each example makes its files (a fresh folder each, removed after it)."""
    return tmp_path_factory.mktemp("fuzz")


@contextlib.contextmanager
def example(scratch: Path):
    """A fresh folder for one example, the working folder while it runs, removed after (kept with
    FUZZ_KEEP=1: the input of an example that crashed the process is the newest folder)."""
    d = Path(tempfile.mkdtemp(dir=scratch))
    cwd = os.getcwd()
    os.chdir(d)
    try:
        yield d
    finally:
        os.chdir(cwd)
        if not os.environ.get("FUZZ_KEEP"):
            shutil.rmtree(d, ignore_errors=True)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> dict:
    """The tiny scene as the workflow writes it: its reference map (Parquet table, GeoJSON document),
    a query, a file of queries and a sequence (as ``flatlandia localize`` reads them), the train
    split's poses, its city index arrays; every reader warmed up once (numba, torch)."""
    import pyarrow.parquet as pq
    from tiny_results import tiny_scene

    d = tmp_path_factory.mktemp("tiny_seeds")
    t = tiny_scene()
    ref, meta, q = t.ref, t.meta, t.queries
    reference_map.write_geoparquet(ref, meta, d / "map.parquet")
    reference_map.write_geojson(ref, meta, d / "map.geojson")
    test = q[q["split"] == "test"].iloc[0]
    query = localize.query_json(localmaps.local_map(test, "gt"), test.classes)
    train = q[q["split"] == "train"]
    many = {
        "queries": [
            localize.query_json(localmaps.local_map(r, "gt"), r.classes, str(r.token)) for r in train.itertuples()
        ]
    }
    frames = [localize.query_json(localmaps.local_map(r, "depth"), r.classes) for r in train.head(4).itertuples()]
    for k, f in enumerate(frames[1:], 1):
        f["pose"] = {"x": 1.5 * k, "y": 0.2 * k, "theta_deg": 3.0 * k}
    frames[1]["sigma_m"], frames[1]["sigma_deg"] = 0.5, 2.0
    ix = index.build(ref, train)
    localize.load_map(d / "map.parquet", learned=None)  # numba's kernels compiled once, before any deadline
    return Seeds(
        ref=ref,
        meta=meta,
        queries=q,
        table=pq.read_table(d / "map.parquet"),
        geojson=json.loads((d / "map.geojson").read_text()),
        query=query,
        many=many,
        sequence={"frames": frames},
        arrays={f: getattr(ix, f) for f in index._FIELDS},
        poses=train[["scene", "token", "x_m", "y_m", "theta_deg"]].reset_index(drop=True),
    )


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """The tiny scene's results folder as scoring reads it (tests/tiny_results.py)."""
    import tiny_results

    return Seeds(score.results_scenes(tiny_results.build(tmp_path_factory.mktemp("fuzz_results") / "results")))


def _priors_doc() -> dict:
    """A learned priors file with every part the solver reads: scale prior, verifier, likelihood
    model, calibration (single frames and sequences), a city's map-size correction and the noise
    model (with a scene's bearing correction)."""
    nf, nb = len(verify.FEATURES), len(likelihood.RANGE_EDGES_M) - 1
    na = len(likelihood.BEARING_EDGES_DEG) - 1
    lik = likelihood.LikelihoodModel(
        fov_half_deg=60.0,
        max_range_m=80.0,
        intercept=-1.0,
        cls_logit=(0.1,) * N_CLASSES,
        range_logit=(0.0,) * nb,
        bear_logit=(0.0,) * na,
        share_w=0.5,
        nocam_w=0.2,
        intercept0=-2.0,
        cls_logit0=(0.0,) * N_CLASSES,
        range_logit0=(0.0,) * nb,
        bear_logit0=(0.0,) * na,
        in_view=300,
    )
    model = noise.NoiseModel((2.0,) * nb, (0.3,) * nb, {"3": 0.2}, 100)
    cal = calibration.Calibration(
        calibration.Logistic(-1.0, (1.0, 0.5, 0.2, 0.3), 120),
        calibration.Logistic(-0.5, (0.8, 0.4, 0.1, 1.0), 60),
        calibration.MapSize(100.0, calibration.MapTerm(0.5, 0.1), calibration.MapTerm(0.4, 0.2), 50),
    )
    v = verify.Verifier(np.linspace(-1, 1, nf), np.zeros(nf), np.ones(nf))
    return solver.LearnedPriors((3.0, 0.4), v, lik, cal, model).to_dict()


PRIORS = _priors_doc()


# ----------------------------------------------------------------------------- shared checks


def refused(got) -> bool:
    event("refused" if isinstance(got, fz.Refused) else "accepted")
    return isinstance(got, fz.Refused)


def is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def numbers(v) -> bool:
    """``v`` a JSON number or a list of them (what a typed field of a record holds)."""
    return is_number(v) or (isinstance(v, list) and all(is_number(x) for x in v))


def json_depth(v) -> int:
    deepest, stack = 0, [(v, 1)]
    while stack:
        x, d = stack.pop()
        if isinstance(x, (dict, list)):
            deepest = max(deepest, d)
            stack.extend((c, d + 1) for c in (x.values() if isinstance(x, dict) else x))
    return deepest


def plain(v):
    """A mutated JSON value as Python data (what a YAML file or a torch pickle can hold): Raw
    numbers as floats, Raw nesting as nested lists (built without recursion)."""
    if isinstance(v, fz.Raw):
        t = v.text
        if t.startswith(("[", "{")):
            depth = len(t) - len(t.lstrip("[{"))
            out: object = 1
            for _ in range(min(depth, 5000)):  # deeper than any bound; a pickle of it still fails
                out = [out]
            return out
        try:
            return float(t)
        except ValueError:
            return t
    if isinstance(v, dict):
        return {k: plain(x) for k, x in v.items()}
    if isinstance(v, list):
        return [plain(x) for x in v]
    return v


def draw_file(data, raw: bytes, bound: int):
    """(bytes, file kind) of one example: ``raw`` maybe corrupted, and what the path is."""
    raw = data.draw(fz.corrupted(raw), label="bytes")
    kind = data.draw(fz.file_kind(), label="file kind")
    return raw, kind


# ----------------------------------------------------------------------------- the JSON door

JSON_SEEDS = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=10),
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=5), c, max_size=4),
    max_leaves=15,
)


def check_json(value) -> None:
    assert json_depth(value) <= validate.MAX_JSON_DEPTH
    stack = [value]
    while stack:
        x = stack.pop()
        if isinstance(x, int) and not isinstance(x, bool):
            assert x.bit_length() <= 100, "an integer longer than MAX_INT_DIGITS digits read as an integer"
        elif isinstance(x, dict):
            stack.extend(x.values())
        elif isinstance(x, list):
            stack.extend(x)


@fz.door_settings(1.5)
@given(data=st.data())
def test_json_door(scratch, data):
    """validate.parse_json / read_json: a JSON value nested at most MAX_JSON_DEPTH deep whose
    integers are at most MAX_INT_DIGITS digits (longer ones floats), or one InputError."""
    doc = data.draw(fz.mutated_json(data.draw(JSON_SEEDS, label="seed")), label="document")
    raw, kind = draw_file(data, fz.dumps(doc).encode("utf-8", "surrogatepass"), validate.MAX_JSON_BYTES)
    with example(scratch) as d:
        got = fz.door(lambda: validate.parse_json(raw, "doc.json"), (InputError,), (d,))
        if not refused(got):
            check_json(got)
        path = fz.place(d, "doc.json", raw, kind, validate.MAX_JSON_BYTES)
        got = fz.door(lambda: validate.read_json(path), (InputError,), (d,))
        if not refused(got):
            check_json(got)
            assert kind in ("file", "link", "empty"), f"a {kind} was read as JSON"


# ----------------------------------------------------------------------------- queries and sequences

QUERY_KEYS = ("objects", "class", "x", "y", "id", "queries", "frames", "pose", "theta_deg", "sigma_m", "sigma_deg")


def check_query(q, source_doc) -> None:
    n = len(q.xy)
    assert localize.MIN_OBJECTS <= n <= validate.MAX_QUERY_OBJECTS and q.xy.shape == (n, 2) and len(q.cls) == n
    assert np.isfinite(q.xy).all() and (np.abs(q.xy) <= validate.MAX_LOCAL_COORD).all()
    assert ((q.cls >= 0) & (q.cls < N_CLASSES)).all()
    if isinstance(source_doc, dict) and isinstance(source_doc.get("objects"), list):  # read as written
        for k, o in enumerate(source_doc["objects"]):
            assert is_number(o["x"]) and is_number(o["y"]) and isinstance(o["class"], str), o
            assert (float(o["x"]), float(o["y"])) == tuple(q.xy[k]) and CLASSES[q.cls[k]] == o["class"]


@fz.door_settings(1.5)
@given(data=st.data())
def test_query_door(tiny, scratch, data):
    """localize.read_queries: each query 3..MAX_QUERY_OBJECTS objects of known classes at finite
    coordinates within MAX_LOCAL_COORD, as the file wrote them; at most MAX_QUERIES queries."""
    seed = data.draw(st.sampled_from(["query", "many"]), label="seed")
    doc = data.draw(fz.mutated_json(tiny[seed], keys=QUERY_KEYS), label="document")
    raw, kind = draw_file(data, fz.dumps(doc).encode("utf-8", "surrogatepass"), validate.MAX_QUERY_JSON_BYTES)
    with example(scratch) as d:
        path = fz.place(d, "q.json", raw, kind, validate.MAX_QUERY_JSON_BYTES)
        got = fz.door(lambda: localize.read_queries(path), (InputError,), (d,))
        if refused(got):
            return
        queries, many = got
        parsed = fz.loads_plain(raw)
        assert 1 <= len(queries) <= validate.MAX_QUERIES
        for k, q in enumerate(queries):
            check_query(q, parsed["queries"][k] if many else parsed)


@fz.door_settings(1.0)
@given(data=st.data())
def test_sequence_door(tiny, scratch, data):
    """localize.read_sequence: at most MAX_SEQUENCE_FRAMES checked frames, odometry finite within
    MAX_ODOMETRY_M, turns within a full turn, every sigma finite and positive."""
    doc = data.draw(fz.mutated_json(tiny["sequence"], keys=QUERY_KEYS), label="document")
    raw, kind = draw_file(data, fz.dumps(doc).encode("utf-8", "surrogatepass"), validate.MAX_QUERY_JSON_BYTES)
    with example(scratch) as d:
        path = fz.place(d, "seq.json", raw, kind, validate.MAX_QUERY_JSON_BYTES)
        got = fz.door(lambda: localize.read_sequence(path), (InputError,), (d,))
        if refused(got):
            return
        parsed = fz.loads_plain(raw)
        assert 1 <= len(got.frames) <= validate.MAX_SEQUENCE_FRAMES
        for k, f in enumerate(got.frames):
            check_query(f, parsed["frames"][k])
        assert got.rel.shape == (len(got.frames), 3) and np.isfinite(got.rel).all()
        assert (np.abs(got.rel[:, :2]) <= validate.MAX_ODOMETRY_M).all() and (
            np.abs(got.rel[:, 2]) <= 2 * math.pi
        ).all()
        assert np.isfinite(got.sigma).all() and (got.sigma[1:] > 0).all()


# ----------------------------------------------------------------------------- bombs


@pytest.fixture(scope="module")
def map_bombs(tiny, tmp_path_factory) -> list[Path]:
    """Scene maps of 20,000 rows (MAX_MAP_OBJECTS) whose dictionary-encoded column decodes to 1.2 GB
    from 15 kB (the issue's 5 kB map reached 3.8 GB in localize)."""
    d = tmp_path_factory.mktemp("map_bombs")
    return [fz.dictionary_bomb(tiny["table"], d / "bomb.parquet", validate.MAX_MAP_OBJECTS, 60_000)]


@pytest.fixture(scope="module")
def poses_bombs(tiny, tmp_path_factory) -> list[Path]:
    """A poses Parquet of 200,000 rows (MAX_POSES_ROWS) whose dictionary-encoded column decodes to
    1.2 GB (the issue's 3 kB poses file reached 3.8 GB in score)."""
    import pyarrow as pa

    d = tmp_path_factory.mktemp("poses_bombs")
    table = pa.Table.from_pandas(tiny["poses"], preserve_index=False)
    return [fz.dictionary_bomb(table, d / "bomb.parquet", validate.MAX_POSES_ROWS, 6_000)]


# ----------------------------------------------------------------------------- scene maps


def check_map(m) -> None:
    n = len(m.xy)
    assert 1 <= n <= validate.MAX_MAP_OBJECTS and m.xy.shape == (n, 2) and len(m.cls) == n == len(m.obj_idx)
    assert np.isfinite(m.xy).all()
    assert ((m.cls >= 0) & (m.cls < N_CLASSES)).all()
    assert np.bincount(m.cls, minlength=N_CLASSES).max() <= validate.MAX_CLASS_OBJECTS
    assert len(np.unique(m.obj_idx)) == n
    if m.lonlat is not None:
        assert np.isfinite(m.lonlat).all() and (np.abs(m.lonlat[:, 0]) <= 180).all()
        assert (np.abs(m.lonlat[:, 1]) <= 90).all()


@fz.door_settings(0.75)
@given(data=st.data())
def test_map_parquet_door(tiny, scratch, map_bombs, data):
    """localize.load_map of a Parquet map: at least one and at most MAX_MAP_OBJECTS objects of
    known classes (at most MAX_CLASS_OBJECTS of one), unique ids, finite metres, lon/lat in range;
    a dictionary-encoded bomb refused before it is decoded."""
    with example(scratch) as d:
        path = d / "map.parquet"
        if data.draw(st.integers(0, 15), label="bomb?") == 0:
            shutil.copy(data.draw(st.sampled_from(map_bombs), label="bomb"), path)
        else:
            table = data.draw(fz.mutated_table(tiny["table"], fz.MAP_COLUMNS), label="table")
            fz.write_parquet(table, path, data.draw(fz.PARQUET_OPTIONS, label="writer"))
            raw, kind = draw_file(data, path.read_bytes(), validate.MAX_MAP_BYTES)
            path.unlink()
            fz.place(d, "map.parquet", raw, kind, validate.MAX_MAP_BYTES)
        got = fz.door(lambda: localize.load_map(path, learned=None), (InputError,), (d,))
        if not refused(got):
            check_map(got)


@fz.door_settings(0.75)
@given(data=st.data())
def test_map_geojson_door(tiny, scratch, data):
    """localize.load_map of a GeoJSON map: as the Parquet map."""
    keys = ("features", "geometry", "coordinates", "properties", "class", "class_id", "obj_idx", "flatlandia", "lon0")
    doc = data.draw(fz.mutated_json(tiny["geojson"], max_mutations=4, keys=keys), label="document")
    raw, kind = draw_file(data, fz.dumps(doc).encode("utf-8", "surrogatepass"), validate.MAX_MAP_BYTES)
    with example(scratch) as d:
        path = fz.place(d, "map.geojson", raw, kind, validate.MAX_MAP_BYTES)
        got = fz.door(lambda: localize.load_map(path, learned=None), (InputError,), (d,))
        if not refused(got):
            check_map(got)


# ----------------------------------------------------------------------------- poses files


def check_poses(p, scenes) -> None:
    t = p.table
    assert 1 <= len(t) <= validate.MAX_POSES_ROWS
    assert np.isfinite(t[["x_m", "y_m", "theta_deg"]].to_numpy(float)).all()
    known = {(s, str(k)) for s, b in scenes.items() for k in b.queries["token"]}
    assert set(zip(t["scene"], t["token"])) <= known


@fz.door_settings(1.0)
@given(data=st.data())
def test_poses_csv_door(tiny, scenes, scratch, data):
    """score.read_poses of a CSV (plain, gzip, bz2, xz): poses of known queries, finite metric
    poses, at most MAX_POSES_ROWS rows; a decompression bomb stopped at MAX_POSES_BYTES."""
    text = data.draw(fz.mutated_csv(tiny["poses"]), label="csv")
    suffix = data.draw(st.sampled_from([".csv", ".csv", ".csv.gz", ".csv.bz2", ".csv.xz"]), label="suffix")
    raw, kind = draw_file(data, fz.compress(text.encode("utf-8", "surrogatepass"), suffix), validate.MAX_POSES_BYTES)
    with example(scratch) as d:
        path = fz.place(d, f"poses{suffix}", raw, kind, validate.MAX_POSES_BYTES)
        got = fz.door(lambda: score.read_poses(path, scenes, "train"), (InputError,), (d,))
        if not refused(got):
            check_poses(got, scenes)


@fz.door_settings(0.75)
@given(data=st.data())
def test_poses_parquet_door(tiny, scenes, scratch, poses_bombs, data):
    """score.read_poses of a Parquet file: as the CSV; a dictionary-encoded bomb refused before it is decoded."""
    import pyarrow as pa

    with example(scratch) as d:
        path = d / "poses.parquet"
        if data.draw(st.integers(0, 15), label="bomb?") == 0:
            shutil.copy(data.draw(st.sampled_from(poses_bombs), label="bomb"), path)
        else:
            table = pa.Table.from_pandas(tiny["poses"], preserve_index=False)
            table = data.draw(fz.mutated_table(table, fz.POSES_COLUMNS), label="table")
            fz.write_parquet(table, path, data.draw(fz.PARQUET_OPTIONS, label="writer"))
            raw, kind = draw_file(data, path.read_bytes(), validate.MAX_POSES_BYTES)
            path.unlink()
            fz.place(d, "poses.parquet", raw, kind, validate.MAX_POSES_BYTES)
        got = fz.door(lambda: score.read_poses(path, scenes, "train"), (InputError,), (d,))
        if not refused(got):
            check_poses(got, scenes)


# ----------------------------------------------------------------------------- priors and calibration

PRIOR_KEYS = ("scale_prior", "verifier", "weights", "mean", "scale", "likelihood", "calibration", "frame", "sequence")


def check_calibration(cal, doc) -> None:
    """A calibration as the file typed it, whose probabilities are finite and in [0, 1]."""
    mass, objects = np.linspace(0, 1, 11), np.full(11, 17.0)
    for kind in calibration.KINDS:
        fit = getattr(cal, kind)
        if fit is None:
            continue
        rec = doc[kind]
        assert is_number(rec["intercept"]) and isinstance(rec["weights"], list), rec
        assert all(is_number(w) for w in rec["weights"]) and isinstance(rec["answers"], int), rec
        assert not isinstance(rec["answers"], bool) and rec["answers"] >= 0
        for frames in (1, 5):
            p = cal.probability(mass, objects, frames, 0.5)
            assert np.isfinite(p).all() and ((p >= 0) & (p <= 1)).all(), (kind, p)
    if cal.map_size is not None:
        check_map_size(cal.map_size, doc["map_size"])


def check_map_size(ms, doc) -> None:
    assert (
        is_number(doc["reference_objects"]) and isinstance(doc["answers"], int) and not isinstance(doc["answers"], bool)
    )
    for kind in ("frame", "sequence"):
        assert is_number(doc[kind]["shift"]) and is_number(doc[kind]["per_log_odds"]), doc[kind]
    p = ms.adjust(np.linspace(0, 1, 11), 1e6, 1)
    assert np.isfinite(p).all() and ((p >= 0) & (p <= 1)).all()


@fz.door_settings(1.5)
@given(data=st.data())
def test_priors_door(scratch, data):
    """solver.LearnedPriors.read: every part as the file typed it (numbers where numbers are
    written, no text read digit by digit, no list where an object is), finite, with spreads > 0;
    the calibration's probabilities finite and in [0, 1]."""
    doc = data.draw(fz.mutated_json(PRIORS, max_mutations=3, keys=PRIOR_KEYS), label="document")
    raw, kind = draw_file(data, fz.dumps(doc).encode("utf-8", "surrogatepass"), validate.MAX_JSON_BYTES)
    with example(scratch) as d:
        path = fz.place(d, "priors.json", raw, kind, validate.MAX_JSON_BYTES)
        got = fz.door(lambda: solver.LearnedPriors.read(path), (InputError,), (d,))
        if refused(got):
            return
        parsed = fz.loads_plain(raw)
        if got.scale is not None:
            assert numbers(parsed["scale_prior"]) and np.isfinite(got.scale).all() and got.scale[1] > 0
        if got.verifier is not None:
            for k in ("weights", "mean", "scale"):
                assert numbers(parsed["verifier"][k]) and np.isfinite(getattr(got.verifier, k)).all()
            assert (got.verifier.scale > 0).all()
        if got.likelihood is not None:
            assert isinstance(parsed["likelihood"], dict)
            assert all(numbers(v) for v in parsed["likelihood"].values()), parsed["likelihood"]
        if got.calibration is not None:
            assert isinstance(parsed["calibration"], dict)
            check_calibration(got.calibration, parsed["calibration"])


@fz.door_settings(1.0)
@given(data=st.data())
def test_city_calibration_door(scratch, data):
    """learned_priors.read_map_size (rule city_calibration's record): typed, finite, in its bounds."""
    from flatlandia.solver.learned_priors import read_map_size

    doc = data.draw(fz.mutated_json({"map_size": PRIORS["calibration"]["map_size"]}, keys=PRIOR_KEYS), label="doc")
    raw, kind = draw_file(data, fz.dumps(doc).encode("utf-8", "surrogatepass"), validate.MAX_JSON_BYTES)
    with example(scratch) as d:
        path = fz.place(d, "city_calibration.json", raw, kind, validate.MAX_JSON_BYTES)
        got = fz.door(lambda: read_map_size(path), (InputError,), (d,))
        if not refused(got):
            check_map_size(got, fz.loads_plain(raw)["map_size"])


# ----------------------------------------------------------------------------- checkpoints

CK_CONFIG = models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)


@pytest.fixture(scope="module")
def checkpoint_seed(tmp_path_factory) -> dict:
    """The tiny MLP's weights and config, and a checkpoint whose first weight deflates 1 GB of zeros
    into a few hundred kB (the issue's 2 GB in torch.load)."""
    d = tmp_path_factory.mktemp("ck_seed")
    state = models.build_model(CK_CONFIG).state_dict()
    meta = {"config": CK_CONFIG.to_dict()}
    good = d / "good.pt"
    torch.save({"format": checkpoints.FORMAT, "state_dict": state, "meta": json.dumps(meta)}, good)
    checkpoints.load_checkpoint(good, models.FineTrainConfig, models.build_model)  # torch warmed up
    bomb = fz.inflating_member(good, d / "bomb.pt", "/data/0", 10**9)
    return Seeds(state=state, meta=meta, good=good, bomb=bomb)


WEIGHT_CHANGES = ("nan", "inf", "shape", "float64", "int64", "bool", "half", "scalar", "empty")


def _changed(t: torch.Tensor, change: str) -> torch.Tensor:
    """A weight made wrong one way (:data:`WEIGHT_CHANGES`)."""
    if change in ("nan", "inf"):
        return torch.full_like(t.double(), math.nan if change == "nan" else -math.inf)
    if change == "shape":
        return torch.zeros(t.numel() + 1)
    if change == "scalar":
        return torch.tensor(1.0)
    if change == "empty":
        return torch.zeros(0)
    return t.to({"float64": torch.float64, "int64": torch.int64, "bool": torch.bool, "half": torch.float16}[change])


@st.composite
def checkpoint_payload(draw, seed: dict):
    """A checkpoint's dict with up to two changes: its config JSON mutated (or not text), its format,
    a weight NaN, reshaped, of another dtype, left out or added, not a tensor; or no dict at all."""
    state = dict(seed["state"])
    meta = fz.dumps(draw(fz.mutated_json(seed["meta"], keys=tuple(seed["meta"]["config"]))))
    payload = {"format": checkpoints.FORMAT, "state_dict": state, "meta": meta}
    for _ in range(draw(st.integers(0, 2))):
        if not isinstance(payload, dict):  # no dict left to change
            break
        op = draw(st.sampled_from(["weight", "weight", "meta", "format", "drop", "extra", "top"]))
        key = draw(st.sampled_from(sorted(state)))
        if op == "weight":
            change = draw(st.sampled_from(WEIGHT_CHANGES))
            state[key] = _changed(state[key], change)
        elif op == "meta":
            payload["meta"] = plain(draw(fz.HOSTILE))
        elif op == "format":
            payload["format"] = plain(draw(fz.HOSTILE))
        elif op == "drop":
            del state[key]
        elif op == "extra":
            state[draw(st.sampled_from([key + ".x", "extra", ""]))] = draw(
                st.sampled_from([torch.zeros(3), 1, "text", [1.0], None])
            )
        else:
            payload = plain(draw(st.one_of(fz.HOSTILE, st.just(state))))
    return fz.Shown(payload)


@fz.door_settings(0.75)
@given(data=st.data())
def test_checkpoint_door(checkpoint_seed, scratch, data):
    """checkpoints.load_checkpoint: a model of the tiny MLP's kind, every weight finite; a deflated
    member that inflates past MAX_CHECKPOINT_BYTES refused before torch reads it."""
    with example(scratch) as d:
        path = d / "ck.pt"
        how = data.draw(st.sampled_from(["saved"] * 6 + ["deflated", "lying sizes", "bomb"]), label="file")
        if how == "bomb":
            shutil.copy(checkpoint_seed["bomb"], path)
        else:
            payload = data.draw(checkpoint_payload(checkpoint_seed), label="payload").value
            try:
                torch.save(payload, d / "saved.pt")
            except (RecursionError, TypeError, ValueError, RuntimeError, pickle.PicklingError):
                reject()  # nothing torch can write: no checkpoint to read
            if how == "saved":
                shutil.move(d / "saved.pt", path)
            else:
                fz.rezip(
                    d / "saved.pt",
                    path,
                    lie=data.draw(st.integers(0, 2**32), label="size") if how != "deflated" else None,
                )
                (d / "saved.pt").unlink()
            raw, kind = draw_file(data, path.read_bytes(), validate.MAX_CHECKPOINT_BYTES)
            path.unlink()
            fz.place(d, "ck.pt", raw, kind, validate.MAX_CHECKPOINT_BYTES)
        got = fz.door(
            lambda: checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model), (InputError,), (d,)
        )
        if not refused(got):
            model, cfg = got
            assert isinstance(cfg, models.FineTrainConfig) and isinstance(model, torch.nn.Module)
            assert all(bool(torch.isfinite(p).all()) for p in model.state_dict().values() if p.is_floating_point())


# ----------------------------------------------------------------------------- city indexes


@pytest.fixture(scope="module")
def index_bomb(tiny, tmp_path_factory) -> Path:
    """A city index whose obj_xy unpacks to 300 MB from a few hundred kB (MAX_INDEX_BYTES: 256 MB)."""
    import zipfile

    path = tmp_path_factory.mktemp("index_bomb") / "bomb.npz"
    n = 300 * validate.MB // 16
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, a in tiny["arrays"].items():
            with z.open(f"{name}.npy", "w", force_zip64=True) as f:
                if name != "obj_xy":
                    np.lib.format.write_array(f, a)
                    continue
                np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (n, 2)})
                for _ in range(300):
                    f.write(bytes(1 << 20))
    return path


#: values a city index's array may be given at one place: NaN, inf, negative, a row past the map, huge
INDEX_VALUES = (math.nan, math.inf, -1, -(2**40), 2**40, 30, 10**12, 0)


def _with_value(v: np.ndarray, i: int, x: float) -> np.ndarray:
    """``v`` with its ``i``-th value (flat) set to ``x``, as int64 or float64 when its dtype cannot hold it."""
    try:
        flat = v.ravel().astype(np.int64 if v.dtype.kind in "iub" and math.isfinite(x) else np.float64)
    except (TypeError, ValueError):  # text or objects: left as they are
        return v
    flat[i] = x
    return flat.reshape(v.shape)


@st.composite
def index_arrays(draw, arrays: dict):
    """A city index's arrays with up to three lies: a value NaN, inf, negative, out of range or
    shifted; another dtype (text, objects, complex); another shape; an array left out or added."""
    a = {k: v.copy() for k, v in arrays.items()}
    for _ in range(draw(st.integers(0, 3))):
        name = draw(st.sampled_from(sorted(a)))
        v = a[name]
        op = draw(st.sampled_from(["value", "value", "shift", "dtype", "shape", "drop", "extra", "reverse"]))
        if op == "value" and v.size:
            a[name] = _with_value(v, draw(st.integers(0, v.size - 1)), draw(st.sampled_from(INDEX_VALUES)))
        elif op == "shift":
            shift = draw(st.sampled_from([1, 3, -1, 10**12]))
            with contextlib.suppress(TypeError, ValueError, OverflowError):  # text, or an int8 past its range
                a[name] = v + shift
        elif op == "dtype":
            dtype = draw(st.sampled_from([np.float32, np.int8, np.uint64, np.bool_, np.complex64, "U3", object]))
            with contextlib.suppress(TypeError, ValueError, OverflowError):  # text as numbers, -3 as uint64
                a[name] = v.astype(dtype)
        elif op == "shape":
            a[name] = draw(st.sampled_from([v.reshape(-1), v.reshape(1, -1), v[:-1], np.concatenate([v, v]), v[:0]]))
        elif op == "drop":
            del a[name]
        elif op == "extra":
            a["extra"] = np.zeros(3)
        elif op == "reverse":
            a[name] = v[::-1].copy()
    return a


def check_index(ix) -> None:
    n, views = len(ix.obj_xy), len(ix.cam)
    assert 1 <= n <= validate.MAX_INDEX_OBJECTS and ix.obj_xy.shape == (n, 2) and ix.cam.shape == (views, 3)
    for name in ("obj_xy", "cam", "idf"):
        assert np.isfinite(getattr(ix, name)).all(), name
    assert len(ix.obj_cls) == n == len(ix.obj_id) == len(np.unique(ix.obj_id))
    assert len(ix.idf) >= N_CLASSES and (ix.idf >= 0).all()
    assert ((ix.obj_cls >= 0) & (ix.obj_cls < len(ix.idf))).all()
    assert len(ix.view_ptr) == views + 1 and ix.view_ptr[0] == 0 and ix.view_ptr[-1] == len(ix.view_obj)
    assert (np.diff(ix.view_ptr) >= 0).all() and ((ix.view_obj >= 0) & (ix.view_obj < n)).all()


@fz.door_settings(1.0)
@given(data=st.data())
def test_city_index_door(tiny, scratch, index_bomb, data):
    """city.index.ViewIndex.load: arrays of their kinds and shapes, every number finite, pointers and
    ids in range (the compiled kernels index with them); an unpacking bomb refused before it inflates."""
    with example(scratch) as d:
        path = d / "index.npz"
        how = data.draw(st.sampled_from(["savez"] * 4 + ["compressed", "lying sizes", "bomb"]), label="file")
        if how == "bomb":
            shutil.copy(index_bomb, path)
        else:
            arrays = data.draw(index_arrays(tiny["arrays"]), label="arrays")
            (np.savez if how == "savez" else np.savez_compressed)(d / "a.npz", **arrays)
            if how == "lying sizes":
                fz.rezip(d / "a.npz", d / "b.npz", lie=data.draw(st.integers(0, 2**32), label="size"))
                shutil.move(d / "b.npz", d / "a.npz")
            raw, kind = draw_file(data, (d / "a.npz").read_bytes(), validate.MAX_INDEX_BYTES)
            (d / "a.npz").unlink()
            fz.place(d, "index.npz", raw, kind, validate.MAX_INDEX_BYTES)
        got = fz.door(lambda: index.ViewIndex.load(path), (InputError,), (d,))
        if not refused(got):
            check_index(got)


# ----------------------------------------------------------------------------- the config

#: the largest number a resolved config may hold: every number of the schema has a maximum that means
#: something (megapixels, sides, radii, epochs, counts); none is anywhere near this
MAX_CONFIG_NUMBER = 1e12
CONFIG_ERRORS = (InputError, config.ConfigError)


def check_config(full) -> None:
    stack = [("", full)]
    while stack:
        where, v = stack.pop()
        if isinstance(v, dict):
            stack.extend((f"{where}.{k}", x) for k, x in v.items())
        elif isinstance(v, list):
            stack.extend((f"{where}[{i}]", x) for i, x in enumerate(v))
        elif is_number(v):
            assert math.isfinite(v) and abs(v) <= MAX_CONFIG_NUMBER, f"{where} = {v!r} resolved"


@st.composite
def config_doc(draw):
    """Some sections of the schema's defaults, mutated (a number 1e300, text for numbers, an unknown
    key, a section that is a list)."""
    defaults = config.section_defaults()
    chosen = draw(st.lists(st.sampled_from(sorted(defaults)), max_size=3, unique=True))
    doc = {k: defaults[k] for k in chosen}
    keys = tuple(defaults) + tuple(k for v in defaults.values() if isinstance(v, dict) for k in v)
    doc = plain(draw(fz.mutated_json(doc, max_mutations=3, keys=keys)))
    return fz.Shown(doc if isinstance(doc, dict) else {"solver": doc})  # Snakemake's config is a mapping


@fz.door_settings(1.0)
@given(data=st.data())
def test_config_resolve_door(data):
    """config.resolve: the complete config, every number finite and bounded, or one ConfigError."""
    doc = data.draw(config_doc(), label="config").value
    got = fz.door(lambda: config.resolve(doc), CONFIG_ERRORS)
    if not refused(got):
        check_config(got)


# ----------------------------------------------------------------------------- the config file

YAML_TEXTS = [
    fz.alias_bomb(9),  # 9 ** 9 values once expanded, 477 bytes (the issue's: 14 min of CPU)
    fz.alias_bomb(4),
    "seed: 0\nseed: 1\n",
    "solver:\n  top_k: 1\n  top_k: 2\n",
    "a: &a [*a]\n",
    "seed: !!python/object/apply:os.system ['true']\n",
    "seed: " + "[" * 300 + "1" + "]" * 300 + "\n",
    "seed: " + "9" * 5000 + "\n",
    "seed: .nan\n",
    "images:\n  max_megapixels: 1.0e+300\n  min_side_px: 100000000000000000000000\n",  # YAML 1.1: 1e300 is text
    "? [1, 2]\n: x\n",
    "--- {}\n--- {}\n",
    "seed: !!binary aGVsbG8=\n",
    "\t- x\n",
    "\ufeffseed: 1\n",
]


def yaml_duplicates(text: bytes) -> bool | None:
    """Whether a mapping of the YAML ``text`` gives a key twice (composed, not built: aliases are
    not expanded), None when it is no YAML PyYAML composes."""
    import yaml

    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except (yaml.YAMLError, RecursionError, ValueError):
        return None
    seen, stack = set(), [root]
    while stack:
        node = stack.pop()
        if node is None or id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            keys = [k.value for k, _ in node.value if isinstance(k, yaml.ScalarNode)]
            if len(keys) != len(set(keys)):
                return True
            stack.extend(n for pair in node.value for n in pair)
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)
    return False


def expanded_size(value, limit: int) -> int:
    """Values of ``value`` with shared subtrees counted where each appears, counting stopped past ``limit``."""
    n, stack = 0, [value]
    while stack and n <= limit:
        x = stack.pop()
        n += 1
        if isinstance(x, dict):
            stack.extend(x.values())
        elif isinstance(x, list):
            stack.extend(x)
    return n


@st.composite
def yaml_text(draw) -> bytes:
    """A config file: some sections of the defaults, mutated, as YAML (or JSON, as Snakemake
    takes it), with a hostile text (an alias bomb, a key given twice, a Python tag, 5,000 digits,
    300 brackets, two documents) added, or its bytes corrupted."""
    import yaml

    doc = draw(config_doc()).value
    try:
        text = yaml.safe_dump(doc, sort_keys=False) if draw(st.booleans()) else json.dumps(doc)
    except (RecursionError, ValueError):
        text = "{}\n"
    how = draw(st.sampled_from(["as is", "hostile", "hostile", "appended", "bytes"]))
    if how == "hostile":
        text = draw(st.sampled_from(YAML_TEXTS))
    elif how == "appended" and not text.startswith("{"):
        text += draw(st.sampled_from(YAML_TEXTS))
    raw = text.encode("utf-8", "surrogatepass")
    return draw(fz.corrupted(raw)) if how == "bytes" else raw


@fz.door_settings(1.0)
@given(data=st.data())
def test_config_file_door(scratch, data):
    """validate.read_config (a --configfile, before Snakemake's config is walked) then config.resolve:
    no key given twice, aliases expanded to at most MAX_CONFIG_NODES values, nested at most
    MAX_CONFIG_DEPTH deep, in milliseconds (a 477-byte alias bomb took 14 min); the resolved config's
    numbers finite and bounded; else one InputError or ConfigError."""
    raw = data.draw(yaml_text(), label="file")
    kind = data.draw(fz.file_kind(), label="file kind")
    with example(scratch) as d:
        path = fz.place(d, "config.yaml", raw, kind, validate.MAX_CONFIG_BYTES)
        got = fz.door(lambda: validate.read_config(path), CONFIG_ERRORS, (d,))
        if refused(got):
            return
        assert kind in ("file", "link", "empty"), f"a {kind} was read as a config"
        assert yaml_duplicates(raw) is not True, "a key given twice was read"
        assert expanded_size(got, validate.MAX_CONFIG_NODES) <= validate.MAX_CONFIG_NODES
        assert json_depth(got) <= validate.MAX_CONFIG_DEPTH + 1
        if isinstance(got, dict):
            full = fz.door(lambda: config.resolve(got), CONFIG_ERRORS, (d,))
            if not refused(full):
                check_config(full)


# ----------------------------------------------------------------------------- provenance records


def _record(rule: str, outputs: dict, inputs: dict | None = None) -> dict:
    return {
        "rule": rule,
        "wildcards": {"scene": "0"},
        "inputs": inputs or {},
        "outputs": {k: {"sha256": v, "bytes": 1} for k, v in outputs.items()},
        "config_hash": "0",
        "config_id": "ab12",
        "package_version": "0",
        "git_commit": "x",
        "finished_at": "now",
        "wall_seconds": 1.0,
    }


OUTPUT_NAMES = [
    "results/a.txt",
    "/",
    "../x",
    "results/../../x",
    "results/link",
    "results/link/etc/passwd",
    "",
    "results/\x1b[2Jx",
    "results/\u202etxt.exe",
    "results/" + "d/" * 300 + "x",
]


@fz.door_settings(0.75)
@given(data=st.data())
def test_provenance_door(scratch, data):
    """provenance.records / manifest / lineage_tree (``flatlandia audit``): never an exception (a
    broken record is left out and said); every record kept names outputs inside the run's folder
    (links resolved) and holds the keys and types of a record; chains of records are walked."""
    recs = [_record("good", {"results/a.txt": "0"})]
    chain = data.draw(st.sampled_from([0, 0, 2, 5, 40]), label="chain")
    recs += [_record(f"c{k}", {f"results/c{k}": "0"}, {f"results/c{k - 1}": "0"} if k else {}) for k in range(chain)]
    for _ in range(data.draw(st.integers(0, 3), label="hostile records")):
        rec = _record("r", {data.draw(st.sampled_from(OUTPUT_NAMES), label="output"): "0"})
        recs.append(data.draw(fz.mutated_json(rec, keys=tuple(rec)), label="record"))
    with example(scratch) as d:
        (d / "results").mkdir()
        (d / "results" / "a.txt").write_text("a")
        (d / "results" / "link").symlink_to("/", target_is_directory=True)
        prov = d / "logs" / "provenance"
        for k, rec in enumerate(recs):
            raw = fz.dumps(rec).encode("utf-8", "surrogatepass")
            if k and k > chain:
                raw, kind = draw_file(data, raw, validate.MAX_RECORD_BYTES)
            else:
                kind = "file"
            fz.place(prov / f"r{k}", "all.json", raw, kind, validate.MAX_RECORD_BYTES)
        skipped: list[str] = []
        got = fz.door(lambda: provenance.records(prov, skipped), (), (d,))
        for rec in got:
            for key, kind in provenance.RECORD_KEYS.items():
                assert isinstance(rec[key], kind), (key, rec)
            for out in rec["outputs"]:
                assert isinstance(out, str) and out and not os.path.isabs(out), out
                real = os.path.realpath(os.path.join(d, out))
                assert real == os.path.realpath(d) or real.startswith(os.path.realpath(d) + os.sep), out
        df = fz.door(lambda: provenance.manifest(prov, []), (), (d,))
        if chain:
            tree = fz.door(lambda: provenance.lineage_tree(f"results/c{chain - 1}", df), (), (d,))
            assert len(tree) >= 1
        fz.door(lambda: provenance.check(df), (), (d,))


def test_provenance_chain_of_1500_records(scratch):
    """``flatlandia audit --tree`` over 1,500 chained records (a RecursionError before): each door
    of the audit once, within the budgets (one example: writing 1,500 records takes a second)."""
    with example(scratch) as d:
        prov = d / "logs" / "provenance"
        for k in range(1500):
            rec = _record(f"c{k}", {f"results/c{k}": "0"}, {f"results/c{k - 1}": "0"} if k else {})
            fz.place(prov / f"c{k}", "all.json", json.dumps(rec).encode())
        df = fz.door(lambda: provenance.manifest(prov, []), (), (d,))
        tree = fz.door(lambda: provenance.lineage_tree("results/c1499", df), (), (d,))
        rows = fz.door(lambda: provenance.lineage("results/c1499", df, tree=True), (), (d,))
        assert len(df) == 1500 and tree and rows


# ----------------------------------------------------------------------------- names and escapes

NAME_PARTS = st.sampled_from(
    [
        "..",
        ".",
        "/",
        "\\",
        "\x00",
        "\x1b",
        "\x85",
        "\u202e",
        "\u2066",
        "\u200b",
        "\ufeff",
        "\ud800",
        "\u2028",
        "a",
        "photo.jpg",
        "x" * 199,
        "\u00e9",
    ]
)
NAMES = st.one_of(
    st.text(max_size=40),
    st.lists(NAME_PARTS, max_size=5).map("".join),
    st.text(st.characters(codec="utf-8"), max_size=250),
)


@fz.door_settings(2.0)
@given(name=NAMES)
def test_plain_name_door(name):
    """names.plain_name: a name that stays in its folder once joined (no '/', '\\', '.', '..'), not
    blank, at most MAX_NAME_BYTES, with no character nobody sees as itself (C0/C1 controls, bidi
    overrides and isolates, zero-width characters, line separators, lone surrogates)."""
    got = fz.door(lambda: names.plain_name(name, "names.txt"), (InputError,))
    if refused(got):
        return
    assert got == name and name.strip() and name not in (".", "..") and "/" not in name and "\\" not in name
    assert not [c for c in name if unicodedata.category(c) in HIDDEN], name
    assert len(name.encode()) <= names.MAX_NAME_BYTES
    assert os.path.dirname(os.path.normpath(os.path.join("/base", name))) == "/base"


@fz.door_settings(2.0)
@given(text=st.one_of(st.text(max_size=40), st.lists(NAME_PARTS, max_size=6).map("".join)))
def test_terminal_escape(text):
    """escape.terminal (what ``flatlandia audit`` prints): no control or invisible character reaches
    the terminal; text without one is unchanged."""
    out = escape.terminal(text)
    assert not [c for c in out if unicodedata.category(c) in HIDDEN], repr(out)
    if not [c for c in text if unicodedata.category(c) in HIDDEN]:
        assert out == text


FORMULA_START = tuple("=+@-\t\r\n\uff1d\uff0b\uff20\uff0d")
PLAIN_NUMBER = r"-?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
TOKEN_FORM = r"-[A-Za-z0-9_\-]{21}"
PROJ_FORM = r"\+proj=[A-Za-z0-9_.=+ \-]*"
CELLS = st.one_of(
    st.text(max_size=30),
    st.builds(
        lambda a, b: a + b,
        st.sampled_from(["-", "+", "=", "@", "'", "\t", "\r", "\uff0d", "'-", "''="]),
        st.text(st.characters(codec="ascii"), max_size=25),
    ),
    st.from_regex(TOKEN_FORM, fullmatch=True),
    st.from_regex(PLAIN_NUMBER, fullmatch=True),
    st.from_regex(r"-(?:[A-Z]{1,2}[0-9]{1,3}[-+])+[A-Z][0-9]", fullmatch=True),
)


@fz.door_settings(2.0)
@given(cell=CELLS)
def test_csv_cell_escape(cell):
    """escape.csv_cell: a cell never starts a formula (= + @ - tab CR LF, full-width forms) unless
    it is a plain number, a published token's form (``-`` and 21 characters of base64url, not
    arithmetic of cell references) or a PROJ string; and every cell reads back as written."""
    import re

    out = escape.csv_cell(cell)
    if out.startswith(FORMULA_START):
        ok = re.fullmatch(PLAIN_NUMBER, out) or re.fullmatch(PROJ_FORM, out, re.ASCII)
        token = re.fullmatch(TOKEN_FORM, out, re.ASCII) and not re.fullmatch(
            r"(?:-+(?:[A-Za-z]{1,3}[0-9]{1,7}|[0-9]+))+", out
        )
        assert ok or token, f"{out!r} starts a formula"
    assert escape.csv_cell_read(out) == cell


# ----------------------------------------------------------------------------- EXIF and metadata.csv


MAPILLARY = {
    "MAPLatitude": 55.7,
    "MAPLongitude": 13.2,
    "MAPAltitude": 20.0,
    "MAPCompassHeading": {"TrueHeading": 120.0, "AccuracyDegrees": 5.0},
    "MAPGPSAccuracyMeters": 3.0,
    "MAPCaptureTime": "2020_01_01_12_00_00_000",
}
#: the issue's descriptions: 20,000 nested brackets, a number of 5,000 digits
EXIF_TEXTS = ['{"a": ' + "[" * 20_000 + "]" * 20_000 + "}", '{"MAPLatitude": ' + "9" * 5000 + "}"]
METADATA_CELLS = [
    "55.7",
    "13.2",
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "",
    "abc",
    "1_000",
    "91",
    "-181",
    "1e5",
    "370",
    "\uff11",
]


@fz.door_settings(0.5)
@given(data=st.data())
def test_exif_door(scratch, data):
    """images.image_audit.read_folder_metadata: a photo whose Mapillary description is hostile JSON
    (20,000 brackets, 5,000 digits) is dropped with its reason, never a traceback; a geotag kept is
    within GEOTAG_RANGES, from the EXIF or a metadata.csv; a bad metadata.csv is one InputError."""
    from PIL import ExifTags, Image

    desc = data.draw(fz.mutated_json(MAPILLARY, keys=tuple(MAPILLARY)), label="description")
    text = fz.dumps(desc) if data.draw(st.integers(0, 5), label="issue's?") else data.draw(st.sampled_from(EXIF_TEXTS))
    text = data.draw(fz.corrupted(text.encode("utf-8", "surrogatepass")), label="bytes")[
        :60_000
    ]  # a JPEG's EXIF: 64 kB
    rows = data.draw(st.lists(st.tuples(*[st.sampled_from(METADATA_CELLS)] * 4), max_size=2), label="metadata.csv")
    with example(scratch) as d:
        ex = Image.Exif()
        ex[ExifTags.Base.ImageDescription] = text.decode("utf-8", "replace")
        Image.new("RGB", (32, 32), (120, 130, 140)).save(d / "a.jpg", exif=ex)
        Image.new("RGB", (32, 32), (20, 30, 40)).save(d / "b.jpg")
        if rows:
            lines = ["name,lat,lon,alt,heading"] + [",".join([n, *r]) for n, r in zip(("a.jpg", "b.jpg"), rows)]
            (d / "metadata.csv").write_text("\n".join(lines) + "\n")
        got = fz.door(lambda: image_audit.read_folder_metadata(d, min_side_px=16), (InputError,), (d,))
        if refused(got):
            return
        kept = got[got["problem"].isna() | (got["problem"] == "")]
        for col, (lo, hi) in image_audit.GEOTAG_RANGES.items():
            v = kept[col].astype(float)
            assert (v.isna() | ((v >= lo) & (v <= hi))).all(), (col, v.tolist())


# ----------------------------------------------------------------------------- fixes of --batch

FIX_CELLS = [
    "11.0",
    "48.0",
    "5",
    "1e308",
    "nan",
    "inf",
    "-inf",
    "",
    "abc",
    "1_000",
    "1e-300",
    "0",
    "-1",
    "400",
    "9" * 400,
]


@fz.door_settings(1.0)
@given(data=st.data())
def test_fixes_door(scratch, data):
    """batch.read_fixes (``localize --batch --fixes``): GPS fixes of finite degrees in range, sigmas
    finite and positive within MAX_PRIOR_M, compass within a turn, each query once."""
    cells = st.sampled_from(FIX_CELLS)
    rows = data.draw(
        st.lists(
            st.tuples(st.sampled_from(["0", "1"]), st.sampled_from(["t1", "t2"]), cells, cells, cells, cells, cells),
            max_size=4,
        ),
        label="rows",
    )
    header = data.draw(
        st.sampled_from(
            ["scene,token,lon,lat,sigma_m,compass_deg,compass_sigma_deg", "scene,token,lon,lat,sigma_m", "token,lon"]
        ),
        label="header",
    )
    width = header.count(",") + 1
    text = "\n".join([header] + [",".join(r[:width]) for r in rows]) + "\n"
    raw, kind = draw_file(data, text.encode(), validate.MAX_CSV_BYTES)
    with example(scratch) as d:
        path = fz.place(d, "fixes.csv", raw, kind, validate.MAX_CSV_BYTES)
        got = fz.door(lambda: batch.read_fixes(path), (InputError,), (d,))
        if refused(got):
            return
        for (lon, lat, sigma), compass in got.values():
            assert abs(lon) <= 180 and abs(lat) <= 90 and 0 < sigma <= validate.MAX_PRIOR_M
            if compass is not None:
                assert math.isfinite(compass[0]) and 0 < compass[1] <= validate.MAX_COMPASS_SIGMA_DEG


# ----------------------------------------------------------------------------- the write door

#: the parts a written path is built of: the run's folder, '..', links out of it and back in, a
#: dot-folder, a Python environment, a link to /dev/null, a pipe, the command's input (and a hard
#: link to it), an artifact of the run, existing and new names
PATH_PARTS = (
    "results",
    "results",
    "sub",
    "..",
    ".",
    ".hidden",
    "venv",
    "link_out",
    "link_in",
    "devnull",
    "fifo",
    "input.json",
    "hard.json",
    "artifact.parquet",
    "file.txt",
    "new.txt",
    "new.txt",
)


def _write_place(d: Path, canary: Path) -> dict:
    """An example's working folder: results/ (where the run may write) with sub/, a regular file, the
    command's input and a hard link to it, an artifact, a pipe, a link to /dev/null, links out of the
    run (to ``canary``) and back in; a dot-folder and a virtualenv beside it."""
    r = d / "results"
    (r / "sub").mkdir(parents=True)
    (r / "file.txt").write_text("file")
    (r / "input.json").write_text("{}")
    os.link(r / "input.json", r / "hard.json")
    (r / "artifact.parquet").write_text("artifact")
    os.mkfifo(r / "fifo")
    (r / "devnull").symlink_to("/dev/null")
    (r / "link_out").symlink_to(canary, target_is_directory=True)
    (r / "link_in").symlink_to(r / "sub", target_is_directory=True)
    for env in (d / "venv", r / "venv"):
        (env / "lib").mkdir(parents=True)
        (env / "pyvenv.cfg").write_text("home = /usr/bin\n")
    (d / ".hidden").mkdir()
    (r / ".hidden").mkdir()
    return {"root": r, "input": r / "input.json", "artifact": r / "artifact.parquet"}


def _safe_to_write(target: Path, place: dict, d: Path) -> bool:
    """What the write door may let through: a new name or a regular file in the run's folder
    (links resolved), not the input (nor a hard link to it), not the artifact, no dot-folder or
    hidden name below the working folder, no Python environment."""
    root = Path(os.path.realpath(place["root"]))
    real_parent = Path(os.path.realpath(target.parent))
    if not (real_parent == root or real_parent.is_relative_to(root)):
        return False
    full = real_parent / target.name
    if os.path.lexists(full) and (not full.is_file() or full.is_symlink()):
        return False
    if os.path.lexists(full) and any(os.path.samefile(full, place[k]) for k in ("input", "artifact")):
        return False
    parts = full.relative_to(os.path.realpath(d)).parts
    if any(p.startswith(".") for p in parts):
        return False
    return not any((p / "pyvenv.cfg").exists() for p in (full.parent, *full.parent.parents) if p.is_relative_to(d))


@fz.door_settings(1.0)
@given(data=st.data())
def test_write_door(scratch, data):
    """plumbing.files.check_target and its writers: a path built of '..', links out and back in,
    dot-folders, a virtualenv, /dev/null, a pipe, the command's input, an artifact, is either a
    regular file or new name inside the run's folder (its real path) or refused; a write never
    lands outside, never through a link, never onto an input; a refused write leaves nothing."""
    from flatlandia.plumbing import files

    parts = data.draw(st.lists(st.sampled_from(PATH_PARTS), min_size=1, max_size=5), label="parts")
    if data.draw(st.booleans(), label="in results/"):  # half the paths start where the run may write
        parts = ["results", *parts]
    absolute = data.draw(st.booleans(), label="absolute")
    canary = scratch / "canary"
    canary.mkdir(exist_ok=True)
    (canary / "keep.txt").write_text("keep")
    with example(scratch) as d:
        place = _write_place(d, canary)
        path = Path(d if absolute else ".", *parts)
        before = fz.listing(d)
        with files.write_roots(place["root"]):
            got = fz.door(
                lambda: files.check_target(path, reads=[place["input"]], artifacts=[place["artifact"]]), (InputError,)
            )
            inside = os.path.realpath(files.resolved(path).parent).startswith(os.path.realpath(d) + os.sep)
            if refused(got):
                if inside:  # the writer refuses it too, and leaves nothing
                    wrote = fz.door(
                        lambda: files.write_text("new", path, reads=[place["input"]], artifacts=[place["artifact"]]),
                        (InputError,),
                    )
                    assert isinstance(wrote, fz.Refused) and fz.listing(d) == before
                return
            assert _safe_to_write(got, place, d), f"{path} -> {got} let through"
            fz.door(lambda: files.write_text("new", path, reads=[place["input"]], artifacts=[place["artifact"]]), ())
        assert got.read_text() == "new" and not got.is_symlink()
        assert (place["input"]).read_text() == "{}" and (place["artifact"]).read_text() == "artifact"
        assert fz.listing(canary) == {"keep.txt"} and (canary / "keep.txt").read_text() == "keep"
        assert os.readlink(place["root"] / "devnull") == "/dev/null"
        made = got.relative_to(os.path.realpath(d))
        assert fz.listing(d) - before <= {str(made), *(str(p) for p in made.parents if str(p) != ".")}


# ----------------------------------------------------------------------------- score --results

QUERY_TABLE_COLUMNS = ("scene", "token", "split", "x_m", "y_m", "theta_deg", "ref_idx", "n_objects", "classes", "lon")


@pytest.fixture(scope="module")
def results_seed(tmp_path_factory) -> Seeds:
    """The tables of the tiny results folder score reads: the benchmark record, the reference map
    and the queries (their pyarrow tables, metadata included)."""
    import pyarrow.parquet as pq
    import tiny_results

    root = tiny_results.build(tmp_path_factory.mktemp("results_seed") / "results")
    names = {
        "record": score.BENCHMARK_RECORD,
        "map": "0/maps/reference_map.parquet",
        "queries": "0/queries/queries.parquet",
    }
    return Seeds({k: (v, pq.read_table(root / v)) for k, v in names.items()})


@fz.door_settings(0.5)
@given(data=st.data())
def test_results_door(results_seed, scratch, data):
    """score.results_scenes (``flatlandia score --results DIR``, the export's scenes): each scene's map
    through the map door (ids unique, classes known, finite metres, its frame degrees that describe
    it) and its queries' truth finite; a FIFO, a folder, a table that lies is one InputError."""
    which = data.draw(st.sampled_from(sorted(results_seed)), label="file changed")
    with example(scratch) as d:
        root = d / "results"
        for key, (rel, table) in results_seed.items():
            path = root / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            if key != which:
                fz.write_parquet(table, path, {})
                continue
            renames = fz.MAP_COLUMNS if key == "map" else QUERY_TABLE_COLUMNS
            fz.write_parquet(data.draw(fz.mutated_table(table, renames), label="table"), path, {})
            raw, kind = draw_file(data, path.read_bytes(), validate.MAX_MAP_BYTES)
            path.unlink()
            fz.place(path.parent, path.name, raw, kind, validate.MAX_MAP_BYTES)
        got = fz.door(lambda: score.results_scenes(root), (InputError,), (d,))
        if refused(got):
            return
        for s, b in got.items():
            assert names.name_problem(s) is None
            assert np.isfinite(b.ref[["x_m", "y_m"]].to_numpy(float)).all() and len(b.ref["obj_idx"].unique()) == len(
                b.ref
            )
            assert np.isfinite(b.queries[["x_m", "y_m", "theta_deg"]].to_numpy(float)).all()
            if b.frame is not None:
                assert abs(b.frame.lon0) <= 180 and abs(b.frame.lat0) <= 90


# ----------------------------------------------------------------------------- the manifest fallback


@pytest.fixture(scope="module")
def manifest_seed(tmp_path_factory):
    """A manifest as rule manifest writes it (provenance.manifest of a few records), as a pyarrow table."""
    import pyarrow as pa

    d = tmp_path_factory.mktemp("manifest_seed")
    prov = d / "logs" / "provenance"
    for k in range(3):
        rec = _record(f"r{k}", {f"results/a{k}.txt": "0"}, {f"results/a{k - 1}.txt": "0"} if k else {})
        (prov / f"r{k}").mkdir(parents=True)
        (prov / f"r{k}" / "all.json").write_text(json.dumps(rec))
    return pa.Table.from_pandas(provenance.manifest(prov, []), preserve_index=False)


@fz.door_settings(0.75)
@given(data=st.data())
def test_manifest_door(manifest_seed, scratch, data):
    """provenance.read_manifest (``flatlandia audit`` of a results folder copied without its logs):
    rows as provenance.manifest writes them (text where text is, a count of bytes, JSON objects in
    the JSON cells) or left out and said; a file that is not a manifest is one InputError."""
    table = data.draw(fz.mutated_table(manifest_seed, tuple(provenance.MANIFEST_COLUMNS)), label="table")
    with example(scratch) as d:
        path = d / "manifest.parquet"
        fz.write_parquet(table, path, data.draw(fz.PARQUET_OPTIONS, label="writer"))
        raw, kind = draw_file(data, path.read_bytes(), validate.MAX_MAP_BYTES)
        path.unlink()
        fz.place(d, "manifest.parquet", raw, kind, validate.MAX_MAP_BYTES)
        got = fz.door(lambda: provenance.read_manifest(path, []), (InputError,), (d,))
        if refused(got):
            return
        assert list(got.columns) == list(provenance.MANIFEST_COLUMNS)
        for row in got.to_dict("records"):
            assert isinstance(row["artifact"], str) and row["artifact"].strip() and isinstance(row["sha256"], str)
            assert isinstance(row["bytes"], int) and 0 <= row["bytes"] < 2**63
            inputs = json.loads(row["inputs"])
            assert isinstance(inputs, dict) and all(
                isinstance(k, str) and isinstance(v, str) for k, v in inputs.items()
            )
