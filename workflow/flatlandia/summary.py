"""The summary at the end of a run: per scene what was built, what is empty and why.

Why: a run that ends rc 0 with an empty map (no segmentation model, no object classes) must say
so where the user looks (the terminal and ``results/summary.md``), not only inside a rule's log.
Reads what is on disk under ``results/``, so it describes every run, whatever its target.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from flatlandia import io

#: why a scene's map can be empty, for the files that do not say it themselves
EMPTY_MAP_HINT = (
    "no objects: the segmentation backend labelled no SfM point with an object class "
    "(the offline backend finds none; see README 'Own photos')"
)


def _rows(path: Path) -> int | None:
    if not path.exists():
        return None
    import pyarrow.parquet as pq

    return int(pq.ParquetFile(path).metadata.num_rows)


def scene_line(results: Path, scene: str) -> tuple[str, list[str]]:
    """One line describing a scene's built artifacts, and the reasons any of them is empty."""
    base = results / scene
    parts, empty = [], []
    images = base / "images" / "images.parquet"
    if images.exists():
        table = pd.read_parquet(images, columns=["kept"])
        parts.append(f"{int(table['kept'].sum())} of {len(table)} images kept")
    stats = base / "sfm" / "sfm_stats.parquet"
    if stats.exists():
        s = pd.read_parquet(stats).iloc[0]
        parts.append(f"SfM {int(s['registered'])} cameras, {int(s['points3D'])} points")
    objects = _rows(base / "objects" / "objects.parquet")
    if objects is not None:
        parts.append(f"{objects} clustered objects")
        if objects == 0:
            meta = io.read_parquet_metadata(base / "objects" / "objects.parquet")
            empty.append(meta.get("empty_because", EMPTY_MAP_HINT))
    ref = _rows(base / "maps" / "reference_map.parquet")
    if ref is not None:
        meta = io.read_parquet_metadata(base / "maps" / "reference_map.parquet")
        local = meta.get("frame") == "local"
        parts.append(
            f"reference map of {ref} objects" + (f" in a local frame ({meta.get('unit')}, no lon/lat)" if local else "")
        )
        if ref == 0 and not empty:
            empty.append("the reference map is empty: " + EMPTY_MAP_HINT)
    queries = base / "queries" / "queries.parquet"
    if queries.exists():
        q = pd.read_parquet(queries, columns=["split"])
        split = q["split"].value_counts().to_dict()
        parts.append(
            f"{len(q)} queries" + (f" ({', '.join(f'{k} {v}' for k, v in sorted(split.items()))})" if split else "")
        )
        if len(q) == 0 and not empty:
            empty.append("no query: no image sees enough objects (images.min_objects)")
    loc = _rows(base / "localization" / "localization.parquet")
    if loc is not None:
        parts.append(f"{loc} localization rows (benchmark methods, no retraining)")
        if loc == 0:
            empty.append("no localization rows: the scene has no query to localize")
    return (", ".join(parts) if parts else "nothing built yet"), empty


def summary(results: str | Path, scenes: list[str]) -> str:
    """Markdown: one line per scene, then the result tables present."""
    results = Path(results)
    lines = ["# Run summary", "", "| scene | built | empty, and why |", "|---|---|---|"]
    for scene in scenes:
        built, empty = scene_line(results, scene)
        lines.append(f"| {scene} | {built} | {'; '.join(empty)} |")
    tables = sorted(p.name for p in (results / "tables").glob("*.parquet")) if (results / "tables").exists() else []
    lines += ["", "Result tables: " + (", ".join(tables) if tables else "none yet (they come with `all` or `tables`)")]
    return "\n".join(lines) + "\n"


def write_summary(results: str | Path, scenes: list[str]) -> str:
    """Write ``results/summary.md`` and return its text."""
    text = summary(results, scenes)
    path = Path(results) / "summary.md"
    with io.atomic_path(path) as tmp:
        tmp.write_text(text)
    return text
