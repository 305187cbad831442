"""The run summary says per scene what was built and why something is empty."""

from __future__ import annotations

import pandas as pd

from flatlandia.plumbing import files, summary


def test_summary_names_empty_scenes_and_why(tmp_path):
    res = tmp_path / "results"
    files.write_parquet(pd.DataFrame({"obj_idx": range(44)}), res / "12/maps/reference_map.parquet")
    files.write_parquet(pd.DataFrame({"split": ["train"] * 8 + ["test"] * 2}), res / "12/queries/queries.parquet")
    files.write_parquet(pd.DataFrame({"kept": [True] * 5 + [False]}), res / "mine/images/images.parquet")
    files.write_parquet(
        pd.DataFrame({"object_id": []}), res / "mine/objects/objects.parquet", {"empty_because": "no classes"}
    )
    files.write_parquet(pd.DataFrame({"obj_idx": []}), res / "mine/maps/reference_map.parquet")
    files.write_parquet(pd.DataFrame({"split": []}), res / "mine/queries/queries.parquet")
    files.write_parquet(pd.DataFrame({"queries": []}), res / "mine/localization/localization.parquet")
    files.write_parquet(
        pd.DataFrame({"obj_idx": [0, 1, 2]}),
        res / "nogps/maps/reference_map.parquet",
        {"frame": "local", "unit": "SfM unit"},
    )
    text = summary.write_summary(res, ["12", "mine", "nogps", "nothing"])
    assert (res / "summary.md").read_text() == text
    lines = {
        line.split("|")[1].strip(): line for line in text.splitlines() if line.startswith("| ") and "---" not in line
    }
    assert "reference map of 44 objects" in lines["12"] and "10 queries (test 2, train 8)" in lines["12"]
    assert (
        "5 of 6 images kept" in lines["mine"]
        and "0 clustered objects" in lines["mine"]
        and "no classes" in lines["mine"]
    )
    assert "0 localization rows" in lines["mine"] and "no query to localize" in lines["mine"]
    assert "3 objects in a local frame (SfM unit, no lon/lat)" in lines["nogps"]
    assert "nothing built yet" in lines["nothing"]


def _rows_of(text: str) -> dict[str, list[str]]:
    """Scene -> its cells, from the summary's table."""
    rows = [line for line in text.splitlines() if line.startswith("| ") and "---" not in line][1:]
    return {cells[0]: cells[1:] for cells in ([c.strip() for c in line.split("|")[1:-1]] for line in rows)}


def test_summary_keeps_every_scene_with_results_across_runs(tmp_path):
    """`maps --config select=[12]`, then `select=[mine]` in the same folder: the second summary
    still describes 12 (an earlier run's), marks mine as this run's; a scene of the sheet without
    results is left out, one this run selected is listed even without any, and folders that are
    not scenes of the sheet (tables, another sheet's scene) never are."""
    res = tmp_path / "results"
    sheet = ["12", "13", "mine", "new"]
    files.write_parquet(pd.DataFrame({"obj_idx": range(44)}), res / "12/maps/reference_map.parquet")
    first = summary.write_summary(res, ["12"], known=sheet)
    assert list(_rows_of(first)) == ["12"] and _rows_of(first)["12"][0] == "yes"
    assert "no other scene has results in this folder" in first

    files.write_parquet(pd.DataFrame({"kept": [True] * 5 + [False]}), res / "mine/images/images.parquet")
    files.write_parquet(pd.DataFrame({"x": [1]}), res / "tables/recovery.parquet")
    files.write_parquet(pd.DataFrame({"kept": [True]}), res / "elsewhere/images/images.parquet")
    second = summary.write_summary(res, ["mine", "new"], known=sheet)
    assert (res / "summary.md").read_text() == second
    rows = _rows_of(second)
    assert list(rows) == ["12", "mine", "new"]  # the sheet's order
    assert rows["12"][:2] == ["no", "reference map of 44 objects"]
    assert rows["mine"][:2] == ["yes", "5 of 6 images kept"]
    assert rows["new"][:2] == ["yes", "nothing built yet"]
    assert "This run selected 2 scene(s)" in second and "1 other scene(s) have results" in second
    assert "Result tables: recovery.parquet" in second

    # a run on one scene does not shrink the record of a run on the whole sheet
    third = summary.write_summary(res, ["12"], known=sheet)
    assert {s: r[0] for s, r in _rows_of(third).items()} == {"12": "yes", "mine": "no"}
