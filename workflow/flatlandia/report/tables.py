"""Result tables with stable, documented schemas: Parquet + markdown + LaTeX, checked when written.

Each table has a schema here: column, dtype kind, unit and meaning. :func:`write_table` refuses a
DataFrame whose columns or dtypes differ from its schema, so a downstream reader (or a paper)
can rely on them; ``docs/tables.md`` is rendered from the same schemas (:func:`schema_markdown`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import vocabulary
from flatlandia.plumbing import escape
from flatlandia.plumbing.files import write_parquet, write_text


@dataclass(frozen=True)
class Column:
    name: str
    kind: str  # "int", "float", "str", "bool"
    unit: str
    meaning: str


#: the field's recall at 1 / 3 / 5 m and 1 / 3 / 5 deg, in the fine and the city tables
RECALL_COLUMNS = [
    Column("recall_1m", "float", "%", "field's recall: queries under 1 m, any heading; failures are misses"),
    Column("recall_3m", "float", "%", "queries under 3 m, any heading"),
    Column("recall_5m", "float", "%", "queries under 5 m, any heading"),
    Column("recall_1deg", "float", "%", "field's recall: queries under 1 deg, any position; failures are misses"),
    Column("recall_3deg", "float", "%", "queries under 3 deg, any position"),
    Column("recall_5deg", "float", "%", "queries under 5 deg, any position"),
]

#: the answers' probability (docs/results.md, "Knowing when it is right"), in the fine, city and
#: beyond-one-frame tables; NaN for a method without a probability
ANSWER_COLUMNS = [
    Column(
        "answered_pct",
        "float",
        "%",
        "queries answered: status ok, the calibrated probability of being within (5 m, 5 deg) at least solver.answer_probability",
    ),
    Column("within_answered_pct", "float", "%", "the answered within (5 m, 5 deg)"),
    Column("wrong_scene_answered_pct", "float", "%", "the answered more than 500 m off (another tile of a city)"),
    Column(
        "answerable_95_pct",
        "float",
        "%",
        "the largest share answerable, surest first, with at least 95 % of the answered within (5 m, 5 deg)",
    ),
    Column(
        "answerable_wrong_1pct",
        "float",
        "%",
        "the largest share answerable, surest first, with at most 1 % of the answered in the wrong scene",
    ),
    Column("answerable_wrong_2pct", "float", "%", "the same with at most 2 % in the wrong scene"),
    Column("ece_points", "float", "points", "expected calibration error of the probability (10 equal bins), 0-100"),
]

SCHEMAS: dict[str, list[Column]] = {
    "coarse_localization": [
        Column(
            "loss",
            "str",
            "",
            "Sim | Trip | Sim+Trip; 'Solver' for the training-free proposals of the geometric solver; '-' for the oracle GT-BB; 'random' / 'S oracle' baselines",
        ),
        Column("strategy", "str", "", "region proposal: N_LM | 2N_LM | R_30 | GT-BB"),
        Column("map_type", "str", "", "gt or depth local maps"),
        Column("queries", "int", "", "test queries"),
        Column("precision", "float", "", "mean |S n S_gt| / |S| (S: proposed reference objects, S_gt: matched ones)"),
        Column("recall", "float", "", "mean |S n S_gt| / |S_gt|"),
        Column("success", "float", "", "share of queries with at least 3 correct proposed objects"),
        Column("proposal_size", "float", "", "mean objects per proposal"),
        Column("paper_precision", "float", "", "the paper's Table 3 (empty where it has no row)"),
        Column("paper_recall", "float", "", "the paper's Table 3"),
        Column("paper_success", "float", "", "the paper's Table 3"),
    ],
    "dataset_stats": [
        Column("city", "str", "", "city, or 'all'"),
        Column("scenes", "int", "", "number of scenes"),
        Column("area_km2", "float", "km2", "mean per scene: convex hull of the reference objects"),
        Column("kb_per_map", "float", "kB", "mean per scene: map as compact JSON [[lon, lat], class]"),
        Column("images", "float", "", "mean per scene: images in the SfM (tokens.txt)"),
        Column("objects", "float", "", "mean objects per scene"),
        Column("queries", "float", "", "mean queries per scene"),
        Column("total_objects", "int", "", "objects in all scenes"),
        Column("total_queries", "int", "", "queries in all scenes"),
        Column("union_area_km2", "float", "km2", "area of the union of the scenes' hulls (overlaps count once)"),
        Column("density_per_1000m2", "float", "1/1000 m2", "objects per 1000 m2 of hull area"),
        Column("paper_scenes", "float", "", "the paper's Table 2"),
        Column("paper_objects", "float", "", "the paper's Table 2"),
        Column("paper_queries", "float", "", "the paper's Table 2"),
        Column("paper_area_km2", "float", "km2", "the paper's Table 2"),
        Column("paper_kb_per_map", "float", "kB", "the paper's Table 2"),
        Column("paper_images", "float", "", "the paper's Table 2"),
    ],
    "fine_localization": [
        Column(
            "run",
            "str",
            "",
            "{method}_{map_type}_{proposal}: results/fine/{run}/ (an external method's: results/external/{run}/)",
        ),
        Column(
            "method",
            "str",
            "",
            "solver (geometric solver) | mlp | mlp_att | gat | gat_att | an external method's name (config external)",
        ),
        Column(
            "method_label", "str", "", "geometric solver | MLP | MLP+ATT | GAT | GAT+ATT | an external method's name"
        ),
        Column("map_type", "str", "", "gt or depth local maps"),
        Column(
            "proposal",
            "str",
            "",
            " | ".join(f"{slug} ({p.figure_label})" for slug, p in vocabulary.PROPOSALS.items()),
        ),
        Column(
            "strategy",
            "str",
            "",
            "GT-BB | whole map | {Sim, Trip, Sim+Trip} {N_LM, 2N_LM, R_30} (coarse proposals) | Solver BB (the solver's training-free box)",
        ),
        Column("queries", "int", "", "test queries"),
        Column("median_m", "float", "m", "median position error, true metres (failed queries count as infinite)"),
        Column("median_deg", "float", "deg", "median orientation error"),
        Column("pct_0.5m_2deg", "float", "%", "queries under 0.5 m and 2 deg (true metres)"),
        Column("pct_1m_5deg", "float", "%", "queries under 1 m and 5 deg"),
        Column("pct_5m_10deg", "float", "%", "queries under 5 m and 10 deg"),
        Column("pct_10m_20deg", "float", "%", "queries under 10 m and 20 deg"),
        *RECALL_COLUMNS,
        Column("within_5m_5deg", "float", "%", "queries under 5 m and 5 deg at once; failures are misses"),
        Column("failure_pct", "float", "%", "F%: proposal holds fewer than 3 objects of the query's classes"),
        Column("no_pose_pct", "float", "%", "queries for which the method returned no pose"),
        Column("gross_pct", "float", "%", "position error over 30 m (true metres)"),
        Column("median_query_ms", "float", "ms", "median time per query, one CPU thread (wall clock)"),
        Column("mean_query_ms", "float", "ms", "mean time per query, one CPU thread (wall clock)"),
        Column(
            "median_query_cpu_ms",
            "float",
            "ms",
            "median CPU time per query (process time: robust to other load on the machine)",
        ),
        Column("train_s", "float", "s", "training wall time (learned models; 0 for the solver), 1 CPU thread"),
        Column("epochs", "int", "", "training epochs (0 for the solver)"),
        Column("n_parameters", "int", "", "trainable parameters (0 for the solver)"),
        Column("model_mb", "float", "MB", "size of the model's weights (0 for the solver)"),
        Column(
            "ref_map_kb",
            "float",
            "kB",
            "mean per scene: reference map the method reads, 9 B per object (2 x float32 + class)",
        ),
        Column(
            "median_pu", "float", "paper m", "median position error in the paper's convention (local-map units x 215)"
        ),
        Column(
            "trained_on",
            "str",
            "",
            "learned models: training proposals, GT-BB or simulated coarse (cut to a radius); '' for the solver",
        ),
        Column("pct_pu_0.5m_2deg", "float", "%", "queries under 0.5 paper m and 2 deg (paper convention)"),
        Column("pct_pu_1m_5deg", "float", "%", "queries under 1 paper m and 5 deg (paper convention)"),
        Column("pct_pu_5m_10deg", "float", "%", "queries under 5 paper m and 10 deg (paper convention)"),
        Column("pct_pu_10m_20deg", "float", "%", "queries under 10 paper m and 20 deg (paper convention)"),
        Column(
            "paper_row",
            "str",
            "",
            "the paper's row of the same method, map type and proposal (Table 4 by model on GT-BB; Table 5's MLP on Sim+Trip 2N_LM), '' where the paper has none (the solver, the whole map, the solver's boxes, external methods)",
        ),
        Column("paper_pct_0.5m_2deg", "float", "%", "the paper's Table 4 (paper convention)"),
        Column("paper_pct_1m_5deg", "float", "%", "the paper's Table 4"),
        Column("paper_pct_5m_10deg", "float", "%", "the paper's Table 4"),
        Column("paper_pct_10m_20deg", "float", "%", "the paper's Table 4"),
        Column("paper_median_pu", "float", "paper m", "the paper's median position error (units x 215), Tables 4-5"),
        Column("paper_median_deg", "float", "deg", "the paper's median orientation error, Tables 4-5"),
        Column("paper_query_ms", "float", "ms", "the paper's query time (GPU; MLP only)"),
        *ANSWER_COLUMNS,
    ],
    "fine_per_scene": [
        Column("scene", "str", "", "benchmark scene id"),
        Column("map_type", "str", "", "gt or depth local maps"),
        Column(
            "run",
            "str",
            "",
            "{method}_{map_type}_{proposal}: the solver on GT-BB and on the whole map, the best learned model on GT-BB",
        ),
        Column("method_label", "str", "", "geometric solver | the learned model of the run"),
        Column("strategy", "str", "", "GT-BB | whole map"),
        Column("queries", "int", "", "the scene's test queries"),
        Column("median_m", "float", "m", "median position error, true metres (failed queries count as infinite)"),
        Column("median_deg", "float", "deg", "median orientation error"),
        Column("within_5m_5deg", "float", "%", "queries under 5 m and 5 deg at once; failures are misses"),
    ],
    "city_scale": [
        Column(
            "map", "str", "", "tiled (the benchmark scenes, 1 km apart) | simulated (a scene among synthetic tiles)"
        ),
        Column("scenes", "int", "", "scenes (tiles) per city"),
        Column("cities", "int", "", "cities of that size; every test query is localized in one"),
        Column("objects", "int", "", "mean objects per city map"),
        Column(
            "method",
            "str",
            "",
            "whole-map solver (the per-scene solver on the whole city) | index + solver (the city search, then the solver on its regions)",
        ),
        Column("queries", "int", "", "depth queries localized"),
        Column("median_m", "float", "m", "median position error"),
        Column("median_deg", "float", "deg", "median orientation error"),
        *RECALL_COLUMNS,
        Column("within_5m_5deg", "float", "%", "queries within (5 m, 5 deg)"),
        Column("wrong_scene_pct", "float", "%", "poses more than 500 m off (in another tile)"),
        Column("no_pose_pct", "float", "%", "queries without a pose"),
        Column("cpu_median_ms", "float", "ms", "CPU per query on one core, median"),
        Column("cpu_p90_ms", "float", "ms", "CPU per query on one core, 90th percentile"),
        Column("region_hit_pct", "float", "%", "index: the true place among the regions handed to the solver"),
        Column("index_mb", "float", "MB", "index size, mean per city"),
        Column("index_build_s", "float", "s", "index build CPU time, mean per city"),
        *ANSWER_COLUMNS,
    ],
    "beyond_one_frame": [
        Column(
            "map",
            "str",
            "",
            "scene (each scene's whole reference map) | city-N (the tiled city of N scenes, the city search) | simulated-N (a scene among synthetic tiles, N objects)",
        ),
        Column("objects", "int", "", "mean objects per map"),
        Column(
            "frames", "int", "", "frames per sequence: the anchor (a test query) and its nearest queries within 30 m"
        ),
        Column("gps_sigma_m", "float", "m", "sigma of the anchor's simulated GPS fix on east and north; empty: no fix"),
        Column(
            "camera_prior",
            "str",
            "",
            "on: the training cameras (less the sequence's companions) gate and cost the pose, co-visibility, verifier | off: none of them",
        ),
        Column("queries", "int", "", "anchors localized"),
        Column("mean_frames", "float", "", "frames used, mean (an anchor with fewer companions uses what it has)"),
        Column("median_m", "float", "m", "median position error of the anchor"),
        Column("median_deg", "float", "deg", "median orientation error of the anchor"),
        *RECALL_COLUMNS,
        Column("within_5m_5deg", "float", "%", "anchors within (5 m, 5 deg)"),
        Column("within_5m_5deg_every_frame", "float", "%", "every frame of the sequences within (5 m, 5 deg)"),
        Column("wrong_scene_pct", "float", "%", "anchors more than 500 m off (another tile of a city)"),
        Column("no_pose_pct", "float", "%", "anchors without a pose"),
        Column("cpu_median_ms", "float", "ms", "CPU per sequence (all its frames together) on one core, median"),
        Column("cpu_p90_ms", "float", "ms", "CPU per sequence on one core, 90th percentile"),
        Column("bound_median_m", "float", "m", "the same sequences with their true matches: median position error"),
        Column("bound_within_5m_5deg", "float", "%", "the same with true matches: anchors within (5 m, 5 deg)"),
        *ANSWER_COLUMNS,
    ],
    "reference_map_reproduction": [
        Column("scene", "str", "", "class-cloud scene id, or 'all'"),
        Column("published", "int", "", "objects of the published reference map"),
        Column("ours", "int", "", "objects we cluster from the scene's class point cloud"),
        Column(
            "matched",
            "int",
            "",
            "published objects matched to one of ours (same macro-class: a published object takes the colour of the cluster it is the exact mean of, else of its nearest coloured point; Hungarian, within objects.audit_radius_m)",
        ),
        Column("within_0.05m", "int", "", "matched within 0.05 m"),
        Column("within_0.5m", "int", "", "matched within 0.5 m"),
        Column("within_2m", "int", "", "matched within 2 m"),
        Column("median_dist_m", "float", "m", "median distance of the matches"),
        Column("extra", "int", "", "our objects not matched within 0.5 m (ours - within_0.5m)"),
        Column("frac_within_0.5m", "float", "", "within_0.5m / published (target 0.9)"),
    ],
    "recovery": [
        Column("scene", "str", "", "scene id, or 'all'"),
        Column("queries", "int", "", "published GT local maps"),
        Column("recovered", "int", "", "registered onto the reference map"),
        Column("max_residual_m", "float", "m", "largest object residual of a recovered query"),
        Column("ambiguous", "int", "", "queries with a second solution within recover.tol_m"),
        Column("resolved_exact_fit", "int", "", "ambiguous queries settled by the exact fit"),
        Column("same_classes", "int", "", "ambiguous queries whose solutions agree on every class"),
        Column("unresolved", "int", "", "equally exact solutions that disagree on classes"),
        Column("seconds", "float", "s", "registration wall time (not reproducible)"),
    ],
}


def _kind(series: pd.Series) -> str:
    if pd.api.types.is_bool_dtype(series):
        return "bool"
    if pd.api.types.is_integer_dtype(series):
        return "int"
    if pd.api.types.is_float_dtype(series):
        return "float"
    return "str"


def check_schema(df: pd.DataFrame, name: str) -> None:
    """Raise ValueError naming every column that is missing, extra or of the wrong kind."""
    schema = SCHEMAS[name]
    want = [c.name for c in schema]
    problems = []
    if list(df.columns) != want:
        missing = [c for c in want if c not in df.columns]
        extra = [c for c in df.columns if c not in want]
        problems.append(f"columns differ (missing {missing}, extra {extra}, order matters)")
    for c in schema:
        if c.name in df.columns and _kind(df[c.name]) != c.kind:
            problems.append(f"{c.name}: {_kind(df[c.name])} instead of {c.kind}")
    if problems:
        raise ValueError(f"table {name!r} does not match its schema: " + "; ".join(problems))


def to_markdown(df: pd.DataFrame, floatfmt: str = ".3g") -> str:
    """The frame as a Markdown table; every header and cell escaped (:func:`flatlandia.plumbing.escape.markdown`)."""

    def fmt(v):
        if isinstance(v, (float, np.floating)):
            return "" if np.isnan(v) else format(v, floatfmt)
        return escape.markdown(v)

    cols = [escape.markdown(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines) + "\n"


def to_latex(df: pd.DataFrame, floatfmt: str = ".3g", caption: str = "") -> str:
    """The frame as a LaTeX table; every header, cell and the caption escaped (:func:`flatlandia.plumbing.escape.latex`)."""

    def esc(v) -> str:
        if isinstance(v, (float, np.floating)):
            return "--" if np.isnan(v) else format(v, floatfmt)
        return escape.latex(v)

    cols = list(df.columns)
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\begin{tabular}{" + "l" * len(cols) + "}",
        r"\hline",
        " & ".join(esc(c) for c in cols) + r" \\",
        r"\hline",
    ]
    lines += [" & ".join(esc(v) for v in row) + r" \\" for row in df.itertuples(index=False)]
    lines += [r"\hline", r"\end{tabular}"]
    if caption:
        lines.append(r"\caption{" + esc(caption) + "}")
    lines.append(r"\end{table}")
    return "\n".join(lines) + "\n"


def write_table(
    df: pd.DataFrame,
    name: str,
    parquet: str | Path,
    markdown: str | Path | None = None,
    latex: str | Path | None = None,
    title: str = "",
    note: str = "",
) -> None:
    """Check the schema, then write Parquet (schema in its metadata) and the renderings. The cells are
    escaped for each format; ``title`` and ``note`` are the caller's own text (the note may hold
    Markdown), written as given into the Markdown and, for ``title``, escaped as the LaTeX caption."""
    check_schema(df, name)
    meta = {"table": name, "columns": {c.name: {"unit": c.unit, "meaning": c.meaning} for c in SCHEMAS[name]}}
    write_parquet(df, parquet, meta)
    if markdown:
        head = f"# {title}\n\n" if title else ""
        write_text(head + (note + "\n\n" if note else "") + to_markdown(df), markdown)
    if latex:
        write_text(to_latex(df, caption=title), latex)


#: tables written under more than one name with the same columns (the city rows of beyond one
#: frame sit in a file of their own, so `all` never reruns them)
SAME_COLUMNS_AS = {
    "beyond_one_frame_city": "beyond_one_frame",
    "ablations": "fine_localization",  # target ablations: the ablation runs beside the runs they ablate
    "ablations_one_frame": "beyond_one_frame",  # target ablations: the protocol's scene rows, camera prior on and off
}


def schema_markdown() -> str:
    """Documentation of every table's columns (rendered into docs/tables.md)."""
    out = [
        "# Result tables\n",
        "Generated from `workflow/flatlandia/tables.py`; every table is checked against this schema when written.\n",
    ]
    for name, cols in SCHEMAS.items():
        out.append(f"\n## `results/tables/{name}.parquet`\n")
        also = [f"`results/tables/{a}.parquet`" for a, of in SAME_COLUMNS_AS.items() if of == name]
        if also:
            out.append(f"The same columns: {', '.join(also)}.\n")
        out.append("| column | type | unit | meaning |\n|---|---|---|---|")
        # a meaning lists its values with " | ": escaped, so the cell stays one cell
        out += [f"| `{c.name}` | {c.kind} | {c.unit} | {c.meaning.replace('|', chr(92) + '|')} |" for c in cols]
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------------- two runs' tables

#: columns whose values are wall or CPU times of a run, not results: two runs' tables are compared
#: on every other column (benchmarks/compare_tables.py, the tests' round trips)
TIMING = re.compile(r"(^|_)(s|ms|sec|seconds|time|minutes|min)(_|$)|query_ms|train_s|qt_", re.IGNORECASE)


def timing_columns(columns) -> list[str]:
    """The columns of ``columns`` that are timings (:data:`TIMING`; the paper's own values are not)."""
    return [c for c in columns if TIMING.search(str(c)) and not str(c).startswith("paper_")]


def columns_equal(a: pd.Series, b: pd.Series, tolerance: float = 0.0) -> bool:
    """Two columns hold the same values: floats within ``tolerance`` (NaN equals NaN), anything else as text."""
    if a.dtype.kind in "fc" and b.dtype.kind in "fc":
        return bool(np.allclose(a.to_numpy(float), b.to_numpy(float), rtol=0, atol=tolerance, equal_nan=True))
    return a.astype(str).tolist() == b.astype(str).tolist()


def table_differences(a: str | Path, b: str | Path, tolerance: float = 0.0) -> list[str]:
    """How table file ``a`` differs from table file ``b`` (Parquet): columns, rows, then every
    non-timing column (:func:`columns_equal`); empty when they agree."""
    ta, tb = pd.read_parquet(a), pd.read_parquet(b)
    if list(ta.columns) != list(tb.columns):
        return [f"columns differ: {sorted(set(ta.columns) ^ set(tb.columns))}"]
    if len(ta) != len(tb):
        return [f"{len(ta)} rows vs {len(tb)}"]
    skip = set(timing_columns(ta.columns))
    return [f"column {c!r} differs" for c in ta.columns if c not in skip and not columns_equal(ta[c], tb[c], tolerance)]
