"""The city-scale table: one row per (city size, method), from the summaries of rule city_eval
and rule city_simulate."""

from __future__ import annotations

import pandas as pd

from flatlandia.report import tables

#: columns of results/tables/city_scale.parquet, in order (schema: flatlandia.report.tables)
COLUMNS = [c.name for c in tables.SCHEMAS["city_scale"]]


def table(summaries: list[dict]) -> pd.DataFrame:
    """The rows, by map kind, size and method."""
    df = pd.DataFrame(summaries).reindex(columns=COLUMNS)  # a summary of an older run lacks the answers' figures
    df = df.astype({"scenes": int, "cities": int, "objects": int, "queries": int})
    return df.sort_values(["map", "objects", "method"], ascending=[False, True, False], ignore_index=True)


def markdown(df: pd.DataFrame, note: str) -> str:
    """The headline columns first (as the issue's table), then every recall."""
    head = df.rename(
        columns={
            "median_m": "median m",
            "within_5m_5deg": "% within (5 m, 5 deg)",
            "wrong_scene_pct": "% wrong scene",
            "no_pose_pct": "% no pose",
            "cpu_median_ms": "CPU median ms",
            "cpu_p90_ms": "CPU p90 ms",
            "region_hit_pct": "% true place in regions",
            "index_mb": "index MB",
            "index_build_s": "index build s",
            "answered_pct": "% answered",
            "within_answered_pct": "answered: % within (5 m, 5 deg)",
            "wrong_scene_answered_pct": "answered: % wrong scene",
            "answerable_95_pct": "answerable at ≥ 95 % within",
            "answerable_wrong_1pct": "answerable at ≤ 1 % wrong scene",
            "answerable_wrong_2pct": "answerable at ≤ 2 % wrong scene",
            "ece_points": "calibration error",
        }
    )
    return (
        "# City scale: one query against a whole city's object map\n\n"
        + note
        + "\n\n"
        + tables.to_markdown(head, ".3g")
    )
