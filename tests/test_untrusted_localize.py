"""Untrusted inputs, third pass, `flatlandia localize`'s doors (flatlandia.plumbing.validate): a crafted city
index never reaches the compiled kernels (finding 1: it was a segfault), sizes are bounded and
pipes or devices are never read (5), metadata and priors that lie or hold NaN are refused (6),
hostile JSON is one ERROR line, not a traceback (8), and GeoJSON booleans, duplicate ids and
megabyte labels are refused by name (10). All on the tiny scene (tests/data/tiny) and files built
here: fast."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from one_tile_city import write_one_tile_city
from tiny_results import tiny_scene

from flatlandia import cli, localize, solver
from flatlandia.city import index
from flatlandia.classes import CLASSES
from flatlandia.data import localmaps, reference_map
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> dict:
    """The tiny scene as the workflow writes it (reference_map.parquet/.geojson), its city index
    arrays, a GT test query file and the query's objects."""
    d = tmp_path_factory.mktemp("tiny_doors")
    tiny = tiny_scene()
    ref, meta, q = tiny.ref, tiny.meta, tiny.queries
    reference_map.write_geoparquet(ref, meta, d / "reference_map.parquet")
    reference_map.write_geojson(ref, meta, d / "reference_map.geojson")
    ix = index.build(ref, q[q["split"] == "train"])
    arrays = {f: getattr(ix, f) for f in index._FIELDS}
    np.savez(d / "good.npz", **arrays)
    r = q[q["split"] == "test"].iloc[0]
    query = localize.query_json(localmaps.local_map(r, "gt"), r.classes)
    (d / "q.json").write_text(json.dumps(query))
    return {
        "dir": d,
        "arrays": arrays,
        "query": query,
        "objects": query["objects"],
        "ref": ref,
        "meta": meta,
        "queries": q,
    }


def run(capsys, *args) -> tuple[int, list[str]]:
    """`flatlandia localize ARGS` in this process: (status, stdout lines)."""
    status = cli.main(["localize", *map(str, args)])
    got = capsys.readouterr()
    return status, (got.err if status else got.out).strip().splitlines()


def one_error(status: int, lines: list[str], *says: str) -> str:
    assert status == 1 and len(lines) == 1 and lines[0].startswith("ERROR: "), lines
    for s in says:
        assert s in lines[0], (s, lines[0])
    return lines[0]


def write(path: Path, value) -> Path:
    path.write_text(value if isinstance(value, str) else json.dumps(value))
    return path


# ----------------------------------------------------------------------------- 1. a crafted city index


def test_an_index_whose_pointers_leave_its_arrays_is_one_error_line_not_a_segfault(tiny, tmp_path):
    """The issue's reproduction: view_ptr + 10**12 sent the numba kernel out of bounds (rc 139)."""
    bad = {**tiny["arrays"], "view_ptr": tiny["arrays"]["view_ptr"] + 10**12}
    np.savez(tmp_path / "bad.npz", **bad)
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "flatlandia.cli",
            "localize",
            "--map",
            str(tmp_path / "bad.npz"),
            "--query",
            str(tiny["dir"] / "q.json"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 1, (res.returncode, res.stderr[-2000:])
    assert res.stderr.strip().splitlines() == [
        f"ERROR: {tmp_path / 'bad.npz'}: view_ptr must run from 0 to the {len(bad['view_obj'])} seen objects "
        "without decreasing (it indexes view_obj)"
    ]
    assert "Traceback" not in res.stderr


def _crafted(a: dict) -> dict:
    """name -> (the index's arrays with one lie, what the ERROR line says)."""
    n = len(a["obj_xy"])
    return {
        "pointer +3": ({**a, "view_ptr": a["view_ptr"] + 3}, "view_ptr must run from 0"),
        "pointers decreasing": ({**a, "view_ptr": a["view_ptr"][::-1].copy()}, "view_ptr must run from 0"),
        "seen object out of range": (
            {**a, "view_obj": a["view_obj"] + n},
            f"view_obj holds map rows outside 0..{n - 1}",
        ),
        "negative seen object": ({**a, "view_obj": a["view_obj"] - 10**6}, "view_obj holds map rows outside"),
        "class past the weights": ({**a, "obj_cls": a["obj_cls"] + 1000}, "obj_cls holds class ids outside"),
        "NaN position": (
            {**a, "obj_xy": np.where(np.arange(n)[:, None] == 0, np.nan, a["obj_xy"])},
            "obj_xy holds NaN",
        ),
        "inf weight": ({**a, "idf": np.full_like(a["idf"], np.inf)}, "idf holds NaN or inf"),
        "ids twice": ({**a, "obj_id": np.zeros_like(a["obj_id"])}, "obj_id holds the same object id twice"),
        "views and pointers apart": ({**a, "cam": a["cam"][:-1]}, "view_ptr must hold one entry per view"),
        "float pointers": (
            {**a, "view_ptr": a["view_ptr"].astype(float)},
            "view_ptr: expected a 1-D array of integers",
        ),
        "missing array": ({k: v for k, v in a.items() if k != "idf"}, "not a city index: no idf"),
        "pickled objects": ({**a, "obj_id": np.array([object()] * n, dtype=object)}, "not a city index"),
    }


@pytest.mark.parametrize("case", list(_crafted({k: np.zeros(2) for k in index._FIELDS})))
def test_every_lie_of_a_crafted_index_is_refused_before_the_kernels(tiny, tmp_path, capsys, case):
    arrays, says = _crafted(tiny["arrays"])[case]
    path = tmp_path / "crafted.npz"
    np.savez(path, **arrays)
    one_error(*run(capsys, "--map", path, "--query", tiny["dir"] / "q.json"), str(path), says)


def test_an_index_that_unpacks_past_its_bound_is_refused_before_anything_is_inflated(tiny, tmp_path, capsys):
    """A few hundred kB of zip holding a 300 MB array (MAX_INDEX_BYTES is 256 MB), written in chunks."""
    path = tmp_path / "bomb.npz"
    n = 300 * validate.MB // 16
    header = {"descr": "<f8", "fortran_order": False, "shape": (n, 2)}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, a in tiny["arrays"].items():
            if name != "obj_xy":
                with z.open(f"{name}.npy", "w") as f:
                    np.lib.format.write_array(f, a)
        with z.open("obj_xy.npy", "w", force_zip64=True) as f:
            np.lib.format.write_array_header_1_0(f, header)
            zeros = bytes(1 << 20)
            for _ in range(300):
                f.write(zeros)
    assert path.stat().st_size < 2 * validate.MB
    t0 = time.process_time()
    one_error(*run(capsys, "--map", path, "--query", tiny["dir"] / "q.json"), "over the limit", "MAX_INDEX_BYTES")
    assert time.process_time() - t0 < 5


def test_a_city_map_beside_the_index_with_nan_lon_lat_is_refused(tiny, tmp_path, capsys):
    """The city's map.parquet gives each tile its lon/lat: NaN there would reach pyproj."""
    ref, q = tiny["ref"], tiny["queries"]
    city = tmp_path / "results" / "city" / "1"

    def no_lon(cref):
        cref.loc[cref.index[0], "lon"] = np.nan
        return cref

    cref, cq = write_one_tile_city(ref, q, city, no_lon)
    one_error(
        *run(capsys, "--map", city / "index", "--query", tiny["dir"] / "q.json"), "map.parquet", "lon/lat holds NaN"
    )


# ----------------------------------------------------------------------------- 5. sizes, pipes, devices


def test_queries_sequences_and_maps_are_bounded(tiny, tmp_path, capsys):
    objs, m = tiny["objects"], tiny["dir"] / "reference_map.parquet"
    many = [{**objs[k % len(objs)], "x": 1.0 + k, "y": 0.5} for k in range(validate.MAX_QUERY_OBJECTS + 1)]
    one_error(
        *run(capsys, "--map", m, "--query", write(tmp_path / "big.json", {"objects": many})),
        "101 objects",
        "MAX_QUERY_OBJECTS",
    )
    frames = [{"objects": objs}] + [{"objects": objs, "pose": {"x": 1.0, "y": 0.0}}] * validate.MAX_SEQUENCE_FRAMES
    seq = write(tmp_path / "seq.json", {"frames": frames})
    one_error(
        *run(capsys, "--map", m, "--sequence", seq, "--map-type", "depth"),
        f"{validate.MAX_SEQUENCE_FRAMES + 1} frames",
        "MAX_SEQUENCE_FRAMES",
    )
    qs = {"queries": [{"id": str(k), "objects": objs} for k in range(validate.MAX_QUERIES + 1)]}
    one_error(*run(capsys, "--map", m, "--query", write(tmp_path / "qs.json", qs)), "10,001 queries", "MAX_QUERIES")
    huge = tmp_path / "huge.json"
    with open(huge, "w") as f:
        f.write('{"objects": [], "pad": "')
        f.truncate(validate.MAX_QUERY_JSON_BYTES + 10)  # sparse: nothing is written
    one_error(*run(capsys, "--map", m, "--query", huge), "over the limit", "MAX_QUERY_JSON_BYTES")
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [2.0 + k * 1e-6, 48.0]},
            "properties": {"class": CLASSES[0]},
        }
        for k in range(validate.MAX_MAP_OBJECTS + 1)
    ]
    big_map = write(tmp_path / "big.geojson", {"type": "FeatureCollection", "features": feats})
    one_error(*run(capsys, "--map", big_map, "--query", tiny["dir"] / "q.json"), "20,001 features", "MAX_MAP_OBJECTS")
    lights = feats[: validate.MAX_CLASS_OBJECTS + 1]  # the solver's candidates grow with one class's objects
    lights_map = write(tmp_path / "lights.geojson", {"type": "FeatureCollection", "features": lights})
    one_error(
        *run(capsys, "--map", lights_map, "--query", tiny["dir"] / "q.json"),
        "301 objects of class",
        "MAX_CLASS_OBJECTS",
    )


@pytest.mark.parametrize("what", ["query", "map"])
def test_a_pipe_or_a_device_is_refused_without_being_read(tiny, tmp_path, what):
    """A FIFO would block the reader for ever and /dev/zero never ends: both refused at once."""
    fifo = tmp_path / ("q.json" if what == "query" else "map.parquet")
    os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero")):
        args = ["--map", tiny["dir"] / "reference_map.parquet", "--query", path]
        if what == "map":
            args = ["--map", path, "--query", tiny["dir"] / "q.json"]
        t0 = time.monotonic()
        res = subprocess.run(
            [sys.executable, "-m", "flatlandia.cli", "localize", *map(str, args)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert res.returncode == 1 and time.monotonic() - t0 < 30, res.stderr[-2000:]
        assert res.stderr.strip().splitlines() == [
            f"ERROR: {path}: is not a regular file (a named pipe, a device or a socket): refused without reading it"
        ]


def test_prior_sizes_and_odometry_are_bounded(tiny, tmp_path, capsys):
    m, q = tiny["dir"] / "reference_map.parquet", tiny["dir"] / "q.json"
    one_error(*run(capsys, "--map", m, "--query", q, "--gps", "2.0,48.0", "--gps-sigma-m", "1e308"), "--gps-sigma-m")
    one_error(*run(capsys, "--map", m, "--query", q, "--near", "2.0,48.0", "--radius-m", "1e300"), "--radius-m")
    objs = tiny["objects"]
    seq = write(tmp_path / "far.json", {"frames": [{"objects": objs}, {"objects": objs, "pose": {"x": 1e308, "y": 0}}]})
    one_error(*run(capsys, "--map", m, "--sequence", seq, "--map-type", "depth"), "frame 1 pose x must be at most")


# ----------------------------------------------------------------------------- 6. metadata and priors that lie


def _parquet_with(
    tmp_path: Path, name: str, meta_text: str, table: pa.Table | None = None, src: Path | None = None
) -> Path:
    t = table if table is not None else pq.read_table(src)
    md = dict(t.schema.metadata)
    md[b"flatlandia"] = meta_text.encode()
    pq.write_table(t.replace_schema_metadata(md), tmp_path / name)
    return tmp_path / name


def test_a_map_whose_metadata_does_not_describe_it_is_refused(tiny, tmp_path, capsys):
    """lon0 = 1e9 gave a pose at lon -80 (truth 2.37); a frame origin must be degrees near the map's
    own objects, and its x_m/y_m must be its lon/lat in that frame."""
    src, meta, q = tiny["dir"] / "reference_map.parquet", tiny["meta"], tiny["dir"] / "q.json"
    cases = {
        "1e9": ({**meta, "lon0": 1e9}, "metadata lon0 must be a finite number in [-180, 180], got 1000000000.0"),
        "far": ({**meta, "lon0": meta["lon0"] + 1.0}, "km from its objects"),
        "shifted": ({**meta, "lon0": meta["lon0"] + 0.01}, "x_m/y_m are not its lon/lat in the frame"),
        "text": ({**meta, "lon0": "abc"}, "metadata lon0 must be a finite number"),
        "list": ([1, 2], "its flatlandia metadata must be a JSON object, not list"),
    }
    for name, (value, says) in cases.items():
        path = _parquet_with(tmp_path, f"{name}.parquet", json.dumps(value), src=src)
        one_error(*run(capsys, "--map", path, "--query", q), str(path), says)
    nan = _parquet_with(tmp_path, "nan.parquet", '{"lon0": NaN, "lat0": 48.0}', src=src)
    one_error(*run(capsys, "--map", nan, "--query", q), "metadata lon0 must be a finite number")
    status, lines = run(capsys, "--map", src, "--query", q)  # the map as written stays good
    assert status == 0 and json.loads("\n".join(lines))["found"]


def test_priors_with_nan_zero_spreads_or_the_wrong_length_are_refused(tiny, tmp_path):
    good = solver.LearnedPriors((3.0, 0.4), None).to_dict()
    nf = len(good["features"])
    verifier = {"weights": [0.1] * nf, "mean": [0.0] * nf, "scale": [1.0] * nf}
    cases = {
        "NaN scale": ({**good, "scale_prior": [float("nan"), 0.4]}, "scale_prior mean must be a finite number"),
        "zero sigma": ({**good, "scale_prior": [3.0, 0.0]}, "scale_prior std must be > 0"),
        "NaN weight": (
            {**good, "verifier": {**verifier, "weights": [float("nan")] * nf}},
            "verifier weights[0] must be a finite",
        ),
        "wrong length": ({**good, "verifier": {**verifier, "weights": [0.1] * (nf + 2)}}, f"must list {nf} numbers"),
        "zero scale": ({**good, "verifier": {**verifier, "scale": [0.0] * nf}}, "verifier scale[0] must be > 0"),
    }
    for name, (value, says) in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(value))  # json writes NaN as NaN, as Python does
        with pytest.raises(InputError, match=says.replace("[", r"\[").replace("]", r"\]")):
            solver.LearnedPriors.read(path)
        with pytest.raises(InputError):
            localize.load_map(tiny["dir"] / "reference_map.parquet", learned=path)
    path = tmp_path / "good.json"
    solver.LearnedPriors((3.0, 0.4), None).write(path)
    assert solver.LearnedPriors.read(path).scale == (3.0, 0.4)


# ----------------------------------------------------------------------------- 8. hostile JSON


def test_hostile_query_json_is_one_error_line(tiny, tmp_path, capsys):
    m, objs = tiny["dir"] / "reference_map.parquet", tiny["objects"]
    first = dict(objs[0])
    cases = {
        "deep.json": ("[" * 100_000 + "]" * 100_000, "nested deeper than 32 levels"),
        "digits.json": ('{"objects": [{"class": "object--bench", "x": ' + "9" * 5000 + ', "y": 1}]}', "at least 3"),
        "e400.json": (json.dumps({"objects": [{**first, "x": 10**400}, *objs[1:]]}), "x must be a finite number"),
        "huge.json": (json.dumps({"objects": [{**first, "x": 1e300}, *objs[1:]]}), "x (MAX_LOCAL_COORD)"),
        "seq_deep.json": ('{"frames": ' + "[" * 5000 + "]" * 5000 + "}", "nested deeper"),
    }
    for name, (text, says) in cases.items():
        path = write(tmp_path / name, text)
        flag = "--sequence" if name.startswith("seq") else "--query"
        extra = ["--map-type", "depth"] if flag == "--sequence" else []
        one_error(*run(capsys, "--map", m, flag, path, *extra), str(path), says)


def _geojson(tiny, tmp_path: Path, name: str, change) -> Path:
    doc = json.loads((tiny["dir"] / "reference_map.geojson").read_text())
    change(doc["features"][0])
    return write(tmp_path / name, doc)


def test_geojson_properties_that_are_not_objects_and_boolean_coordinates_are_refused(tiny, tmp_path, capsys):
    q = tiny["dir"] / "q.json"
    cases = {
        "list.geojson": (
            lambda f: f.update(properties=[1, 2]),
            "feature 0: properties must be a JSON object (or null), not list",
        ),
        "text.geojson": (
            lambda f: f.update(properties="abc"),
            "feature 0: properties must be a JSON object (or null), not str",
        ),
        "bool.geojson": (
            lambda f: f["geometry"].update(coordinates=[True, False]),
            "feature 0: coordinates must be numbers",
        ),
    }
    for name, (change, says) in cases.items():
        one_error(*run(capsys, "--map", _geojson(tiny, tmp_path, name, change), "--query", q), name, says)


# ----------------------------------------------------------------------------- 10. duplicates, long labels


def test_duplicate_object_ids_are_refused(tiny, tmp_path, capsys):
    t = pq.read_table(tiny["dir"] / "reference_map.parquet")
    ids = t.column("obj_idx").to_pylist()
    ids[1] = ids[0]
    t = t.set_column(t.schema.get_field_index("obj_idx"), "obj_idx", pa.array(ids, t.schema.field("obj_idx").type))
    path = tmp_path / "dup.parquet"
    pq.write_table(t, path)
    one_error(
        *run(capsys, "--map", path, "--query", tiny["dir"] / "q.json"),
        f"obj_idx {ids[0]} given to more than one object",
    )


def test_a_megabyte_class_name_is_quoted_by_its_start_at_once(tiny, tmp_path, capsys):
    objs = tiny["objects"]
    path = write(tmp_path / "long.json", {"objects": [{**objs[0], "class": "x" * 1_000_000}, *objs[1:]]})
    t0 = time.process_time()
    line = one_error(
        *run(capsys, "--map", tiny["dir"] / "reference_map.parquet", "--query", path), "unknown class 'xxx"
    )
    assert len(line) < 1000 and time.process_time() - t0 < 5, len(line)
