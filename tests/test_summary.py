"""The run summary says per scene what was built and why something is empty."""

from __future__ import annotations

import pandas as pd

from flatlandia import io, summary


def test_summary_names_empty_scenes_and_why(tmp_path):
    res = tmp_path / "results"
    io.write_parquet(pd.DataFrame({"obj_idx": range(44)}), res / "12/maps/reference_map.parquet")
    io.write_parquet(pd.DataFrame({"split": ["train"] * 8 + ["test"] * 2}), res / "12/queries/queries.parquet")
    io.write_parquet(pd.DataFrame({"kept": [True] * 5 + [False]}), res / "mine/images/images.parquet")
    io.write_parquet(
        pd.DataFrame({"object_id": []}), res / "mine/objects/objects.parquet", {"empty_because": "no classes"}
    )
    io.write_parquet(pd.DataFrame({"obj_idx": []}), res / "mine/maps/reference_map.parquet")
    io.write_parquet(pd.DataFrame({"split": []}), res / "mine/queries/queries.parquet")
    io.write_parquet(pd.DataFrame({"queries": []}), res / "mine/localization/localization.parquet")
    io.write_parquet(
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
