"""Rule viewer: one scene as a self-contained HTML page (an SVG map viewer).

Why self-contained: the page is opened from disk or from the Snakemake report, on machines
without a server or a network. Its script, style and the scene's data are written into the page
at build time from this package's ``assets/`` (plain JavaScript, no library); it fetches nothing.
The output is deterministic: the same inputs give the same bytes.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from flatlandia.plumbing import escape, files
from flatlandia.report import figures
from flatlandia.report.figures import MAP_TYPE_DASHES, TRUTH_COLOUR
from flatlandia.viewer.query_figures import WRONG_COLOUR
from flatlandia.viewer.scene_view import Estimate, QueryView, SceneView

ASSETS = Path(__file__).parent / "assets"
#: query cameras by split, as results/{scene}/maps/reference_map.png draws them
SPLIT_COLOURS = {"train": "#8c8c8c", "val": "#1f77b4", "test": "#d62728"}


def _r(v: float, digits: int = 2) -> float | None:
    """A coordinate rounded to centimetres (JSON has no NaN: None)."""
    return round(float(v), digits) if np.isfinite(v) else None


def _estimate(e: Estimate) -> list:
    """[x, y, heading deg, error m, error deg, inliers, correct inliers, matches or None]."""
    matches = None if e.matches is None else list(e.matches)
    pose = [_r(e.x), _r(e.y), _r(e.theta_deg)] if e.has_pose else [None, None, None]
    return pose + [_r(e.error_m, 3), _r(e.error_deg, 2), e.n_inliers, e.n_correct_inliers, matches]


def _query(q: QueryView) -> dict:
    return {
        "token": q.token,
        "split": q.split,
        "x": _r(q.x),
        "y": _r(q.y),
        "theta": _r(q.theta_deg),
        "ref": list(q.ref_idx),
        "local": [[_r(u), _r(v)] for u, v in q.local],
        "est": {e.run.name: _estimate(e) for e in q.estimates},
    }


def _class_colours(labels: list[str]) -> list[str]:
    """tab20 by sorted class label, as the reference-map figure colours them."""
    from matplotlib.colors import to_hex

    cmap = figures.pyplot().get_cmap("tab20")
    return [to_hex(cmap(k % 20)) for k in range(len(labels))]


#: a published query's photo on Mapillary: the token is the Mapillary image key
MAPILLARY_PHOTO = "https://www.mapillary.com/app/?pKey="


def page_data(view: SceneView, photo_url: str | None = None) -> dict:
    """Everything the page draws, as JSON-ready values; ``photo_url``: the address a query's token
    is appended to for its photo (published scenes: :data:`MAPILLARY_PHOTO`), or None."""
    labels = sorted(view.ref["class_label"].astype(str).unique())
    k = {c: i for i, c in enumerate(labels)}
    counts = view.ref["class_label"].astype(str).value_counts()
    objects = [
        [_r(x), _r(y), k[str(c)], int(o)]
        for x, y, c, o in view.ref[["x_m", "y_m", "class_label", "obj_idx"]].itertuples(index=False)
    ]
    unit = view.axes[0].rsplit("(", 1)[-1].rstrip(")") if "(" in view.axes[0] else ""
    n_test = len(view.test_queries())
    return {
        "title": f"Scene {view.scene}: {len(view.ref)} objects, {len(view.queries)} queries ({n_test} test)",
        "scene": view.scene,
        "axes": list(view.axes),
        "unit": unit,
        "classes": [
            {"label": c, "colour": col, "count": int(counts[c])} for c, col in zip(labels, _class_colours(labels))
        ],
        "objects": objects,
        "queries": [_query(q) for q in view.queries],
        "photoUrl": photo_url,
        "runs": [
            {
                "name": r.name,
                "label": r.short_label,
                "group": r.setting,
                "colour": r.colour,
                "dash": MAP_TYPE_DASHES[r.map_type],
                "featured": r.name in view.featured,
            }
            for r in view.runs
        ],
        "splitColours": SPLIT_COLOURS,
        "truthColour": TRUTH_COLOUR,
        "wrongColour": WRONG_COLOUR,
    }


def render(view: SceneView, photo_url: str | None = None) -> str:
    """The page: the template with the style, the script and the scene's data written in. The title
    is HTML-escaped (:func:`flatlandia.plumbing.escape.html`), the data is JSON that cannot close its script
    block; the placeholders are filled in one pass, so a value that holds one is never filled again."""
    text = json.dumps(page_data(view, photo_url), sort_keys=True, separators=(",", ":"), allow_nan=False)
    text = text.replace("<", "\\u003c")  # the data can never close its <script> block
    parts = {
        "__TITLE__": escape.html(f"Flatlandia scene {view.scene}"),
        "__CSS__": (ASSETS / "viewer.css").read_text(),
        "__JS__": (ASSETS / "viewer.js").read_text(),
        "__DATA__": text,
    }
    template = (ASSETS / "viewer.html").read_text()
    return re.sub("|".join(parts), lambda m: parts[m.group(0)], template)


def write_page(view: SceneView, path: str | Path, photo_url: str | None = None) -> int:
    """Write the page atomically; its size in bytes."""
    html = render(view, photo_url)
    files.write_text(html, path)
    return len(html.encode())
