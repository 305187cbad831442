"""The table of "beyond one frame": results/tables/beyond_one_frame.{parquet,md} (the scene rows) and
beyond_one_frame_city.{parquet,md} (the same columns, the scene and city rows).

One row per (map, frames, GPS sigma, camera prior) from the summaries of rules beyond_scene and
beyond_city (:func:`flatlandia.sequences.evaluation.summaries`); the Markdown puts the headline columns
first, the true-match bound beside them, and OrienterNet's published recalls under them, labelled
as another task.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import paper
from flatlandia.benchmark import metrics
from flatlandia.plumbing import escape
from flatlandia.report import tables

#: columns of results/tables/beyond_one_frame.parquet, in order (schema: flatlandia.report.tables)
COLUMNS = [c.name for c in tables.SCHEMAS["beyond_one_frame"]]
#: maps in the table's order
MAP_ORDER = ("scene", "city", "simulated")


def table(summaries: list[dict]) -> pd.DataFrame:
    """The rows: scene map first, then the cities; by camera prior (on first), GPS (none first), frames."""
    df = pd.DataFrame(summaries).reindex(columns=COLUMNS)  # a summary of an older run lacks the answers' figures
    df = df.astype({"objects": int, "frames": int, "queries": int})
    kind = df["map"].str.split("-").str[0].map({m: k for k, m in enumerate(MAP_ORDER)}).fillna(len(MAP_ORDER))
    order = pd.DataFrame(
        {
            "kind": kind,
            "objects": df["objects"],
            "camera": df["camera_prior"].ne("on").astype(int),
            "gps": df["gps_sigma_m"].fillna(0.0),
            "frames": df["frames"],
        }
    )
    idx = order.sort_values(["kind", "objects", "camera", "gps", "frames"], kind="stable").index
    return df.loc[idx].reset_index(drop=True)


def _cell(v, fmt: str = ".1f") -> str:
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)


def markdown(df: pd.DataFrame, note: str) -> str:
    """Headline columns (as the issue asks them), the bound beside, then every recall, then OrienterNet."""
    heads = [
        "map",
        "frames",
        "GPS sigma m",
        "camera prior",
        "queries",
        "median m / deg",
        "% within 1 / 3 / 5 m",
        "% within 1 / 3 / 5°",
        "% within (5 m, 5°)",
        "every frame",
        "% wrong scene",
        "CPU ms median / p90",
        "true matches: median m, % within (5 m, 5°)",
        "% answered",
        "answered: % within (5 m, 5°) / % wrong scene",
        "answerable at ≥ 95 % within / ≤ 1 % wrong scene",
    ]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for r in df.to_dict("records"):
        rec_m = " / ".join(_cell(r[c]) for c in metrics.RECALL_COLUMNS[:3])
        rec_d = " / ".join(_cell(r[c]) for c in metrics.RECALL_COLUMNS[3:])
        cells = [
            escape.markdown(str(r["map"])),
            str(int(r["frames"])) + (f" ({r['mean_frames']:.2f})" if r["mean_frames"] < r["frames"] - 0.005 else ""),
            _cell(r["gps_sigma_m"], "g") if np.isfinite(r["gps_sigma_m"]) else "",
            escape.markdown(str(r["camera_prior"])),
            str(int(r["queries"])),
            f"{_cell(r['median_m'], '.2f')} / {_cell(r['median_deg'], '.2f')}",
            rec_m,
            rec_d,
            _cell(r["within_5m_5deg"]),
            _cell(r["within_5m_5deg_every_frame"]),
            _cell(r["wrong_scene_pct"]),
            f"{_cell(r['cpu_median_ms'])} / {_cell(r['cpu_p90_ms'])}",
            f"{_cell(r['bound_median_m'], '.2f')}, {_cell(r['bound_within_5m_5deg'])}",
            _cell(r["answered_pct"]),
            f"{_cell(r['within_answered_pct'])} / {_cell(r['wrong_scene_answered_pct'])}",
            f"{_cell(r['answerable_95_pct'])} / {_cell(r['answerable_wrong_1pct'])}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    single = [paper.ORIENTERNET_MGL_RECALL_M[m] for m in metrics.RECALL_M] + [
        paper.ORIENTERNET_MGL_RECALL_DEG[d] for d in metrics.RECALL_DEG
    ]
    seq = [paper.ORIENTERNET_MGL_SEQUENTIAL_RECALL_M[m] for m in metrics.RECALL_M] + [
        paper.ORIENTERNET_MGL_SEQUENTIAL_RECALL_DEG[d] for d in metrics.RECALL_DEG
    ]
    other = [
        "## OrienterNet, for scale: another task",
        "",
        "OrienterNet (Sarlin et al., CVPR 2023) on its MGL benchmark: one image (or a sequence) against an "
        "OpenStreetMap raster, with a location prior, on a GPU. Not a baseline of this task (an object map "
        "registered against an object map); quoted beside our recalls for scale.",
        "",
        "| OrienterNet, MGL | frames | % within 1 / 3 / 5 m | % within 1 / 3 / 5° |",
        "|---|---|---|---|",
        "| single image with a prior | 1 | "
        + " / ".join(f"{v:.1f}" for v in single[:3])
        + " | "
        + " / ".join(f"{v:.1f}" for v in single[3:])
        + " |",
        f"| sequential | {paper.ORIENTERNET_MGL_SEQUENTIAL_FRAMES} | "
        + " / ".join(f"{v:.1f}" for v in seq[:3])
        + " | "
        + " / ".join(f"{v:.1f}" for v in seq[3:])
        + " |",
    ]
    return (
        "# Beyond one frame: a GPS fix and a few frames of motion\n\n"
        + note
        + "\n\n"
        + "\n".join(lines)
        + "\n\n"
        + "\n".join(other)
        + "\n"
    )


def note(split: str, beyond: dict) -> str:
    """The table's note: the protocol in words (docs/results.md, "Beyond one frame", has it in full)."""
    return (
        f"Depth local maps, {split} split; each row's anchors are the {split} queries. A sequence of k frames is "
        f"the anchor and its k-1 nearest queries of the scene within {beyond['sequence_radius_m']:g} m (any split), "
        f"tied by simulated odometry: each step of the chain (anchor, nearest companion, next...) is the true "
        f"relative pose plus Gaussian noise of {beyond['odometry_distance_pct']:g} % of the step's length on forward "
        f"and left and {beyond['odometry_heading_deg']:g}° on the turn. A companion's own training camera is left "
        "out of the camera prior, the co-visibility sets and the verifier's views while it is used; the anchor is "
        "never in them. GPS: the anchor's true position plus sigma times a standard normal draw on east and north "
        "(one draw per anchor, seeded by the config's seed, shared by every sigma); the solver weighs it as a "
        "Gaussian likelihood and keeps poses within 4 sigma. `camera prior off`: no training cameras at all (no "
        "gate, co-visibility or verifier). `every frame`: % of all the sequences' frames within (5 m, 5°). CPU: "
        "the whole sequence (every frame's search and the joint solve; for a city, the index too) on one core. "
        "Wrong scene: a pose more than 500 m off. The bound: the same sequences refined on their true matches "
        "from the truth (bearings, the odometry and the fix; no training priors). Answered: the anchors whose "
        "calibrated probability of being within (5 m, 5°) is at least `solver.answer_probability` (status ok); "
        "answerable: the largest share answerable, surest first, with at least 95 % of the answered within "
        "(5 m, 5°) / at most 1 % in the wrong scene."
    )
