"""The hostile inputs of issues 33 and 42 (untrusted inputs, third and fourth passes), each run as a user would and measured.

    python benchmarks/bench_untrusted_probes.py [--out /tmp/flatlandia-probes] [--timeout 300] [--only NAME ...]

Builds every probe's input in ``--out`` from the tiny scene (tests/data/tiny): a crafted city index,
maps whose metadata lies, hostile query and sequence files, pipes and devices, a compressed poses
bomb, sparse files of gigabytes, tampered provenance records, forged fetch markers, hostile
checkpoints, priors and transforms, a city of ``$\\input{secret.tex}$``, impossible EXIF geotags;
then runs each probe's command (``flatlandia localize``, ``flatlandia score``, ``flatlandia audit``,
``flatlandia debug``, ``snakemake -n``, or a few lines of Python calling the rule's entry) under
``/usr/bin/time -v`` with a time limit. Prints one row per probe (finding, probe, what it ended
in: its first ERROR/WARNING line or what it wrote, exit status, peak RSS, wall and CPU time) as a Markdown
table, also written to ``OUT/probes.md``. Besides the probes, the worst inputs the bounds let
through (a depth query of MAX_QUERY_OBJECTS street lights on a map of MAX_CLASS_OBJECTS of them, a
sequence of MAX_SEQUENCE_FRAMES such frames, a map with every class at its bound, a file of
MAX_QUERIES queries) show what the bounds cost at most.

The probes of issue 42 (finding ``42.N``: a config's fetch.dest in a virtualenv or an absent
``~/.ssh``-like folder under a temporary HOME, ``--out`` onto the command's inputs or a link to
``/dev/null``, ``audit --write`` through ``..`` and links, a YAML alias bomb and a key given twice,
a deflated checkpoint, dictionary-encoded Parquet bombs, EXIF descriptions of 20,000 brackets,
priors whose calibration is a list or text, ``score --results`` and ``--batch`` exports that lie,
1,500 chained records, terminal escapes in record names, ``-2-3`` in a CSV cell, names with
U+0085 or U+202E) each carry the expectation "one ERROR line or a result, no traceback, peak RSS
under 1 GB, wall under 30 s"; column ``meets`` says whether it held, and the script exits non-zero
when one did not.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from flatlandia import geo, localize  # noqa: E402
from flatlandia.classes import CLASSES  # noqa: E402
from flatlandia.data import (  # noqa: E402
    localmaps,
    published,  # noqa: E402
    queries,
    recover,
    reference_map,
)
from flatlandia.plumbing import files, validate  # noqa: E402

TINY_ROOT, TINY_SCENE = REPO / "tests" / "data" / "tiny", "0"
FLATLANDIA = [sys.executable, "-m", "flatlandia.cli"]
#: this Python's snakemake (its environment's bin/ need not be on PATH)
SNAKEMAKE = (
    str(Path(sys.executable).with_name("snakemake"))
    if Path(sys.executable).with_name("snakemake").exists()
    else "snakemake"
)


def build(out: Path) -> dict:
    """Every probe's input under ``out``; the paths by name."""
    lonlat, classes = published.read_reference_map(
        TINY_ROOT / f"individual_reference_maps/map_{TINY_SCENE}.json", len(CLASSES)
    )
    ref, meta = reference_map.published_reference_map(TINY_SCENE, lonlat, classes)
    local = published.read_local_maps(TINY_ROOT / "local_maps.json", TINY_SCENE)
    rec = recover.recover_scene(TINY_SCENE, lonlat, classes, local)
    split = queries.split_queries(list(rec["token"]), 0, salt=TINY_SCENE)
    q = queries.build_queries(TINY_SCENE, rec, ref, local, geo.MetricFrame(meta["lon0"], meta["lat0"]), split)
    results = out / "run" / "results"
    maps = results / TINY_SCENE / "maps"
    reference_map.write_geoparquet(ref, meta, maps / "reference_map.parquet")
    reference_map.write_geojson(ref, meta, maps / "reference_map.geojson")
    files.write_parquet(q, results / TINY_SCENE / "queries" / "queries.parquet")
    files.write_parquet(pd.DataFrame({"scene": [TINY_SCENE]}), results / "tables" / "dataset_stats_per_scene.parquet")
    p = {"results": results, "map": maps / "reference_map.parquet", "geojson": maps / "reference_map.geojson"}
    d = out / "in"
    d.mkdir(parents=True, exist_ok=True)

    def put(name: str, value) -> Path:
        path = d / name
        path.write_text(value if isinstance(value, str) else json.dumps(value))
        p[name] = path
        return path

    r = q[q["split"] == "test"].iloc[0]
    query = localize.query_json(localmaps.local_map(r, "gt"), r.classes)
    objs = query["objects"]
    put("q.json", query)
    rng = np.random.default_rng(0)

    def objects(n: int) -> list:
        c, x, y = rng.integers(0, len(CLASSES), n), rng.uniform(1, 50, n), rng.uniform(-20, 20, n)
        return [{"class": CLASSES[int(k)], "x": float(a), "y": float(b)} for k, a, b in zip(c, x, y)]

    # 1: a crafted city index
    from flatlandia.city import index

    arrays = {f: getattr(index.build(ref, q[q["split"] == "train"]), f) for f in index._FIELDS}
    for name, shift in (("index_1e12.npz", 10**12), ("index_3.npz", 3)):
        np.savez(d / name, **{**arrays, "view_ptr": arrays["view_ptr"] + shift})
        p[name] = d / name
    # 5: sizes, pipes
    put("q_10000.json", {"objects": objects(10_000)})
    put("q_1e6.json", {"objects": [objs[k % len(objs)] for k in range(1_000_000)]})
    put("q_max.json", {"objects": objects(validate.MAX_QUERY_OBJECTS)})
    # the worst a map within the bounds can be: MAX_CLASS_OBJECTS street lights in 300 x 200 m, and
    # queries and sequences of street lights only (every query object has every light as candidate)
    light = CLASSES.index("object--street-light")
    k = validate.MAX_CLASS_OBJECTS
    lon, lat = 2.37 + rng.uniform(-0.0015, 0.0015, k), 48.9 + rng.uniform(-0.001, 0.001, k)
    put(
        "map_worst.geojson",
        {
            "type": "FeatureCollection",
            "features": [
                {
                    "type": "Feature",
                    "geometry": {"type": "Point", "coordinates": [float(a), float(b)]},
                    "properties": {"class": CLASSES[light]},
                }
                for a, b in zip(lon, lat)
            ],
        },
    )
    lights = [{**o, "class": CLASSES[light]} for o in objects(validate.MAX_QUERY_OBJECTS)]
    put("q_worst.json", {"objects": lights})
    steps = [{"objects": lights[:17], "pose": {"x": 0.5 * k, "y": 0.0}} for k in range(1, validate.MAX_SEQUENCE_FRAMES)]
    put("seq_worst.json", {"frames": [{"objects": lights[:17]}] + steps})
    put("seq_1000.json", {"frames": [{"objects": objs}] + [{"objects": objs, "pose": {"x": 1.0, "y": 0.0}}] * 999})
    put("q_many.json", {"queries": [{"id": str(k), "objects": objs} for k in range(validate.MAX_QUERIES)]})
    for name in ("fifo.json", "fifo.zip"):
        if not (d / name).exists():
            os.mkfifo(d / name)
        p[name] = d / name
    n = min(validate.MAX_MAP_OBJECTS, validate.MAX_CLASS_OBJECTS * len(CLASSES))  # every class at its bound
    lon, lat = 2.37 + rng.uniform(-0.015, 0.015, n), 48.9 + rng.uniform(-0.01, 0.01, n)
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [float(a), float(b)]},
            "properties": {"class": CLASSES[int(k)]},
        }
        for a, b, k in zip(lon, lat, np.arange(n) % len(CLASSES))
    ]
    put("map_max.geojson", {"type": "FeatureCollection", "features": feats})
    train = q[q["split"] == "train"][["scene", "token", "x_m", "y_m", "theta_deg"]]
    rows = train.to_csv(index=False, header=False).encode()
    with gzip.open(d / "bomb.csv.gz", "wb", compresslevel=1) as f:  # 2 GB of rows in a few MB
        f.write(b"scene,token,x_m,y_m,theta_deg\n")
        for _ in range(2 * 10**9 // len(rows)):
            f.write(rows)
    p["bomb.csv.gz"] = d / "bomb.csv.gz"
    with open(d / "sparse.csv", "wb") as f:
        f.write(b"scene,token,x_m,y_m,theta_deg\n")
        f.truncate(2 * 10**9)
    p["sparse.csv"] = d / "sparse.csv"
    # 6, 8: lying metadata, hostile JSON and priors
    import pyarrow.parquet as pq

    table = pq.read_table(p["map"])
    for name, text in (
        ("lon0_1e9.parquet", json.dumps({**meta, "lon0": 1e9})),
        ("meta_list.parquet", "[1, 2]"),
        ("lon0_abc.parquet", json.dumps({**meta, "lon0": "abc"})),
        ("lon0_nan.parquet", '{"lon0": NaN, "lat0": 48.0}'),
    ):
        md = dict(table.schema.metadata)
        md[b"flatlandia"] = text.encode()
        pq.write_table(table.replace_schema_metadata(md), d / name)
        p[name] = d / name
    ids = table.column("obj_idx").to_pylist()
    ids[1] = ids[0]
    import pyarrow as pa

    pq.write_table(
        table.set_column(table.schema.get_field_index("obj_idx"), "obj_idx", pa.array(ids, pa.int64())),
        d / "dup.parquet",
    )
    p["dup.parquet"] = d / "dup.parquet"
    g = json.loads(p["geojson"].read_text())
    for name, change in (
        ("props_list.geojson", lambda f: f.update(properties=[1, 2])),
        ("props_str.geojson", lambda f: f.update(properties="abc")),
        ("bool.geojson", lambda f: f["geometry"].update(coordinates=[True, False])),
    ):
        doc = json.loads(json.dumps(g))
        change(doc["features"][0])
        put(name, doc)
    put("deep.json", "[" * 100_000 + "]" * 100_000)
    put(
        "digits.json",
        '{"objects": [{"class": "object--bench", "x": ' + "9" * 4301 + ', "y": 1}, ' + json.dumps(objs)[1:] + "}",
    )
    put("e400.json", json.dumps({"objects": [{**objs[0], "x": 10**400}, *objs[1:]]}))
    put("seq_1e308.json", {"frames": [{"objects": objs}, {"objects": objs, "pose": {"x": 1e308, "y": 0}}]})
    put("class_1mb.json", {"objects": [{**objs[0], "class": "x" * 1_000_000}, *objs[1:]]})
    nf = 9
    put("priors_nan.json", '{"scale_prior": [NaN, 0.4], "verifier": null}')
    put("priors_sigma0.json", {"scale_prior": [3.0, 0.0], "verifier": None})
    put(
        "priors_len.json",
        {"scale_prior": [3.0, 0.4], "verifier": {"weights": [0.1] * (nf + 3), "mean": [0.0] * nf, "scale": [1.0] * nf}},
    )
    t = json.loads((TINY_ROOT / "maps" / TINY_SCENE / "transformations.json").read_text())
    t["to_mapillary"]["rotation"][0][0] = float("nan")
    put("transformations_nan.json", json.dumps(t))
    # 7, 10: poses
    truth = q[q["split"] == "train"]
    km = truth.assign(x_m=truth["x_m"] / 1000, y_m=truth["y_m"] / 1000)[["scene", "token", "x_m", "y_m", "theta_deg"]]
    km.to_csv(d / "km.csv", index=False)
    pd.concat([km.iloc[:4], truth[km.columns].iloc[4:]]).to_csv(d / "km_some.csv", index=False)
    frame = geo.MetricFrame(meta["lon0"], meta["lat0"])
    ll = frame.to_lonlat(truth[["x_m", "y_m"]].to_numpy(float))
    pd.DataFrame(
        {
            "scene": truth["scene"],
            "token": truth["token"],
            "lon": np.radians(ll[:, 0]),
            "lat": np.radians(ll[:, 1]),
            "heading_deg": 90 - truth["theta_deg"],
        }
    ).to_csv(d / "radians.csv", index=False)
    odd = truth[km.columns].astype(str)
    odd.loc[odd.index[0], "x_m"] = "1_000"
    odd.loc[odd.index[1], "y_m"] = "\uff11\uff12"
    odd.to_csv(d / "digits.csv", index=False)
    long_token = truth[km.columns].copy()
    long_token.loc[long_token.index[0], "token"] = "7" * 10_000_000
    long_token.to_csv(d / "long_token.csv", index=False)
    for name in ("km.csv", "km_some.csv", "radians.csv", "digits.csv", "long_token.csv"):
        p[name] = d / name
    # 2: fetch
    run = out / "run"
    photos = run / "my_photos"
    photos.mkdir(parents=True, exist_ok=True)
    (photos / "01.jpg").write_bytes(b"my photo")
    (photos / ".flatlandia-fetch").write_text('{"url": "x"}')
    import zipfile

    with zipfile.ZipFile(d / "archive.zip", "w") as z:
        z.writestr("top/imgs/1.jpg", b"1")
    p["archive.zip"], p["run"], p["photos"] = d / "archive.zip", run, photos
    # 5, 8: provenance records
    prov = run / "logs" / "provenance"
    shutil.rmtree(prov, ignore_errors=True)
    with open(d / "big.bin", "wb") as f:
        f.truncate(40 * 10**9)
    base = {
        "wildcards": {},
        "inputs": {},
        "config_hash": "0",
        "package_version": "0",
        "git_commit": "x",
        "finished_at": "now",
    }
    for name, rec in {
        "root": {**base, "rule": "root", "outputs": {"/": {"sha256": "0", "bytes": 1}}},
        "big": {**base, "rule": "big", "outputs": {str(d / "big.bin"): {"sha256": "0", "bytes": 1}}},
        "list": {**base, "rule": "list", "outputs": ["results/x"]},
        "norule": {**base, "outputs": {}},
    }.items():
        (prov / name).mkdir(parents=True)
        (prov / name / "all.json").write_text(json.dumps(rec))
    (prov / "broken").mkdir()
    (prov / "broken" / "all.json").write_text("{not json")
    good = run / "results" / "good.txt"
    good.write_text("good")
    (prov / "good").mkdir()
    rec = {**base, "rule": "good", "outputs": {"results/good.txt": {"sha256": files.sha256(good), "bytes": 4}}}
    (prov / "good" / "all.json").write_text(json.dumps(rec))
    # 8: checkpoints
    import torch

    from flatlandia import checkpoints
    from flatlandia.fine import models

    cfg = models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)
    state = models.build_model(cfg).state_dict()
    nan = {k: torch.full_like(v, float("nan")) if v.is_floating_point() else v for k, v in state.items()}
    for name, st, text in (
        ("ck_nan.pt", nan, json.dumps({"config": cfg.to_dict()})),
        ("ck_huge.pt", state, json.dumps({"config": {**cfg.to_dict(), "hidden": 200000, "heads": 64}})),
        ("ck_deep.pt", state, "[" * 100_000 + "]" * 100_000),
    ):
        torch.save({"format": checkpoints.FORMAT, "state_dict": st, "meta": text}, d / name)
        p[name] = d / name
    # 8: YAML config nested deep (Snakemake's loader takes about 250 levels; ours stops at 16)
    put("deep200.yaml", "seed: " + "[" * 200 + "1" + "]" * 200 + "\n")
    # 10: EXIF
    from PIL import ExifTags, Image
    from PIL.TiffImagePlugin import IFDRational

    exif_dir = d / "exif"
    exif_dir.mkdir(exist_ok=True)
    ex = Image.Exif()
    gps = ex.get_ifd(ExifTags.IFD.GPSInfo)
    gps[ExifTags.GPS.GPSLatitudeRef], gps[ExifTags.GPS.GPSLongitudeRef] = "N", "E"
    gps[ExifTags.GPS.GPSLatitude] = (IFDRational(1e9), IFDRational(0), IFDRational(0))
    gps[ExifTags.GPS.GPSLongitude] = (IFDRational(13), IFDRational(11), IFDRational(0))
    Image.new("RGB", (64, 64)).save(exif_dir / "lat.jpg", exif=ex)
    ex = Image.Exif()
    ex[ExifTags.Base.ImageDescription] = json.dumps(
        {"MAPLatitude": 55.7, "MAPLongitude": 13.2, "MAPCompassHeading": {"TrueHeading": 1e308}}
    )
    Image.new("RGB", (64, 64)).save(exif_dir / "heading.jpg", exif=ex)
    p["exif"] = exif_dir
    p["debug"] = out / "debug" / "a" / "b" / "c" / "run"  # an empty working folder, three folders down
    p["debug"].mkdir(parents=True, exist_ok=True)
    return p


def python(code: str) -> list[str]:
    """A probe that calls the rule's entry from Python, as its script does (one ERROR line on InputError)."""
    head = "import sys\nfrom flatlandia.plumbing.errors import InputError\ntry:\n"
    body = "".join(f"    {line}\n" for line in code.strip().splitlines())
    tail = "except InputError as e:\n    print(f'ERROR: {e}')\n    sys.exit(1)\n"
    return [sys.executable, "-c", head + body + tail]


def probes(p: dict) -> list[tuple[str, str, list[str], Path | None]]:
    """(finding, probe, command, working folder) of every probe."""
    loc = [*FLATLANDIA, "localize", "--map", str(p["map"])]
    score = [
        *FLATLANDIA,
        "score",
        "--name",
        "mine",
        "--split",
        "train",
        "--results",
        str(p["results"]),
        "--out",
        str(p["run"] / "scores"),
    ]
    q = str(p["q.json"])
    run = p["run"]
    return [
        (
            "1",
            "index view_ptr + 10**12",
            [*FLATLANDIA, "localize", "--map", str(p["index_1e12.npz"]), "--query", q],
            None,
        ),
        ("1", "index view_ptr + 3", [*FLATLANDIA, "localize", "--map", str(p["index_3.npz"]), "--query", q], None),
        (
            "2",
            "fetch.dest a folder with a forged .flatlandia-fetch",
            python(f"""
from flatlandia.data import fetch
import os; os.chdir({str(run)!r})
try:
    fetch.fetch_images({p["archive.zip"].as_uri()!r}, 'imgs', 'my_photos', timeout_s=5)
except fetch.FetchError as e:
    print('ERROR:', str(e)[:300]); sys.exit(1)
"""),
            None,
        ),
        (
            "2",
            "fetch.dest an absolute path outside the run",
            python(f"""
from flatlandia.data import fetch
try:
    fetch.check_dest({str(p["photos"].parent.parent / "elsewhere")!r}, {str(run)!r})
except fetch.FetchError as e:
    print('ERROR:', str(e)[:300]); sys.exit(1)
"""),
            None,
        ),
        (
            "3",
            "debug solver_priors region=../../../../x/pwn",
            [*FLATLANDIA, "debug", "solver_priors", "region=../../../../x/pwn", "-d", "."],
            p["debug"],
        ),
        (
            "3",
            "debug reference_map scene=999",
            [*FLATLANDIA, "debug", "reference_map", "scene=999", "-d", "."],
            p["debug"],
        ),
        (
            "4",
            "export: tokens +cmd|calc, =HYPERLINK(...), city =HYPERLINK(...)",
            python(f"""
import pandas as pd
from flatlandia.data import export
from flatlandia.plumbing import files
ref = pd.read_parquet({str(p["map"])!r}); meta = files.read_parquet_metadata({str(p["map"])!r})
q = pd.read_parquet({str(p["results"] / TINY_SCENE / "queries" / "queries.parquet")!r})
q['token'] = ['+cmd|calc' if k == 0 else '=HYPERLINK("x")' if k == 1 else t for k, t in enumerate(q['token'])]
out = export.scene_export('0', ref, meta, q)
idx = export.index_export([dict(scene='0', city='=HYPERLINK("x")', ref=ref, meta=meta, queries=q)], [])
cells = [l.split(',')[0] for l in export.csv_text(out['queries']).splitlines()[1:3]]
print('wrote', cells, 'and city', export.csv_text(idx['scenes']).splitlines()[1].split(',')[1])
"""),
            None,
        ),
        ("5", "localize 10,000 objects", [*loc, "--query", str(p["q_10000.json"])], None),
        ("5", "localize 10^6 objects", [*loc, "--query", str(p["q_1e6.json"])], None),
        ("5", "sequence of 1,000 frames", [*loc, "--sequence", str(p["seq_1000.json"]), "--map-type", "depth"], None),
        ("5", "--query a FIFO", [*loc, "--query", str(p["fifo.json"])], None),
        ("5", "--query /dev/zero", [*loc, "--query", "/dev/zero"], None),
        (
            "5",
            "fetch.url file:// a FIFO",
            python(f"""
from flatlandia.data import fetch
try:
    fetch.fetch_images({p["fifo.zip"].as_uri()!r}, 'imgs', 'x', timeout_s=5, workdir={str(run)!r})
except fetch.FetchError as e:
    print('ERROR:', e); sys.exit(1)
"""),
            None,
        ),
        ("5", "score a 15 MB .csv.gz of 2 GB of rows", [*score, str(p["bomb.csv.gz"])], None),
        ("5", "score a 2 GB sparse CSV", [*score, str(p["sparse.csv"])], None),
        ("5, 8", "audit --check: records naming /, a 40 GB file, broken ones", [*FLATLANDIA, "audit", "--check"], run),
        (
            "5",
            "bound: depth query of 100 street lights on 300 of them (MAX_QUERY_OBJECTS, MAX_CLASS_OBJECTS)",
            [
                *FLATLANDIA,
                "localize",
                "--map",
                str(p["map_worst.geojson"]),
                "--query",
                str(p["q_worst.json"]),
                "--map-type",
                "depth",
            ],
            None,
        ),
        (
            "5",
            "bound: sequence of 20 frames of 17 street lights on 300 of them (MAX_SEQUENCE_FRAMES)",
            [
                *FLATLANDIA,
                "localize",
                "--map",
                str(p["map_worst.geojson"]),
                "--sequence",
                str(p["seq_worst.json"]),
                "--map-type",
                "depth",
            ],
            None,
        ),
        (
            "5",
            "bound: depth query of 100 objects on 12,600 (300 of each class)",
            [
                *FLATLANDIA,
                "localize",
                "--map",
                str(p["map_max.geojson"]),
                "--query",
                str(p["q_max.json"]),
                "--map-type",
                "depth",
            ],
            None,
        ),
        ("5", "bound: MAX_QUERIES (10,000) queries, GT", [*loc, "--query", str(p["q_many.json"])], None),
        (
            "6",
            "transformations.json with a NaN rotation",
            python(f"""
from flatlandia.data import published
published.read_transformations({str(p["transformations_nan.json"])!r})
"""),
            None,
        ),
        (
            "6",
            "map metadata lon0 = 1e9",
            [*FLATLANDIA, "localize", "--map", str(p["lon0_1e9.parquet"]), "--query", q],
            None,
        ),
        (
            "6",
            "priors JSON with a NaN scale",
            [*loc, "--query", q, "--map-type", "depth", "--priors", str(p["priors_nan.json"])],
            None,
        ),
        (
            "6",
            "checkpoint with NaN weights",
            python(f"""
from flatlandia import checkpoints
from flatlandia.fine import models
checkpoints.load_checkpoint({str(p["ck_nan.pt"])!r}, models.FineTrainConfig, models.build_model)
"""),
            None,
        ),
        ("7", "score x_m, y_m in km (every row)", [*score, str(p["km.csv"])], None),
        ("7", "score 4 of 10 rows in km", [*score, str(p["km_some.csv"])], None),
        ("7", "score lon, lat in radians", [*score, str(p["radians.csv"])], None),
        ("8", "query JSON nested 100,000 deep", [*loc, "--query", str(p["deep.json"])], None),
        ("8", "an integer of 4,301 digits", [*loc, "--query", str(p["digits.json"])], None),
        ("8", "10**400", [*loc, "--query", str(p["e400.json"])], None),
        ("8", "sequence pose x = 1e308", [*loc, "--sequence", str(p["seq_1e308.json"]), "--map-type", "depth"], None),
        (
            "8",
            "map metadata a list",
            [*FLATLANDIA, "localize", "--map", str(p["meta_list.parquet"]), "--query", q],
            None,
        ),
        (
            "8",
            'map metadata "lon0": "abc"',
            [*FLATLANDIA, "localize", "--map", str(p["lon0_abc.parquet"]), "--query", q],
            None,
        ),
        (
            "8",
            "map metadata lon0 NaN",
            [*FLATLANDIA, "localize", "--map", str(p["lon0_nan.parquet"]), "--query", q],
            None,
        ),
        (
            "8",
            "GeoJSON properties a list",
            [*FLATLANDIA, "localize", "--map", str(p["props_list.geojson"]), "--query", q],
            None,
        ),
        (
            "8",
            "GeoJSON properties a string",
            [*FLATLANDIA, "localize", "--map", str(p["props_str.geojson"]), "--query", q],
            None,
        ),
        ("8", "--gps-sigma-m 1e308", [*loc, "--query", q, "--gps", "2.0,48.0", "--gps-sigma-m", "1e308"], None),
        (
            "8",
            "verifier weights of the wrong length",
            [*loc, "--query", q, "--map-type", "depth", "--priors", str(p["priors_len.json"])],
            None,
        ),
        (
            "8",
            "scale-prior sigma 0",
            [*loc, "--query", q, "--map-type", "depth", "--priors", str(p["priors_sigma0.json"])],
            None,
        ),
        (
            "8",
            "checkpoint config hidden=200000, heads=64",
            python(f"""
from flatlandia import checkpoints
from flatlandia.fine import models
checkpoints.load_checkpoint({str(p["ck_huge.pt"])!r}, models.FineTrainConfig, models.build_model)
"""),
            None,
        ),
        (
            "8",
            "checkpoint meta nested 100,000 deep",
            python(f"""
from flatlandia import checkpoints
from flatlandia.fine import models
checkpoints.load_checkpoint({str(p["ck_deep.pt"])!r}, models.FineTrainConfig, models.build_model)
"""),
            None,
        ),
        (
            "8",
            "config value nested 200 deep (snakemake -n)",
            [
                SNAKEMAKE,
                "-s",
                str(REPO / "Snakefile"),
                "-d",
                str(run),
                "-n",
                "all",
                "--configfile",
                str(p["deep200.yaml"]),
            ],
            None,
        ),
        (
            "9",
            "city $\\input{secret.tex}$ in plot_reference_map",
            python(f"""
import pandas as pd
from flatlandia.data import reference_map
ref = pd.read_parquet({str(p["map"])!r}); q = pd.read_parquet({str(p["results"] / TINY_SCENE / "queries" / "queries.parquet")!r})
reference_map.plot_reference_map(ref, q, {str(run / "map.png")!r}, r'scene 0 ($\\input{{secret.tex}}$): 30 objects')
print('wrote', {str(run / "map.png")!r})
"""),
            None,
        ),
        (
            "10",
            "EXIF latitude 1e9, heading 1e308",
            python(f"""
from flatlandia.images import image_audit
df = image_audit.read_folder_metadata({str(p["exif"])!r})
print('; '.join(f'{{n}}: dropped: {{r}}' for n, r in zip(df['name'], df['problem'])))
"""),
            None,
        ),
        ("10", "poses 1_000 and full-width digits", [*score, str(p["digits.csv"])], None),
        (
            "10",
            "duplicate obj_idx in a map",
            [*FLATLANDIA, "localize", "--map", str(p["dup.parquet"]), "--query", q],
            None,
        ),
        (
            "10",
            "GeoJSON coordinates [true, false]",
            [*FLATLANDIA, "localize", "--map", str(p["bool.geojson"]), "--query", q],
            None,
        ),
        ("10", "a 10 MB token in a poses file", [*score, str(p["long_token.csv"])], None),
        ("10", "a 1 MB class name", [*loc, "--query", str(p["class_1mb.json"])], None),
    ]


# ----------------------------------------------------------------------------- issue 42


def _results_copy(p: dict, out: Path, name: str, change) -> Path:
    """A copy of the probes' results folder named ``name`` with ``change(results)`` applied (a lie)."""
    dest = out / "lies" / name / "results"
    shutil.rmtree(dest.parent, ignore_errors=True)
    shutil.copytree(p["results"], dest, symlinks=True)
    change(dest)
    return dest


def _export(p: dict, folder: Path) -> Path:
    """The tiny scene's export (rules export_scene and export_index), what ``localize --batch`` reads."""
    from flatlandia.data import export

    ref = pd.read_parquet(p["map"])
    meta = files.read_parquet_metadata(p["map"])
    q = pd.read_parquet(p["results"] / TINY_SCENE / "queries" / "queries.parquet")
    shutil.rmtree(folder, ignore_errors=True)
    scene = export.scene_export(TINY_SCENE, ref, meta, q)
    for name in ("reference_map", "queries", "local_maps", "proposals", "ground_truth"):
        files.write_text(export.csv_text(scene[name]), folder / TINY_SCENE / f"{name}.csv")
    files.write_text(json.dumps(scene["reference_geojson"]) + "\n", folder / TINY_SCENE / "reference_map.geojson")
    files.write_json(scene["frame"], folder / TINY_SCENE / "frame.json")
    idx = export.index_export([{"scene": TINY_SCENE, "city": "Flatland", "ref": ref, "meta": meta, "queries": q}], [])
    for name in ("classes", "scenes", "template"):
        files.write_text(export.csv_text(idx[name]), folder / f"{'poses_template' if name == 'template' else name}.csv")
    return folder


def _record(rule: str, outputs: dict, inputs: dict | None = None) -> dict:
    return {
        "rule": rule,
        "wildcards": {"scene": TINY_SCENE},
        "inputs": inputs or {},
        "outputs": {k: {"sha256": v, "bytes": 1} for k, v in outputs.items()},
        "config_hash": "0",
        "package_version": "0",
        "git_commit": "x",
        "finished_at": "now",
    }


def build_42(out: Path, p: dict) -> None:
    """The inputs of issue 42's probes, added to ``p``."""
    import zipfile

    import pyarrow as pa
    import pyarrow.parquet as pq
    import torch

    from flatlandia import checkpoints, solver
    from flatlandia.fine import models

    d = out / "in42"
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)

    def put(name: str, value) -> Path:
        path = d / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(value if isinstance(value, str) else json.dumps(value))
        p[name] = path
        return path

    # 1, 2: a fetch into a virtualenv's site-packages, or into an absent ~/.ssh of a temporary HOME
    run = out / "run42"
    shutil.rmtree(run, ignore_errors=True)
    site = run / ".venv" / "lib" / "python3.11" / "site-packages"
    site.mkdir(parents=True)
    (run / ".venv" / "pyvenv.cfg").write_text("home = /usr/bin\n")
    (run / "resources").mkdir()
    with zipfile.ZipFile(d / "evil.zip", "w") as z:
        z.writestr("top/data/__init__.py", "print('PWNED: code from a fetched archive ran')\n")
        z.writestr("top/data/authorized_keys", "ssh-ed25519 AAAA attacker\n")
    p["evil.zip"], p["run42"], p["home"] = d / "evil.zip", run, out / "home42"
    shutil.rmtree(p["home"], ignore_errors=True)
    p["home"].mkdir()
    # 3, 4, 5: --out onto /dev (a link to /dev/null made here), onto the command's inputs, audit --write
    (run / "devnull").symlink_to("/dev/null")
    solver.LearnedPriors((3.0, 0.4), None).write(run / "priors.json")
    p["export"] = _export(p, run / "results" / "export")
    rows = pd.read_csv(p["export"] / TINY_SCENE / "queries.csv", dtype=str)
    fixes = pd.DataFrame({"scene": TINY_SCENE, "token": rows["token"], "lon": 11.0, "lat": 48.0, "sigma_m": 50.0})
    fixes.head(2).to_csv(run / "fixes.csv", index=False)
    (run / "in_the_way.json").mkdir()
    audit = out / "audit42"
    shutil.rmtree(audit, ignore_errors=True)
    maps = audit / "results" / TINY_SCENE / "maps"
    maps.mkdir(parents=True)
    shutil.copy(p["map"], maps / "reference_map.parquet")
    (audit / "res_link").symlink_to("results", target_is_directory=True)
    prov = audit / "logs" / "provenance"
    artifact = f"results/{TINY_SCENE}/maps/reference_map.parquet"
    rec = _record("reference_map", {artifact: files.sha256(maps / "reference_map.parquet")})
    (prov / "reference_map").mkdir(parents=True)
    (prov / "reference_map" / "all.json").write_text(json.dumps(rec))
    hostile = _record("\x1b]0;pwned\x07\x1b[2J", {"results/\x1b[31mred\u202etxt.exe": "0"})
    (prov / "hostile").mkdir()
    (prov / "hostile" / "all.json").write_text(json.dumps(hostile))
    p["audit42"] = audit
    chain = out / "chain42"
    shutil.rmtree(chain, ignore_errors=True)
    (chain / "results").mkdir(parents=True)
    for k in range(1500):
        (chain / "results" / f"c{k}").write_text(str(k))
        rec = _record(f"c{k}", {f"results/c{k}": files.sha256(chain / "results" / f"c{k}")}, {f"results/c{k - 1}": "0"})
        (chain / "logs" / "provenance" / f"c{k}").mkdir(parents=True)
        (chain / "logs" / "provenance" / f"c{k}" / "all.json").write_text(json.dumps(rec))
    p["chain42"] = chain
    # 6: a score whose scores.md is a folder in the way
    q = pd.read_parquet(p["results"] / TINY_SCENE / "queries" / "queries.parquet")
    train = q[q["split"] == "train"][["scene", "token", "x_m", "y_m", "theta_deg"]]
    train.to_csv(d / "truth.csv", index=False)
    p["truth.csv"] = d / "truth.csv"
    (out / "scores42" / "scores.md").mkdir(parents=True, exist_ok=True)
    p["scores42"] = out / "scores42"
    # 7: unbounded work: an alias bomb, a deflated checkpoint, dictionary-encoded Parquet bombs
    levels = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"] + [
        f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 9) + "]" for k in range(1, 10)
    ]
    put("alias_bomb.yaml", "\n".join(levels) + "\n")
    put("twice.yaml", "seed: 1\nseed: 2\n")
    # YAML 1.1 reads 1e300 as text: written as a float and a 24-digit integer
    put("megapixels.yaml", "images:\n  max_megapixels: 1.0e+300\n  min_side_px: 100000000000000000000000\n")
    cfg = models.FineTrainConfig(model="MLP", map_type="gt", hidden=8, epochs=1)
    state = models.build_model(cfg).state_dict()
    torch.save(
        {"format": checkpoints.FORMAT, "state_dict": state, "meta": json.dumps({"config": cfg.to_dict()})}, d / "ck.pt"
    )
    zero = bytes(1 << 24)
    with zipfile.ZipFile(d / "ck.pt") as z, zipfile.ZipFile(d / "ck_deflated.pt", "w") as zout:
        for info in z.infolist():
            zi = zipfile.ZipInfo(info.filename, info.date_time)
            zi.compress_type = zipfile.ZIP_DEFLATED
            if info.filename.endswith("/data/0"):
                with zout.open(zi, "w", force_zip64=True) as f:
                    f.write(z.read(info))
                    for _ in range(2 * 10**9 // len(zero)):  # 2 GB of zeros: 2 MB deflated
                        f.write(zero)
            else:
                zout.writestr(zi, z.read(info))
    p["ck_deflated.pt"] = d / "ck_deflated.pt"

    def dictionary_bomb(table: pa.Table, rows: int, value_bytes: int, path: Path) -> Path:
        big = table.take(pa.array([k % table.num_rows for k in range(rows)], pa.int64()))
        pad = pa.DictionaryArray.from_arrays(pa.array([0] * rows, pa.int32()), pa.array(["x" * value_bytes]))
        pq.write_table(big.append_column("pad", pad), path, dictionary_pagesize_limit=10**9, store_schema=False)
        p[path.name] = path
        return path

    dictionary_bomb(pq.read_table(p["map"]), validate.MAX_MAP_OBJECTS, 190_000, d / "map_dict_bomb.parquet")
    dictionary_bomb(
        pa.Table.from_pandas(train, preserve_index=False),
        validate.MAX_POSES_ROWS,
        19_000,
        d / "poses_dict_bomb.parquet",
    )
    # 8: tracebacks: EXIF descriptions, priors calibrations, lying results folders and exports
    from PIL import ExifTags, Image

    exif = d / "exif"
    exif.mkdir()
    for name, desc in (
        ("brackets.jpg", '{"a": ' + "[" * 20_000 + "]" * 20_000 + "}"),
        ("digits.jpg", '{"MAPLatitude": ' + "9" * 5000 + "}"),
    ):
        ex = Image.Exif()
        ex[ExifTags.Base.ImageDescription] = desc
        Image.new("RGB", (64, 64), (120, 130, 140)).save(exif / name, exif=ex)
    Image.new("RGB", (64, 64), (20, 30, 40)).save(exif / "plain.jpg")
    p["exif42"] = exif
    meta_csv = d / "exif_csv"
    meta_csv.mkdir()
    Image.new("RGB", (64, 64)).save(meta_csv / "a.jpg")
    (meta_csv / "metadata.csv").write_text("name,lat,lon,alt,heading\na.jpg,55.7,13.2,1e308,1e308\n")
    p["exif_csv42"] = meta_csv
    good = solver.LearnedPriors((3.0, 0.4), None).to_dict()
    cal = {"features": ["log_odds", "log_objects", "log_frames", "agreement"], "sequence": None}
    put("priors_cal_list.json", {**good, "calibration": [1]})
    put("priors_cal_text.json", {**good, "calibration": "abc"})
    put(
        "priors_weights_text.json",
        {**good, "calibration": {**cal, "frame": {"intercept": 0.0, "weights": "1234", "answers": 50}}},
    )
    put(
        "priors_weights_1e308.json",
        {
            **good,
            "calibration": {**cal, "frame": {"intercept": 0.0, "weights": [1e308, -1e308, 1e308, 1.0], "answers": 50}},
        },
    )

    def meta_lie(value):
        def change(results: Path) -> None:
            path = results / TINY_SCENE / "maps" / "reference_map.parquet"
            t = pq.read_table(path)
            md = dict(t.schema.metadata)
            md[b"flatlandia"] = value.encode()
            pq.write_table(t.replace_schema_metadata(md), path)

        return change

    meta = files.read_parquet_metadata(p["map"])
    p["results_lon0_text"] = _results_copy(p, out, "lon0_text", meta_lie(json.dumps({**meta, "lon0": "abc"})))
    p["results_lon0_nan"] = _results_copy(p, out, "lon0_nan", meta_lie(json.dumps({**meta, "lon0": float("nan")})))

    def queries_change(f):
        def change(results: Path) -> None:
            path = results / TINY_SCENE / "queries" / "queries.parquet"
            f(path, pd.read_parquet(path))

        return change

    p["results_no_split"] = _results_copy(
        p, out, "no_split", queries_change(lambda path, t: t.drop(columns="split").to_parquet(path))
    )
    p["results_nan_truth"] = _results_copy(
        p,
        out,
        "nan_truth",
        queries_change(lambda path, t: t.assign(x_m=[float("nan")] + list(t["x_m"][1:])).to_parquet(path)),
    )

    def fifo(path: Path, t) -> None:
        path.unlink()
        os.mkfifo(path)

    p["results_fifo"] = _results_copy(p, out, "fifo", queries_change(fifo))
    for name, change in (
        ("ids_20_digits", lambda g: g.assign(matched_obj_idx="1" * 20)),
        ("x_nan", lambda g: g.assign(x_m="nan")),
        ("x_1e300", lambda g: g.assign(x_m="1e300")),
        ("id_99999", lambda g: g.assign(matched_obj_idx="99999")),
        ("id_negative", lambda g: g.assign(matched_obj_idx="-5")),
    ):
        ex = out / "exports" / name
        shutil.rmtree(ex, ignore_errors=True)
        shutil.copytree(p["export"], ex)
        gt = pd.read_csv(ex / TINY_SCENE / "ground_truth.csv", dtype=str, keep_default_na=False)
        change(gt).to_csv(ex / TINY_SCENE / "ground_truth.csv", index=False)
        p[f"export_{name}"] = ex
    state_dir = out / "fetch_state42"
    shutil.rmtree(state_dir, ignore_errors=True)
    (state_dir / "resources" / "data").mkdir(parents=True)
    (state_dir / "resources" / ".flatlandia-fetches.json").write_text(
        '{"' + str((state_dir / "resources" / "data").resolve()) + '": {"inode": NaN, "url": "x"}}'
    )
    p["fetch_state42"] = state_dir
    # manifest fallback: no artifact column, bad JSON cells, not Parquet
    for name, df in (
        ("manifest_no_artifact", pd.DataFrame({"rule": ["x"]})),
        (
            "manifest_bad_json",
            pd.DataFrame(
                {"artifact": ["results/x"], "rule": ["x"], "inputs": ["{not json"], "sha256": ["0"], "bytes": [1]}
            ),
        ),
    ):
        folder = out / name
        shutil.rmtree(folder, ignore_errors=True)
        (folder / "results").mkdir(parents=True)
        df.to_parquet(folder / "results" / "manifest.parquet")
        p[name] = folder
    folder = out / "manifest_not_parquet"
    shutil.rmtree(folder, ignore_errors=True)
    (folder / "results").mkdir(parents=True)
    (folder / "results" / "manifest.parquet").write_text("not parquet")
    p["manifest_not_parquet"] = folder


def probes_42(p: dict) -> list[tuple[str, str, list[str], Path | None]]:
    """(finding, probe, command, working folder) of every probe of issue 42."""
    run, q = p["run42"], str(p["q.json"])
    loc = [*FLATLANDIA, "localize", "--map", str(p["map"]), "--query", q]
    score = [*FLATLANDIA, "score", "--name", "mine", "--split", "train"]
    snakemake_n = [SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(run), "-n", "all", "--configfile"]
    batch = [*FLATLANDIA, "localize", "--batch"]
    fetch_code = """
from flatlandia.data import fetch
import os, pandas as pd
os.chdir({run!r})
{home}
scenes = pd.DataFrame({{"scene": ["0"], "city": ["x"], "name": ["y"]}})
try:
    got = fetch.fetch_flatlandia({dest!r}, scenes, url={url!r}, timeout_s=5, workdir={run!r}, data_folder={data!r})
    print("wrote", got, sorted(os.listdir(got)))
except fetch.FetchError as e:
    print("ERROR:", str(e)[:300]); sys.exit(1)
"""
    load_ck = """
from flatlandia import checkpoints
from flatlandia.fine import models
checkpoints.load_checkpoint({path!r}, models.FineTrainConfig, models.build_model)
print("loaded")
"""
    return [
        (
            "42.1",
            "fetch.dest .venv/lib/python3.11/site-packages/sitecustomize",
            python(
                fetch_code.format(
                    run=str(run),
                    home="",
                    dest=".venv/lib/python3.11/site-packages/sitecustomize",
                    url=p["evil.zip"].as_uri(),
                    data="/nonexistent",
                )
            ),
            None,
        ),
        (
            "42.2",
            "fetch.dest = flatlandia_root = an absent ~/.ssh (temporary HOME)",
            python(
                fetch_code.format(
                    run=str(run),
                    home=f"os.environ['HOME'] = {str(p['home'])!r}",
                    dest=str(p["home"] / ".ssh"),
                    url=p["evil.zip"].as_uri(),
                    data=str(p["home"] / ".ssh"),
                )
            ),
            None,
        ),
        ("42.3", "localize --out a link to /dev/null", [*loc, "--out", str(run / "devnull")], None),
        (
            "42.3",
            "audit --write a link to /dev/null",
            [*FLATLANDIA, "audit", "--write", str(run / "devnull")],
            p["audit42"],
        ),
        (
            "42.4",
            "localize --priors P.json --out P.json",
            [*loc, "--map-type", "depth", "--priors", str(run / "priors.json"), "--out", str(run / "priors.json")],
            None,
        ),
        (
            "42.4",
            "localize --batch --fixes F.csv --out F.csv",
            [*batch, str(p["export"]), "--fixes", str(run / "fixes.csv"), "--out", str(run / "fixes.csv")],
            None,
        ),
        (
            "42.4",
            "localize --batch EXPORT --out EXPORT/0/ground_truth.csv",
            [*batch, str(p["export"]), "--out", str(p["export"] / TINY_SCENE / "ground_truth.csv")],
            None,
        ),
        (
            "42.5",
            "audit --write results/../results/0/maps/reference_map.parquet",
            [*FLATLANDIA, "audit", "--write", f"results/../results/{TINY_SCENE}/maps/reference_map.parquet"],
            p["audit42"],
        ),
        (
            "42.5",
            "audit --write through a link to results/",
            [*FLATLANDIA, "audit", "--write", f"res_link/{TINY_SCENE}/maps/reference_map.parquet"],
            p["audit42"],
        ),
        (
            "42.6",
            "score --out DIR whose scores.md is a folder in the way",
            [*score, str(p["truth.csv"]), "--results", str(p["results"]), "--out", str(p["scores42"])],
            None,
        ),
        ("42.7", "config: a 477-byte YAML alias bomb (snakemake -n)", [*snakemake_n, str(p["alias_bomb.yaml"])], None),
        (
            "42.7",
            "checkpoint whose weight deflates 2 GB into 2 MB",
            python(load_ck.format(path=str(p["ck_deflated.pt"]))),
            None,
        ),
        (
            "42.7",
            "score a dictionary-encoded poses Parquet of 3.8 GB decoded",
            [*score, str(p["poses_dict_bomb.parquet"]), "--results", str(p["results"]), "--out", str(run / "s1")],
            None,
        ),
        (
            "42.7",
            "localize on a dictionary-encoded map Parquet of 3.8 GB decoded",
            [*FLATLANDIA, "localize", "--map", str(p["map_dict_bomb.parquet"]), "--query", q],
            None,
        ),
        (
            "42.8",
            "EXIF description of 20,000 brackets, a 5,000-digit number",
            python(f"""
from flatlandia.images import image_audit
df = image_audit.read_folder_metadata({str(p["exif42"])!r})
print('; '.join(f'{{n}}: {{r}}' for n, r in zip(df['name'], df['problem'])))
"""),
            None,
        ),
        *[
            ("42.8", f"priors calibration {what}", [*loc, "--map-type", "depth", "--priors", str(p[name])], None)
            for what, name in (("[1]", "priors_cal_list.json"), ("'abc'", "priors_cal_text.json"))
        ],
        *[
            (
                "42.8",
                f"score --results: {what}",
                [*score, str(p["truth.csv"]), "--results", str(p[name]), "--out", str(run / name)],
                None,
            )
            for what, name in (
                ("map lon0 'abc'", "results_lon0_text"),
                ("map lon0 NaN", "results_lon0_nan"),
                ("queries without a split column", "results_no_split"),
                ("queries.parquet a FIFO", "results_fifo"),
            )
        ],
        *[
            (
                "42.8",
                f"--batch: ground_truth.csv {what}",
                [*batch, str(p[name]), "--out", str(run / f"{name}.csv")],
                None,
            )
            for what, name in (("20-digit object ids", "export_ids_20_digits"), ("x_m NaN", "export_x_nan"))
        ],
        (
            "42.8",
            "NaN in resources/.flatlandia-fetches.json",
            python(f"""
from flatlandia.data import fetch
print('fetched before:', fetch.fetched_before({str(p["fetch_state42"] / "resources" / "data")!r}, {str(p["fetch_state42"])!r}))
"""),
            None,
        ),
        ("42.8", "localize --out onto a folder in the way", [*loc, "--out", str(run / "in_the_way.json")], None),
        (
            "42.8",
            "audit --tree over 1,500 chained records",
            [*FLATLANDIA, "audit", "results/c1499", "--tree"],
            p["chain42"],
        ),
        *[
            ("42.8", f"audit: the manifest fallback {what}", [*FLATLANDIA, "audit", "--check"], p[name])
            for what, name in (
                ("without an artifact column", "manifest_no_artifact"),
                ("with bad JSON cells", "manifest_bad_json"),
                ("not Parquet", "manifest_not_parquet"),
            )
        ],
        *[
            (
                "42.9",
                f"priors calibration weights {what}",
                [*loc, "--map-type", "depth", "--priors", str(p[name])],
                None,
            )
            for what, name in (("'1234'", "priors_weights_text.json"), ("+-1e308", "priors_weights_1e308.json"))
        ],
        (
            "42.9",
            "score --results: a NaN truth",
            [*score, str(p["truth.csv"]), "--results", str(p["results_nan_truth"]), "--out", str(run / "s2")],
            None,
        ),
        *[
            (
                "42.9",
                f"--batch: ground_truth.csv {what}",
                [*batch, str(p[name]), "--out", str(run / f"{name}.csv")],
                None,
            )
            for what, name in (
                ("object id 99999", "export_id_99999"),
                ("object id -5", "export_id_negative"),
                ("x_m 1e300", "export_x_1e300"),
            )
        ],
        (
            "42.9",
            "metadata.csv alt and heading 1e308",
            python(f"""
from flatlandia.images import image_audit
df = image_audit.read_folder_metadata({str(p["exif_csv42"])!r})
print('; '.join(f'{{n}}: alt {{a}}, heading {{h}}, problem {{r}}' for n, a, h, r in zip(df['name'], df['alt'], df['heading'], df['problem'])))
"""),
            None,
        ),
        (
            "42.9",
            "config images.max_megapixels 1e300, min_side_px 1e23 (snakemake -n)",
            [*snakemake_n, str(p["megapixels.yaml"])],
            None,
        ),
        ("42.9", "config: a key given twice (snakemake -n)", [*snakemake_n, str(p["twice.yaml"])], None),
        ("42.10", "audit lists records named with ESC, OSC and U+202E", [*FLATLANDIA, "audit"], p["audit42"]),
        (
            "42.10",
            "CSV cells -2-3, -A1-B1",
            python("""
from flatlandia.plumbing import escape
print('wrote', [escape.csv_cell(c) for c in ('-2-3', '-A1-B1', '-AB21Af_LPev08UY_96ptQ')])
"""),
            None,
        ),
        *[
            (
                "42.10",
                f"plain name holding {what}",
                python(f"""
from flatlandia.plumbing import names
print('accepted', repr(names.plain_name({name!r}, 'metadata.csv', 'image name')))
"""),
                None,
            )
            for what, name in (("U+0085", "a\u0085b.jpg"), ("U+202E", "photo\u202egpj.exe"))
        ],
    ]


#: what every probe of issue 42 must end in: one ERROR line or a result, no traceback, within these
MAX_PROBE_RSS_MB, MAX_PROBE_WALL_S = 1000, 30


def meets(m: dict, stdout_has_controls: bool = False) -> bool:
    """Whether a probe of issue 42 met its expectation (:data:`MAX_PROBE_RSS_MB`, :data:`MAX_PROBE_WALL_S`)."""
    ended = m["result"] and not m["result"].startswith(("TRACEBACK", "killed"))
    return bool(ended and not stdout_has_controls and m["rss_mb"] < MAX_PROBE_RSS_MB and m["wall_s"] < MAX_PROBE_WALL_S)


def measure(cmd: list[str], cwd: Path | None, timeout: int) -> dict:
    """Run under /usr/bin/time -v with a time limit: exit status, what it ended in, peak RSS, wall."""
    t0 = time.monotonic()
    res = subprocess.run(
        ["/usr/bin/time", "-v", "timeout", "-s", "KILL", str(timeout), *cmd], capture_output=True, text=True, cwd=cwd
    )
    wall = time.monotonic() - t0
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", res.stderr)
    lines = [ln for ln in (res.stdout + "\n" + res.stderr).splitlines() if ln.strip()]
    said = [ln for ln in lines if ln.startswith(("ERROR", "WARNING"))]
    warned = [ln for ln in said if ln.startswith("WARNING")]
    if "Traceback" in res.stderr:
        result = "TRACEBACK: " + next(
            (ln for ln in reversed(res.stderr.splitlines()) if ln.strip() and "Command" not in ln), ""
        )
    elif res.returncode in (-9, 137):
        result = f"killed after {timeout} s"
    elif said and not (res.returncode == 0 and len(warned) == len(said) > 1):
        result = said[0]
    elif said:  # warnings, then a result (the audit): how many, and the result
        result = f"{len(warned)} WARNING lines ({warned[0][:80]}...); then: {res.stdout.strip().splitlines()[-1]}"
    else:
        result = next((ln for ln in res.stdout.splitlines() if ln.strip().startswith(("wrote", '"found"', "all "))), "")
        result = result or (res.stdout.strip().splitlines() or [""])[0]
    status = re.search(r"Exit status: (\d+)", res.stderr)
    cpu = sum(float(v) for v in re.findall(r"(?:User|System) time \(seconds\): ([0-9.]+)", res.stderr))
    return {
        "rc": int(status.group(1)) if status else res.returncode,
        "result": result,
        "controls": bool(re.search("[\x1b\x07\x85\u202e]", res.stdout + res.stderr)),
        "rss_mb": int(rss.group(1)) / 1000 if rss else float("nan"),
        "wall_s": wall,
        "cpu_s": cpu,
    }


def _printable(text: str) -> str:
    """``text`` with its controls and invisible characters written as escapes (a probe's output may hold ESC)."""
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="/tmp/flatlandia-probes", help="scratch folder for the probes' inputs")
    ap.add_argument("--timeout", type=int, default=300, help="seconds a probe may run")
    ap.add_argument("--only", nargs="*", help="probes whose name (or finding, 42.7) holds one of these words")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    p = build(out)
    build_42(out, p)
    rows, missed = [], []
    for finding, name, cmd, cwd in probes(p) + probes_42(p):
        if args.only and not any(w in name or w == finding for w in args.only):
            continue
        m = measure(cmd, cwd, args.timeout)
        result = m["result"].replace("|", "\\|")
        result = result if len(result) <= 160 else result[:157] + "..."
        ok = ("yes" if meets(m, m["controls"]) else "NO") if finding.startswith("42.") else ""
        if ok == "NO":
            missed.append(f"{finding} {name}")
        rows.append(
            f"| {finding} | {name} | {_printable(result)} | {m['rc']} | {m['rss_mb']:.0f} | {m['wall_s']:.1f} | "
            f"{m['cpu_s']:.1f} | {ok} |"
        )
        print(rows[-1], flush=True)
    table = (
        "| finding | probe | result | rc | peak RSS MB | wall s | CPU s | meets |\n|---|---|---|---|---|---|---|---|\n"
        + "\n".join(rows)
    )
    (out / "probes.md").write_text(table + "\n")
    print(f"\n{table}\n\nwritten to {out / 'probes.md'}")
    if missed:
        print(
            f"\n{len(missed)} probe(s) of issue 42 missed their expectation (one ERROR line or a result, no traceback, "
            f"RSS < {MAX_PROBE_RSS_MB} MB, wall < {MAX_PROBE_WALL_S} s, no raw control character): " + "; ".join(missed)
        )
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
