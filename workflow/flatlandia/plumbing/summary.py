"""The summary at the end of a run: per scene what was built, what is empty and why.

Why: a run that ends rc 0 with an empty map (no segmentation model, no object classes) must say
so where the user looks (the terminal and ``results/summary.md``), not only inside a rule's log.
Reads what is on disk under ``results/``, so it describes every run, whatever its target; and
every scene with results in the folder, not only this run's: a run on one scene must not replace
the record of the scenes an earlier run built there (a column says which scenes this run selected).
Cheap: one ``stat`` per scene of the sheet, then the small files of the scenes listed.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from flatlandia.plumbing import escape, files

#: why a scene's map can be empty, for the files that do not say it themselves
EMPTY_MAP_HINT = (
    "no objects: the segmentation backend labelled no SfM point with an object class "
    "(the offline backend finds none; see docs/usage.md, 'Your own photos')"
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
            meta = files.read_parquet_metadata(base / "objects" / "objects.parquet")
            empty.append(meta.get("empty_because", EMPTY_MAP_HINT))
    ref = _rows(base / "maps" / "reference_map.parquet")
    if ref is not None:
        meta = files.read_parquet_metadata(base / "maps" / "reference_map.parquet")
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


def listed_scenes(results: str | Path, scenes: list[str], known: list[str] | None = None) -> list[str]:
    """The scenes the summary describes: those of ``known`` (the scene sheet's ids, in its order)
    that have a folder ``results/<scene>/``, and this run's ``scenes`` even without one (after the
    sheet's, where they are not in it)."""
    results = Path(results)
    this_run = [str(s) for s in scenes]
    on_disk = [str(s) for s in (known or []) if (results / str(s)).is_dir()]
    wanted = set(on_disk) | set(this_run)
    order = [str(s) for s in (known or [])] + this_run
    return [s for s in dict.fromkeys(order) if s in wanted]


def summary(results: str | Path, scenes: list[str], known: list[str] | None = None) -> str:
    """Markdown: one line per scene (:func:`listed_scenes`: every scene of ``known`` with results
    here, and this run's ``scenes``), marked when this run selected it; then the result tables
    present. Values read from disk are escaped (:func:`flatlandia.plumbing.escape.markdown`)."""
    results = Path(results)
    this_run = {str(s) for s in scenes}
    listed = listed_scenes(results, scenes, known)
    earlier = len([s for s in listed if s not in this_run])
    lines = [
        "# Run summary",
        "",
        f"This run selected {len(this_run)} scene(s) (`this run`: yes); "
        + (
            f"{earlier} other scene(s) have results in this folder from earlier runs (`this run`: no)."
            if earlier
            else "no other scene has results in this folder."
        ),
        "",
        "| scene | this run | built | empty, and why |",
        "|---|---|---|---|",
    ]
    for scene in listed:
        built, empty = scene_line(results, scene)
        cells = [scene, "yes" if scene in this_run else "no", built, "; ".join(empty)]
        lines.append("| " + " | ".join(escape.markdown(c) for c in cells) + " |")
    tables = sorted(p.name for p in (results / "tables").glob("*.parquet")) if (results / "tables").exists() else []
    lines += [
        "",
        "Result tables: "
        + (", ".join(escape.markdown(t) for t in tables) if tables else "none yet (they come with `all` or `tables`)"),
    ]
    return "\n".join(lines) + "\n"


def write_summary(results: str | Path, scenes: list[str], known: list[str] | None = None) -> str:
    """Write ``results/summary.md`` and return its text: ``scenes`` are this run's, ``known`` the
    scene sheet's ids (every one with results in the folder is described too)."""
    text = summary(results, scenes, known)
    path = Path(results) / "summary.md"
    with files.atomic_path(path) as tmp:
        tmp.write_text(text)
    return text
