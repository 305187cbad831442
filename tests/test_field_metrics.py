"""The field's metrics: recall at 1 / 3 / 5 m and 1 / 3 / 5 deg for every fine run, in the
fine_localization table (Parquet, markdown, LaTeX) and the scene rows, OrienterNet's published MGL
figures beside them as another task's."""

import numpy as np
import pandas as pd
import pytest

from flatlandia import paper
from flatlandia.benchmark import fine_rows, metrics
from flatlandia.fine import fine_table, scene_localization
from flatlandia.report import tables


def _errors(error_m, error_deg):
    n = len(error_m)
    return pd.DataFrame(
        {
            "error_m": error_m,
            "error_deg": error_deg,
            "solvable": [np.isfinite(m) for m in error_m],
            "seconds": [0.01] * n,
            "error_paper_m": error_m,
        }
    )


#: ten queries: position and heading fall on different thresholds; two failed (no pose)
ERRORS = _errors(
    [0.5, 0.9, 2.0, 2.9, 4.0, 4.9, 20.0, 0.2, np.inf, np.inf],
    [30.0, 0.5, 0.9, 2.5, 4.5, 60.0, 2.0, 4.0, 180.0, 180.0],
)


def test_recall_counts_position_and_heading_apart_and_failures_as_misses():
    s = metrics.summarise(ERRORS)
    # under 1 m: 0.5, 0.9, 0.2 (the first has a 30 deg heading: position recall ignores it)
    assert s["recall_1m"] == pytest.approx(30.0)
    assert s["recall_3m"] == pytest.approx(50.0)  # + 2.0, 2.9
    assert s["recall_5m"] == pytest.approx(70.0)  # + 4.0, 4.9; 20 m and both failures miss
    # under 1 deg: 0.5, 0.9 (positions 0.9 m and 2 m: heading recall ignores them)
    assert s["recall_1deg"] == pytest.approx(20.0)
    assert s["recall_3deg"] == pytest.approx(40.0)  # + 2.5, 2.0 (the 20 m query)
    assert s["recall_5deg"] == pytest.approx(60.0)  # + 4.5, 4.0; 30, 60 and the failures miss
    assert s["pct_1m_5deg"] == pytest.approx(20.0)  # the paper's joint threshold is unchanged
    empty = metrics.summarise(ERRORS.iloc[:0])
    assert all(np.isnan(empty[c]) for c in metrics.RECALL_COLUMNS)


def test_orienternet_figures_are_keyed_by_our_thresholds():
    assert tuple(paper.ORIENTERNET_MGL_RECALL_M) == metrics.RECALL_M
    assert tuple(paper.ORIENTERNET_MGL_RECALL_DEG) == metrics.RECALL_DEG
    assert metrics.RECALL_COLUMNS == [
        "recall_1m",
        "recall_3m",
        "recall_5m",
        "recall_1deg",
        "recall_3deg",
        "recall_5deg",
    ]


def _summaries():
    """Two runs as fine_eval writes them: the solver on GT-BB (gt maps) and on the whole map (depth)."""
    gtbb = {"run": "solver_gt_gtbb", "map_type": "gt", "strategy": "GT-BB", **metrics.summarise(ERRORS)}
    whole = _errors([0.5, 2.0, 10.0, np.inf], [0.5, 2.0, 10.0, 180.0])
    return [
        gtbb,
        {"run": "solver_depth_whole", "map_type": "depth", "strategy": "whole map", **metrics.summarise(whole)},
    ]


def test_every_run_has_its_recalls_in_parquet_markdown_and_latex(tmp_path):
    df = fine_rows.table_rows(_summaries())
    tables.write_table(df, "fine_localization", tmp_path / "f.parquet", tmp_path / "f.md", tmp_path / "f.tex")
    back = pd.read_parquet(tmp_path / "f.parquet").set_index("run")
    assert back.loc["solver_gt_gtbb", metrics.RECALL_COLUMNS].tolist() == pytest.approx([30, 50, 70, 20, 40, 60])
    assert back.loc["solver_depth_whole", metrics.RECALL_COLUMNS].tolist() == pytest.approx([25, 50, 50, 25, 50, 50])

    flat = (tmp_path / "f.md").read_text().splitlines()
    head = [c.strip() for c in flat[0].split("|")[1:-1]]
    row = dict(zip(head, (c.strip() for c in flat[2].split("|")[1:-1])))
    assert row["run"] == "solver_gt_gtbb" and [row[c] for c in metrics.RECALL_COLUMNS] == [
        "30",
        "50",
        "70",
        "20",
        "40",
        "60",
    ]
    tex = (tmp_path / "f.tex").read_text()
    assert r"recall\_1m & recall\_3m & recall\_5m & recall\_1deg & recall\_3deg & recall\_5deg" in tex
    assert r"solver\_depth\_whole" in tex and "& 25 & 50 & 50 & 25 & 50 & 50 &" in tex


def test_paper_layout_keeps_tables_4_5_and_adds_recall_beside_orienternet():
    md = fine_table.render_markdown(fine_rows.table_rows(_summaries()))
    table4, recall = md.split("## Recall at the field's thresholds")
    assert "## Table 4 (GT-BB proposals)" in table4 and "## Table 5 (coarse proposals and whole map)" in table4
    assert "recall" not in table4.split("## Table 4")[1]  # the paper's layout stays as it was
    lines = recall.splitlines()
    assert "| method | proposal | map type | 1 m | 3 m | 5 m | 1° | 3° | 5° | (5 m, 5°) |" in lines
    assert "| geometric solver | GT-BB | gt | 30.0 | 50.0 | 70.0 | 20.0 | 40.0 | 60.0 | 50.0 |" in lines
    assert "| geometric solver | whole map | depth | 25.0 | 50.0 | 50.0 | 25.0 | 50.0 | 50.0 | 50.0 |" in lines
    theirs = [ln for ln in lines if ln.startswith("| OrienterNet")]
    assert theirs == [
        "| OrienterNet, MGL (another task) | OSM raster, 100-200 m prior | image | 14.4 | 48.7 | 61.7 | 21.0 | 55.0 | 70.2 | – |"
    ]
    assert "not as a baseline" in recall and "100-200 m location prior" in recall


def test_a_run_without_recalls_reads_as_missing_not_zero():
    """A summary written before the recalls existed: NaN in the table, a dash in the markdown."""
    old = {k: v for k, v in _summaries()[0].items() if k not in metrics.RECALL_COLUMNS}
    df = fine_rows.table_rows([old])
    assert df[metrics.RECALL_COLUMNS].isna().all(axis=None)
    assert "| geometric solver | GT-BB | gt | – | – | – | – | – | – |" in fine_table.render_markdown(df)


def test_scene_rows_markdown_shows_the_recalls():
    rows = pd.DataFrame(
        [
            {
                "scene": "9",
                "method": "geometric solver",
                "method_slug": "solver",
                "map_type": "depth",
                "proposal": "whole",
                "strategy": "whole map",
                **metrics.summarise(ERRORS),
            }
        ]
    )
    lines = scene_localization.render_markdown(rows, "9").splitlines()
    head = [c.strip() for c in lines[2].split("|")[1:-1]]
    cells = dict(zip(head, (c.strip() for c in lines[4].split("|")[1:-1])))
    assert [cells[c] for c in metrics.RECALL_COLUMNS] == ["30.00", "50.00", "70.00", "20.00", "40.00", "60.00"]
