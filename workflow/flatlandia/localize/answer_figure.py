"""One answer drawn on its map (``flatlandia localize --plot FILE``): the map's objects by class, the
pose (the camera and its heading), the query's objects laid at the pose with a ray from the camera
to each (and a dotted link to the map object each was matched to), the alternatives fainter with
their probabilities, a sequence's other frames, and a title with the status and probability.

Why a figure of its own: an answer is numbers; whether an ``ambiguous`` answer's alternatives lie
across the street or in another tile is seen at once on the map. matplotlib is not among the
localizer's dependencies (the localizer alone installs without it): :func:`check_plot` says what
to install, in one line, before any work. The style is the workflow's figures': Agg, the classes
in ``tab20`` by sorted label as ``reference_map.png`` and the map viewer colour them, the solver's
colour for the pose (:mod:`flatlandia.report.figures`).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from flatlandia.classes import CLASSES
from flatlandia.localize.object_map import ObjectMap
from flatlandia.localize.query_files import Query
from flatlandia.plumbing import escape
from flatlandia.plumbing.errors import InputError

#: what --plot writes, by the file's suffix
FORMATS = {".png": "png", ".svg": "svg"}
#: metres of map around the drawn answer (a city map is drawn only there; a scene map whole)
MARGIN_M = 20.0
#: how faint the alternatives are beside the pose
ALTERNATIVE_ALPHA = 0.4
#: metres: an answer drawn wider than this (a city's tiles, an alternative far off) gets a close-up
#: of its pose beside it
CLOSE_UP_M = 400.0


def check_plot(path: str | Path) -> str:
    """The format of a --plot file (its suffix), and matplotlib importable; InputError otherwise
    (one line: the localizer alone installs without matplotlib, the extra ``plot`` brings it)."""
    fmt = FORMATS.get(Path(path).suffix.lower())
    if fmt is None:
        raise InputError(path, f"a plot is {' or '.join(FORMATS)} (--plot answer.png)")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise InputError(
            "--plot",
            'needs matplotlib, which the localizer alone does not install: pip install "flatlandia[plot]" '
            "(or pip install matplotlib)",
        ) from None
    return fmt


def _rotate(xy: np.ndarray, theta_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg))
    return xy @ np.array([[c, s], [-s, c]])


def placed(query: Query, pose: dict) -> np.ndarray:
    """The query's objects at a pose of an answer (``x_m``, ``y_m``, ``theta_deg``, ``scale``: metres
    per query unit), in the map's frame: where the answer says the camera saw them."""
    scale = pose.get("scale") or 1.0
    return np.array([pose["x_m"], pose["y_m"]]) + _rotate(np.asarray(query.xy, float) * scale, pose["theta_deg"])


def _camera(ax, pose: dict, colour: str, size: float, alpha: float = 1.0, label=None, ls="-") -> None:
    """A camera: a dot at its position and an arrow along its heading."""
    x, y, th = pose["x_m"], pose["y_m"], math.radians(pose["theta_deg"])
    ax.plot(x, y, marker="o", ms=7, c=colour, mec="w", mew=0.6, ls="", alpha=alpha, zorder=6, label=label)
    ax.annotate(
        "",
        xy=(x + size * math.cos(th), y + size * math.sin(th)),
        xytext=(x, y),
        arrowprops={"arrowstyle": "->", "color": colour, "alpha": alpha, "lw": 1.4, "ls": ls},
        zorder=6,
    )


def _class_colours(m: ObjectMap) -> dict[int, tuple]:
    """Class id -> colour: tab20 by the map's sorted class labels (reference_map.png's, the viewer's)."""
    from flatlandia.report import figures

    cmap = figures.pyplot().get_cmap("tab20")
    labels = sorted({CLASSES[int(c)] for c in np.unique(m.cls)})
    by_label = {label: cmap(k % 20) for k, label in enumerate(labels)}
    return {int(c): by_label[CLASSES[int(c)]] for c in np.unique(m.cls)}


def _probability(p) -> str:
    return "no probability" if p is None else f"probability {p:.2f}"


def _alternative(k: int, alt: dict, answer: dict) -> str:
    """An alternative in the legend: its number on the map, how far it lies from the pose (metres,
    degrees) and its probability."""
    turn = abs((alt["theta_deg"] - answer["theta_deg"] + 180.0) % 360.0 - 180.0)
    away = math.hypot(alt["x_m"] - answer["x_m"], alt["y_m"] - answer["y_m"])
    return escape.mathtext(
        f"alternative {k + 1}: {away:.1f} m, {turn:.0f}° from the pose, {_probability(alt.get('probability'))}"
    )


def _title(answer: dict, query: Query) -> str:
    who = f"query {answer['id']}" if answer.get("id") else "the query"
    if "frames" in answer:
        who = f"a sequence of {len(answer['frames'])} frames, its anchor" if answer["frames"] else "a sequence"
    head = f"{who}: {answer['status']}"
    if not answer["found"]:
        return f"{head}\n" + textwrap.fill(answer.get("reason", ""), 100)
    where = f" (scene {answer['scene']})" if answer.get("scene") else ""
    return (
        f"{head}, {_probability(answer['probability'])}{where}\n"
        f"{len(answer['matches'])} of its {len(query.cls)} objects matched; "
        f"{len(answer['alternatives'])} alternative(s)"
    )


def _box(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners of a square around ``pts`` with :data:`MARGIN_M` metres about them."""
    lo, hi = pts.min(axis=0) - MARGIN_M, pts.max(axis=0) + MARGIN_M
    centre, half = (lo + hi) / 2, float((hi - lo).max()) / 2
    return centre - half, centre + half


def _views(m: ObjectMap, answer: dict, laid: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """What is drawn, one box per panel: a scene map whole with the answer; on a city the answer
    (its pose, laid objects, alternatives, frames). When that is wider than :data:`CLOSE_UP_M` (an
    alternative in another tile, a map of many scenes), a close-up of the pose and its objects first."""
    close = np.vstack([laid.reshape(-1, 2), [[answer["x_m"], answer["y_m"]]]]) if answer["found"] else None
    pts = close if close is not None else np.zeros((0, 2))
    if answer["found"]:
        others = [*answer["alternatives"], *answer.get("frames", [])]
        pts = np.vstack([pts, np.array([[p["x_m"], p["y_m"]] for p in others], float).reshape(-1, 2)])
    whole = _box(m.framed(pts))
    if close is not None and float((whole[1] - whole[0]).max()) > CLOSE_UP_M:
        return [_box(close), whole]
    return [whole]


def _draw(ax, m: ObjectMap, query: Query, answer: dict, laid: np.ndarray, view, colours: dict, colour) -> None:
    """One panel: the map objects inside ``view`` by class, and the answer (matches, rays, laid
    objects, alternatives numbered, a sequence's frames, the camera)."""
    lo, hi = view
    span = float((hi - lo).max())
    inside = np.flatnonzero(((m.xy >= lo) & (m.xy <= hi)).all(axis=1))
    for c in sorted({int(c) for c in m.cls[inside]}, key=lambda c: CLASSES[c]):
        rows = inside[m.cls[inside] == c]
        label = escape.mathtext(f"{CLASSES[c]} ({len(rows)})")
        ax.scatter(*m.xy[rows].T, s=22, color=colours[c], edgecolor="k", linewidth=0.3, zorder=3, label=label)
    if answer["found"]:
        row_of = {int(o): k for k, o in enumerate(m.obj_idx)}
        for match in answer["matches"]:  # each laid object to the map object it was matched to
            k = row_of.get(int(match["obj_idx"]))
            if k is not None:
                p, t = laid[match["query_object"]], m.xy[k]
                ax.plot([p[0], t[0]], [p[1], t[1]], c=colour, ls=":", lw=0.9, zorder=4)
        for p in laid:  # the query's rays: from the camera to each of its objects at the pose
            ax.plot([answer["x_m"], p[0]], [answer["y_m"], p[1]], c=colour, lw=0.7, alpha=0.6, zorder=4)
        edges = [colours.get(int(c), "k") for c in query.cls]
        ax.scatter(*laid.T, s=46, marker="D", facecolors="none", edgecolors=edges, zorder=5)
        ax.scatter(*laid.T, s=14, marker="x", c=colour, lw=1.0, zorder=5)
        for k, alt in enumerate(answer["alternatives"]):  # numbered here, described in the legend
            _camera(ax, alt, colour, 0.05 * span, ALTERNATIVE_ALPHA, ls="--")
            ax.annotate(
                str(k + 1), (alt["x_m"], alt["y_m"]), xytext=(5, 4), textcoords="offset points", fontsize=7, zorder=7
            )
        if len(answer.get("frames", [])) > 1:
            track = np.array([[f["x_m"], f["y_m"]] for f in answer["frames"]], float)
            ax.plot(*track.T, c=colour, lw=1.0, ls="-.", alpha=0.7, zorder=5)
            for f in answer["frames"][1:]:
                _camera(ax, f, colour, 0.035 * span, 0.7)
        _camera(ax, answer, colour, 0.08 * span)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)" if m.geographic else "x (the map's frame)")
    ax.set_ylabel("y north (m)" if m.geographic else "y (the map's frame)")
    ax.grid(alpha=0.3)


def _answer_handles(answer: dict, colour) -> list:
    """The legend of what the answer's marks mean, an alternative per line."""
    from matplotlib.lines import Line2D

    if not answer["found"]:
        return []
    return [
        Line2D([], [], c=colour, marker="o", label=escape.mathtext(f"pose: {_probability(answer['probability'])}")),
        Line2D([], [], c=colour, lw=0.7, marker="x", label="the query's objects at the pose, rays from the camera"),
        Line2D([], [], c=colour, ls=":", label="matched to this map object"),
        *(
            Line2D([], [], c=colour, ls="--", marker="o", alpha=ALTERNATIVE_ALPHA, label=_alternative(k, alt, answer))
            for k, alt in enumerate(answer["alternatives"])
        ),
        *(
            [Line2D([], [], c=colour, ls="-.", marker="o", label="the sequence's other frames")]
            if len(answer.get("frames", [])) > 1
            else []
        ),
    ]


def answer_figure(m: ObjectMap, query: Query, answer: dict):
    """The figure of one answer (:func:`flatlandia.localize.localize`'s, or a sequence's) of
    ``query`` (the sequence's anchor frame) on the map it was localized on: one panel, or a
    close-up of the pose beside the whole (:func:`_views`)."""
    from flatlandia.report import figures

    plt = figures.pyplot()
    colour = figures.method_colour("solver")
    colours = _class_colours(m)
    laid = placed(query, answer) if answer["found"] else np.zeros((0, 2))
    views = _views(m, answer, laid)
    fig, axes = plt.subplots(1, len(views), figsize=(1.5 + 6.5 * len(views), 7.5), dpi=110, squeeze=False)
    for ax, view in zip(axes[0], views, strict=True):
        _draw(ax, m, query, answer, laid, view, colours, colour)
    if len(views) > 1:
        axes[0, 0].set_title("the pose, close up", fontsize=8)
        axes[0, 1].set_title("the answer and its alternatives", fontsize=8)
    fig.suptitle(escape.mathtext(_title(answer, query)), fontsize=9)
    last = axes[0, -1]
    last.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="map objects")
    handles = _answer_handles(answer, colour)
    if handles:
        fig.legend(handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, 0.02), frameon=False)
    fig.tight_layout()
    return fig


def write_answer_figure(m: ObjectMap, query: Query, answer: dict, path: str | Path, *, reads=(), artifacts=()) -> Path:
    """Draw an answer (:func:`answer_figure`) into ``path`` (PNG or SVG by its suffix), written
    atomically through the write door (``reads``, ``artifacts``: what it must not replace)."""
    from flatlandia.plumbing import files
    from flatlandia.report import figures

    fmt = check_plot(path)
    fig = answer_figure(m, query, answer)
    try:
        with files.atomic_path(path, reads=reads, artifacts=artifacts) as tmp:
            fig.savefig(tmp, format=fmt, bbox_inches="tight")
    finally:
        figures.pyplot().close(fig)
    return Path(path)
