"""The benchmark's inputs as plain files (CSV, GeoJSON, JSON) for methods in any language.

Target ``export`` (not in ``all``) writes ``results/export/``: per benchmark scene the reference
map, its metric frame, the queries' local maps (the only input of a query), the map regions
proposed for them, and apart from those the ground truth; beside them the classes, the scenes and
a template of the poses a method fills to be scored. Entry functions: :func:`scene_export` (rule
``export_scene``) and :func:`index_export` (rule ``export_index``); :func:`csv_text` is how every
table is written. What each file holds is :data:`FILES_MARKDOWN`, the text of the export's
``README.md`` and of the section "Export the benchmark" of docs/usage.md.

Floats are written in positional notation with the fewest digits that read back to the same
double (``numpy.format_float_positional(unique=True)``): the CSVs hold exactly the Parquet values.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from flatlandia import geo, proposals, vocabulary
from flatlandia.classes import CLASSES
from flatlandia.data import localmaps
from flatlandia.plumbing import escape
from flatlandia.plumbing.errors import InputError

MAP_TYPES = list(vocabulary.MAP_TYPES)
#: every proposal source, in the order of proposals.csv: the oracle box, then the coarse stages (the
#: whole map needs no file: reference_map.csv)
COARSE_SOURCES = list(vocabulary.COARSE_PROPOSALS)
SOURCES = [vocabulary.GTBB, *COARSE_SOURCES]
#: strategies in the order of proposals.csv (a coarse model writes N_LM, 2N_LM, R_30; the solver also BB)
STRATEGIES = list(vocabulary.STRATEGIES)
SPLITS = ["train", "val", "test"]

REFERENCE_COLUMNS = ["obj_idx", "class_id", "class", "lon", "lat", "x_m", "y_m"]
QUERY_COLUMNS = ["token", "split", "n_objects"]
LOCAL_MAP_COLUMNS = ["token", "split", "map_type", "k", "class_id", "class", "x", "y"]
PROPOSAL_COLUMNS = ["token", "map_type", "source", "strategy", "obj_idx"]
GROUND_TRUTH_COLUMNS = ["token", "split", "x_m", "y_m", "theta_deg", "lon", "lat", "heading_deg", "matched_obj_idx"]
CLASS_COLUMNS = ["class_id", "class"]
SCENE_COLUMNS = [
    "scene",
    "city",
    "n_objects",
    "n_queries_train",
    "n_queries_val",
    "n_queries_test",
    "crs",
    "lon0",
    "lat0",
]
TEMPLATE_COLUMNS = ["scene", "token", "x_m", "y_m", "theta_deg"]

#: what the export's files hold: the body of results/export/README.md and of the section "Export the
#: benchmark" of docs/usage.md (tests/test_export.py checks that it carries it verbatim)
FILES_MARKDOWN = """\
| file | one row per | columns |
|---|---|---|
| `classes.csv` | object class (42) | `class_id` (what every other file uses), `class` (its Mapillary Vistas label) |
| `scenes.csv` | scene | `scene`, `city`, `n_objects` (reference map), `n_queries_train`, `n_queries_val`, `n_queries_test`, `crs` (PROJ string of the scene's metric frame), `lon0`, `lat0` (its origin, degrees) |
| `poses_template.csv` | test query | `scene`, `token`, and `x_m`, `y_m`, `theta_deg` left empty: the file a method fills to be scored |
| `{scene}/frame.json` | (one object) | `scene`, `crs`, `lon0`, `lat0`, `axes`, `unit`, `angles`: the scene's metric frame |
| `{scene}/reference_map.csv` | object of the reference map | `obj_idx` (the object's id in every file), `class_id`, `class`, `lon`, `lat` (degrees, WGS 84), `x_m`, `y_m` (metres, scene frame) |
| `{scene}/reference_map.geojson` | object (a point at lon, lat) | the same properties |
| `{scene}/queries.csv` | query | `token` (Mapillary image id), `split` (`train`, `val`, `test`), `n_objects` (objects in its local maps) |
| `{scene}/local_maps.csv` | object of a query's local map | `token`, `split`, `map_type` (`gt` or `depth`), `k` (object index in the local map, from 0), `class_id`, `class`, `x` (forward), `y` (left) |
| `{scene}/proposals.csv` | object of a proposed map region | `token`, `map_type`, `source`, `strategy`, `obj_idx` |
| `{scene}/ground_truth.csv` | query | `token`, `split`, `x_m`, `y_m`, `theta_deg`, `lon`, `lat`, `heading_deg`, `matched_obj_idx` |
| `{scene}/query_cameras.geojson` | query (its camera, a point at lon, lat) | `token`, `split`, `heading_deg`, `theta_deg`, `x_m`, `y_m`, `n_objects`: the cameras as a GIS point layer (every split; ground truth, as `ground_truth.csv`) |

**A query** is the objects one photo sees, as a local map: the camera at the origin looking along
**+x**, **+y to its left**. Each query has two local maps of the same objects in the same order
(`k`): `gt`, in metres (the reference objects it saw, moved rigidly into the camera frame: an
exact copy), and `depth`, placed by monocular depth, of **unknown scale**: its coordinates are
normalised so that the median distance of its objects to the camera is 1. A method localizes a
query from its local map and the scene's reference map; it never reads `ground_truth.csv` for a
test query.

**The scene frame** is a transverse Mercator projection centred on the scene (`crs`, origin
`lon0`, `lat0`): `x_m` east, `y_m` north, metres. lon/lat are WGS 84 degrees.

**A pose** is `x_m`, `y_m` (the camera in the scene frame) and `theta_deg`, the direction of the
viewing axis (the local map's +x), counter-clockwise from east (+x of the scene frame), degrees;
`heading_deg` is the same direction as a compass heading, clockwise from north: `heading_deg` =
(90 - `theta_deg`) mod 360 (north of the scene frame, within 0.001 degrees of true north at every
camera). A local-map object (x, y) lands on the map at
(`x_m` + x cos theta - y sin theta, `y_m` + x sin theta + y cos theta). In `ground_truth.csv`,
`matched_obj_idx` lists the reference object of each local-map object in local-map order (`k`),
space-separated; the `gt` local map placed at the true pose lands on them to within a micrometre.

**Proposals** are map regions a fine method may search instead of the whole reference map (which
needs no file: use `reference_map.csv`); each region is listed per `map_type`. `source`: `gtbb`,
the oracle box (`strategy` `GT-BB`: the reference objects inside the axis-aligned box around the
query's matched objects and its true camera, enlarged by 10 %; it uses the ground truth; every
split, the same for both map types); `coarse-sim`, `coarse-trip`, `coarse-simtrip`, the learned
coarse models (GAT retrieval trained with the Sim, Trip and Sim+Trip losses; test split;
`strategy` `N_LM`: the N best-scored objects, N the query's objects, `2N_LM`: 2N, `R_30`: every
object within 30 m of the best one); `coarse-solver`, the geometric solver's training-free
proposals (test split; `N_LM`, `2N_LM`, `R_30` as above around the solver's poses, `BB`: the
GT-BB box built from the solver's matches and camera). A query whose proposal is empty has no rows
for it.

**Splits**: `train`, `val`, `test`, 80/10/10 per scene with a fixed seed. Train on the train
split (its ground truth is yours to use) and tune on val; the benchmark scores the test split.

**Reading the files**: comma-separated, UTF-8, a header line, rows in a fixed order (scenes as
in `scenes.csv`, queries as in `queries.csv`, objects by `k` or `obj_idx`; `proposals.csv` by
source, map type, strategy and query as listed here, each proposal's objects as proposed). Read `scene` and
`token` as text (some tokens start with `-`; others are long numbers), e.g.
`pd.read_csv(path, dtype={"scene": str, "token": str})`. Floats are written with the fewest
digits that read back to the same double, so the files hold the workflow's values exactly.

**Scoring**: fill `poses_template.csv` (columns `scene`, `token` and either `x_m`, `y_m`,
`theta_deg` as above or `lon`, `lat`, `heading_deg`; optional `map_type`, `proposal`, `seconds`)
and run `flatlandia score POSES --name NAME --out DIR`. `flatlandia localize --batch EXPORT --out
POSES.csv` writes the geometric solver's poses of the test split in this shape (a baseline, and a
check of the format end to end).
"""


def _floats(values) -> list[str]:
    """Floats as the shortest positional decimal that reads back to the same double; NaN empty."""
    out = []
    for v in np.asarray(values, dtype=float):
        out.append("" if np.isnan(v) else np.format_float_positional(v, unique=True, trim="0"))
    return out


def csv_text(df: pd.DataFrame) -> str:
    """A table as CSV text: floats exact and positional (:func:`_floats`), text cells no spreadsheet
    runs (:func:`flatlandia.plumbing.escape.csv_cell`: ``=HYPERLINK(...)`` becomes ``'=HYPERLINK(...)``, a
    published token such as ``-AB21Af_LPev08UY_96ptQ`` stays as it is), ``\\n`` line ends, no index."""
    out = df.copy()
    for c in out.columns:
        if pd.api.types.is_float_dtype(out[c]):
            out[c] = _floats(out[c])
        elif not pd.api.types.is_numeric_dtype(out[c]):
            out[c] = [escape.csv_cell(v) if isinstance(v, str) else v for v in out[c]]
    header = [escape.csv_cell(c) for c in out.columns]
    return out.to_csv(index=False, lineterminator="\n", header=header)


def heading_deg(theta_deg) -> np.ndarray:
    """Compass heading (clockwise from north, [0, 360)) of a direction ``theta_deg`` counter-clockwise
    from east."""
    h = np.mod(90.0 - np.asarray(theta_deg, float), 360.0)
    return np.where(h >= 360.0, 0.0, h)


def _check_frame(scene: str, meta: dict) -> None:
    if meta.get("frame") == "local" or not meta.get("crs"):
        raise InputError(f"scene {scene} reference map", "no geographic frame (crs): nothing to export")


def frame_json(scene: str, meta: dict) -> dict:
    """The scene's metric frame: the reference map's ``flatlandia`` metadata, what a user needs of it."""
    _check_frame(scene, meta)
    return {
        "scene": str(scene),
        "crs": meta["crs"],
        "lon0": float(meta["lon0"]),
        "lat0": float(meta["lat0"]),
        "axes": meta["axes"],
        "unit": meta["unit"],
        "angles": (
            "theta_deg: the camera's viewing axis counter-clockwise from east (+x), degrees; "
            "heading_deg: the same, clockwise from north, (90 - theta_deg) mod 360"
        ),
    }


def reference_table(ref: pd.DataFrame) -> pd.DataFrame:
    """reference_map.csv: the objects by ``obj_idx``."""
    out = pd.DataFrame(
        {
            "obj_idx": ref["obj_idx"].astype(np.int64),
            "class_id": ref["class_id"].astype(np.int64),
            "class": [CLASSES[int(c)] for c in ref["class_id"]],
            "lon": ref["lon"].astype(float),
            "lat": ref["lat"].astype(float),
            "x_m": ref["x_m"].astype(float),
            "y_m": ref["y_m"].astype(float),
        }
    )
    return out.sort_values("obj_idx", kind="stable").reset_index(drop=True)


def reference_geojson(scene: str, table: pd.DataFrame, frame: dict) -> dict:
    """reference_map.geojson: the objects of :func:`reference_table` as points (lon, lat), same properties."""
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [float(r.lon), float(r.lat)]},
            "properties": {
                "obj_idx": int(r.obj_idx),
                "class_id": int(r.class_id),
                "class": str(r[2]),  # "class" is a keyword: the tuple calls the field _2
                "lon": float(r.lon),
                "lat": float(r.lat),
                "x_m": float(r.x_m),
                "y_m": float(r.y_m),
            },
        }
        for r in table[REFERENCE_COLUMNS].itertuples(index=False)
    ]
    return {"type": "FeatureCollection", "name": f"flatlandia_scene_{scene}", "flatlandia": frame, "features": feats}


def query_cameras_geojson(scene: str, queries: pd.DataFrame, frame: dict) -> dict:
    """query_cameras.geojson: every query's camera as a point (lon, lat) with its ``token``, ``split``,
    ``heading_deg`` (compass, clockwise from north: a GIS rotates a marker by it), ``theta_deg``,
    ``x_m``, ``y_m`` and ``n_objects``, in the queries' order: a point layer to see beside the
    reference map. It is ground truth, as ground_truth.csv: a method never reads its test rows."""
    theta = queries["theta_deg"].to_numpy(float)
    heading = heading_deg(theta)
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [float(r.lon), float(r.lat)]},
            "properties": {
                "token": str(r.token),
                "split": str(r.split),
                "heading_deg": float(h),
                "theta_deg": float(r.theta_deg),
                "x_m": float(r.x_m),
                "y_m": float(r.y_m),
                "n_objects": int(r.n_objects),
            },
        }
        for r, h in zip(queries.itertuples(index=False), heading, strict=True)
    ]
    return {
        "type": "FeatureCollection",
        "name": f"flatlandia_query_cameras_{scene}",
        "flatlandia": frame,
        "features": feats,
    }


def queries_table(queries: pd.DataFrame) -> pd.DataFrame:
    """queries.csv: token, split, number of objects (no ground truth), in the queries' order."""
    return pd.DataFrame(
        {
            "token": queries["token"].astype(str),
            "split": queries["split"].astype(str),
            "n_objects": queries["n_objects"].astype(np.int64),
        }
    ).reset_index(drop=True)


def local_maps_table(queries: pd.DataFrame) -> pd.DataFrame:
    """local_maps.csv: one row per object of each query's GT and depth local maps (query order, then
    map type, then ``k``)."""
    parts = []
    for r in queries.itertuples(index=False):
        cls = np.asarray(r.classes, np.int64)
        for mt in MAP_TYPES:
            xy = localmaps.local_map(r, mt)
            if len(xy) != len(cls):
                raise InputError(
                    f"query {r.token}", f"its {mt} local map has {len(xy)} objects, its classes {len(cls)}"
                )
            parts.append(
                pd.DataFrame(
                    {
                        "token": str(r.token),
                        "split": str(r.split),
                        "map_type": mt,
                        "k": np.arange(len(cls), dtype=np.int64),
                        "class_id": cls,
                        "class": [CLASSES[int(c)] for c in cls],
                        "x": xy[:, 0],
                        "y": xy[:, 1],
                    }
                )
            )
    if not parts:
        return pd.DataFrame({c: pd.Series(dtype=_dtype(c)) for c in LOCAL_MAP_COLUMNS})
    return pd.concat(parts, ignore_index=True)[LOCAL_MAP_COLUMNS]


def _dtype(column: str) -> str:
    if column in ("k", "class_id", "obj_idx", "n_objects"):
        return "int64"
    if column in ("x", "y", "x_m", "y_m", "theta_deg", "lon", "lat", "heading_deg"):
        return "float64"
    return "object"


def ground_truth_table(queries: pd.DataFrame) -> pd.DataFrame:
    """ground_truth.csv: each query's true pose (scene frame and compass) and its matched objects."""
    theta = queries["theta_deg"].to_numpy(float)
    return pd.DataFrame(
        {
            "token": queries["token"].astype(str).to_numpy(),
            "split": queries["split"].astype(str).to_numpy(),
            "x_m": queries["x_m"].to_numpy(float),
            "y_m": queries["y_m"].to_numpy(float),
            "theta_deg": theta,
            "lon": queries["lon"].to_numpy(float),
            "lat": queries["lat"].to_numpy(float),
            "heading_deg": heading_deg(theta),
            "matched_obj_idx": [" ".join(str(int(i)) for i in idx) for idx in queries["ref_idx"]],
        },
        columns=GROUND_TRUTH_COLUMNS,
    )


def _proposal_rows(table: pd.DataFrame, source: str, map_types: Iterable[str] | None = None) -> pd.DataFrame:
    """One row per proposed object of a proposal table (``token``, ``strategy``, ``proposal`` and,
    unless ``map_types`` repeats every proposal for each, ``map_type``)."""
    rows = []
    for r in table.itertuples(index=False):
        objs = [int(o) for o in r.proposal]
        for mt in map_types if map_types is not None else [r.map_type]:
            rows += [(str(r.token), str(mt), source, str(r.strategy), o) for o in objs]
    return pd.DataFrame(rows, columns=PROPOSAL_COLUMNS).astype({"obj_idx": np.int64})


def proposals_table(ref: pd.DataFrame, queries: pd.DataFrame, coarse: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """proposals.csv: the GT-BB box of every query and, for the test queries, the proposals of the
    coarse tables given (``coarse``: source -> the proposal table of rule coarse_eval or coarse_solver,
    every scene; this scene's rows are kept). Ordered by source, map type, strategy, query, then
    as proposed."""
    unknown = sorted(set(coarse) - set(COARSE_SOURCES))
    if unknown:
        raise ValueError(f"unknown proposal sources {unknown}; known: {COARSE_SOURCES}")
    scene = str(ref["scene"].iloc[0])
    parts = [_proposal_rows(proposals.gtbb_proposals(ref, queries), vocabulary.GTBB, MAP_TYPES)]
    for source in COARSE_SOURCES:
        if source not in coarse:
            continue
        t = coarse[source]
        t = t[t["scene"].astype(str) == scene]
        t = t[t["token"].astype(str).isin(queries["token"].astype(str))]
        strange = sorted(set(t["strategy"]) - set(STRATEGIES)) + sorted(set(t["map_type"]) - set(MAP_TYPES))
        if strange:
            raise InputError(f"{source} proposals", f"unknown strategies or map types {strange}")
        parts.append(_proposal_rows(t, source))
    out = pd.concat(parts, ignore_index=True)
    order = {
        "source": {s: i for i, s in enumerate(SOURCES)},
        "map_type": {m: i for i, m in enumerate(MAP_TYPES)},
        "strategy": {s: i for i, s in enumerate(STRATEGIES)},
        "token": {str(t): i for i, t in enumerate(queries["token"])},
    }
    keys = pd.DataFrame({c: out[c].map(o) for c, o in order.items()})
    idx = np.lexsort([keys[c].to_numpy() for c in reversed(list(order))])  # stable: within a proposal, as given
    return out.iloc[idx].reset_index(drop=True)


def scene_export(
    scene: str, ref: pd.DataFrame, meta: dict, queries: pd.DataFrame, coarse: dict[str, pd.DataFrame] | None = None
) -> dict:
    """Rule export_scene: a benchmark scene's files, by name (``reference_map``, ``reference_geojson``,
    ``frame``, ``queries``, ``local_maps``, ``proposals``, ``ground_truth``, ``query_cameras``): tables for
    :func:`csv_text`, dicts for JSON. ``ref``/``meta``: reference_map.parquet and its metadata;
    ``queries``: queries.parquet; ``coarse``: the coarse proposal tables present, by source."""
    scene = str(scene)
    frame = frame_json(scene, meta)
    table = reference_table(ref)
    return {
        "reference_map": table,
        "reference_geojson": reference_geojson(scene, table, frame),
        "frame": frame,
        "queries": queries_table(queries),
        "local_maps": local_maps_table(queries),
        "proposals": proposals_table(ref, queries, coarse or {}),
        "ground_truth": ground_truth_table(queries),
        "query_cameras": query_cameras_geojson(scene, queries, frame),
    }


def classes_table() -> pd.DataFrame:
    """classes.csv: the 42 classes by id."""
    return pd.DataFrame({"class_id": np.arange(len(CLASSES), dtype=np.int64), "class": CLASSES})


def scenes_table(scenes: list[dict]) -> pd.DataFrame:
    """scenes.csv from ``scenes``: dicts with ``scene``, ``city``, ``ref``, ``meta``, ``queries``."""
    rows = []
    for s in scenes:
        frame = frame_json(s["scene"], s["meta"])
        split = s["queries"]["split"].astype(str).value_counts()
        rows.append(
            {
                "scene": str(s["scene"]),
                "city": str(s["city"]),
                "n_objects": int(len(s["ref"])),
                **{f"n_queries_{k}": int(split.get(k, 0)) for k in SPLITS},
                "crs": frame["crs"],
                "lon0": frame["lon0"],
                "lat0": frame["lat0"],
            }
        )
    return pd.DataFrame(rows, columns=SCENE_COLUMNS)


def poses_template(scenes: list[dict]) -> pd.DataFrame:
    """poses_template.csv: every test query (scenes' order, then the queries') with empty pose columns."""
    rows = [
        (str(s["scene"]), str(t))
        for s in scenes
        for t, split in zip(s["queries"]["token"], s["queries"]["split"])
        if split == "test"
    ]
    out = pd.DataFrame(rows, columns=["scene", "token"])
    for c in ("x_m", "y_m", "theta_deg"):
        out[c] = np.nan
    return out[TEMPLATE_COLUMNS]


def readme_text(scenes: pd.DataFrame, sources: list[str], absent: list[str]) -> str:
    """results/export/README.md: what this export holds (its scenes, its proposal sources and those
    absent), then :data:`FILES_MARKDOWN`."""
    md = escape.markdown
    n_test = int(scenes["n_queries_test"].sum()) if len(scenes) else 0
    lines = [
        "# Flatlandia benchmark: the inputs, exported",
        "",
        "Written by the Flatlandia workflow (`snakemake --cores 2 export`; rules `export_scene` and "
        "`export_index`, module `flatlandia.data.export`). Object-based 3DoF visual localization: find the pose "
        "of a camera from the objects its photo sees (a query's local map) on the scene's map of classed "
        "objects (its reference map).",
        "",
        f"**Scenes** ({len(scenes)}, {int(scenes['n_objects'].sum()) if len(scenes) else 0} reference objects, "
        f"{n_test} test queries): "
        + (", ".join(f"{md(r.scene)} ({md(r.city)})" for r in scenes.itertuples(index=False)) or "none")
        + ".",
        "",
        "**Proposal sources in `proposals.csv`**: " + ", ".join(f"`{md(s)}`" for s in sources) + ".",
    ]
    if absent:
        lines += [
            "",
            "**Absent**: "
            + ", ".join(f"`{md(s)}`" for s in absent)
            + ": not built in this folder when the export was written (the export trains no model and "
            "runs no solver: it takes the coarse proposals that exist). Build them first (`snakemake --cores 2 "
            "benchmark`, which trains the models of `coarse.losses`, or `snakemake --cores 2 "
            "results/coarse/solver/proposals.parquet` for the solver's alone), then run "
            "`snakemake --cores 2 export` again.",
        ]
    return "\n".join(lines) + "\n\n" + FILES_MARKDOWN


def index_export(scenes: list[dict], sources: list[str]) -> dict:
    """Rule export_index: ``readme`` (text), ``classes``, ``scenes``, ``template`` (tables for
    :func:`csv_text`). ``scenes``: per benchmark scene (in order) a dict with ``scene``, ``city``,
    ``ref`` and ``meta`` (reference_map.parquet, its metadata), ``queries`` (queries.parquet);
    ``sources``: the coarse proposal sources present (the others are reported absent)."""
    unknown = sorted(set(sources) - set(COARSE_SOURCES))
    if unknown:
        raise ValueError(f"unknown proposal sources {unknown}; known: {COARSE_SOURCES}")
    table = scenes_table(scenes)
    present = [vocabulary.GTBB, *[s for s in COARSE_SOURCES if s in sources]]
    absent = [s for s in COARSE_SOURCES if s not in sources]
    return {
        "readme": readme_text(table, present, absent),
        "classes": classes_table(),
        "scenes": table,
        "template": poses_template(scenes),
    }


def place_local_map(local_xy: np.ndarray, x_m: float, y_m: float, theta_deg: float) -> np.ndarray:
    """A local map placed at a pose (metres, degrees counter-clockwise from east): the check a user
    can make with ground_truth.csv (:func:`flatlandia.geo.local_to_world`)."""
    return geo.local_to_world(np.asarray(local_xy, float).reshape(-1, 2), np.array([x_m, y_m]), np.radians(theta_deg))
