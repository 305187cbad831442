"""Rule query_figures: a figure per test query and a gallery of a scene's worst queries.

Each panel is the reference map with the query's local map laid at its true pose and at the
featured runs' estimates (the solver's, the best learned model's), every estimated object linked
to the reference object it was matched to (or, for a run that stores no matches, to its true
position), and the errors in the legend.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flatlandia.plumbing import escape, names
from flatlandia.report import figures
from flatlandia.report.figures import MAP_TYPE_STYLES, TRUTH_COLOUR, Run, method_label
from flatlandia.viewer.scene_view import Estimate, QueryView, SceneView, worst_queries

#: a link to a reference object that is not the true one
WRONG_COLOUR = "#d62728"


def _camera(ax, x, y, theta_deg, colour, size, label=None) -> None:
    """A camera: a dot at its position and an arrow along its heading."""
    ax.plot(x, y, marker="o", ms=7, c=colour, mec="w", mew=0.6, ls="", zorder=6, label=label)
    d = size * np.array([np.cos(np.radians(theta_deg)), np.sin(np.radians(theta_deg))])
    ax.annotate("", xy=(x + d[0], y + d[1]), xytext=(x, y), arrowprops={"arrowstyle": "->", "color": colour}, zorder=6)


def _links(ax, view: SceneView, q: QueryView, e: Estimate, placed: np.ndarray) -> None:
    """Each estimated object to the reference object it was matched to: the run's colour when that
    is the true one, red when not; without matches, a dotted line to the object's true position."""
    ls = MAP_TYPE_STYLES[e.run.map_type]
    if e.matches is None:
        for p, t in zip(placed, q.truth()):
            ax.plot([p[0], t[0]], [p[1], t[1]], c=e.run.colour, ls=":", lw=0.9, zorder=4)
        return
    targets = view.object_xy(e.matches)
    for p, t, m, truth in zip(placed, targets, e.matches, q.ref_idx):
        if m >= 0 and np.isfinite(t).all():
            ax.plot([p[0], t[0]], [p[1], t[1]], c=e.run.colour if m == truth else WRONG_COLOUR, ls=ls, lw=1.1, zorder=4)


def draw_query(ax, view: SceneView, q: QueryView, runs: tuple[str, ...], legend: bool = True) -> None:
    """One query on the reference map: the truth in green, each of ``runs`` in its method's colour;
    the errors in a legend below, or (``legend=False``, for a gallery) in the title."""
    ref = view.ref[["x_m", "y_m"]].to_numpy(float)
    truth = q.truth()
    ax.scatter(ref[:, 0], ref[:, 1], s=10, c="0.72", zorder=1, label="reference objects")
    seen = view.object_xy(q.ref_idx)
    ax.scatter(seen[:, 0], seen[:, 1], s=90, facecolors="none", edgecolors=TRUTH_COLOUR, lw=1.2, zorder=2)
    pts = [truth, [[q.x, q.y]]]
    span = float(np.ptp(np.vstack(pts), axis=0).max()) if len(truth) else 10.0
    for t in truth:
        ax.plot([q.x, t[0]], [q.y, t[1]], c=TRUTH_COLOUR, lw=0.6, alpha=0.5, zorder=2)
    ax.scatter(truth[:, 0], truth[:, 1], s=22, marker="s", c=TRUTH_COLOUR, zorder=3)
    _camera(ax, q.x, q.y, q.theta_deg, TRUTH_COLOUR, 0.12 * span + 2, f"true pose, its {len(truth)} objects")
    for name in runs:
        e = q.estimate(name)
        if e is None:
            continue
        label = escape.mathtext(f"{e.run.label}: {e.summary()}")
        if not e.has_pose:
            ax.plot([], [], c=e.run.colour, ls=MAP_TYPE_STYLES[e.run.map_type], label=label)
            continue
        placed = e.place(q.local)
        _links(ax, view, q, e, placed)
        ax.scatter(placed[:, 0], placed[:, 1], s=30, marker="x", c=e.run.colour, lw=1.4, zorder=5)
        _camera(ax, e.x, e.y, e.theta_deg, e.run.colour, 0.12 * span + 2, label)
        pts += [placed, [[e.x, e.y]]]
    _frame(ax, np.vstack(pts))
    ax.set_xlabel(escape.mathtext(view.axes[0]))  # scene ids, tokens, units come from files: '$' starts mathtext
    ax.set_ylabel(escape.mathtext(view.axes[1]))
    ax.grid(alpha=0.3)
    if legend:
        ax.set_title(escape.mathtext(f"scene {view.scene}, query {q.token} ({len(truth)} objects)"), fontsize=9)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), frameon=False)
        return
    errors = [f"{method_label(e.run.method)}: {e.summary()}" for e in map(q.estimate, runs) if e is not None]
    ax.set_title(escape.mathtext(f"query {q.token} ({len(truth)} objects)\n" + "\n".join(errors)), fontsize=8)


def _gallery_handles(view: SceneView) -> list:
    """What the colours of a gallery's panels mean (their errors are in their titles)."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], marker="o", c="0.72", ls="", label="reference objects"),
        Line2D([], [], marker="s", c=TRUTH_COLOUR, label="true pose and local map (its objects ringed)"),
    ]
    for run in (Run.parse(name) for name in view.featured):
        handles.append(
            Line2D([], [], marker="x", c=run.colour, ls=":", label=escape.mathtext(f"{run.label}: estimate"))
        )
    handles.append(Line2D([], [], c=WRONG_COLOUR, label="matched to a wrong object"))
    return handles


def _frame(ax, pts: np.ndarray, pad: float = 0.15, min_half: float = 12.0) -> None:
    """Equal-aspect limits around the drawn query, with a margin."""
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) * (0.5 + pad), min_half)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")


def query_figure(view: SceneView, q: QueryView):
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(6.2, 7.2))
    draw_query(ax, view, q, view.featured)
    # fixed margins: a layout pass per figure is dear (docs/measurements.md, "Code paths")
    fig.subplots_adjust(left=0.13, right=0.97, top=0.95, bottom=0.22)
    return fig


def worst_figure(view: SceneView, n: int = 6):
    """The ``n`` queries the solver localizes worst, side by side (a note when there is none)."""
    plt = figures.pyplot()
    worst = worst_queries(view, n)
    cols = max(1, min(3, len(worst)))
    rows = max(1, int(np.ceil(len(worst) / cols)))
    handles = _gallery_handles(view)
    ncol = 3 if cols > 1 else 1  # a one-panel gallery is too narrow for three legend columns
    # the title and the legend above the panels, in inches from the top, so that neither touches the
    # other nor the first row's titles whatever the rows (the panels' own titles are 3 lines)
    head_in = 0.45 + 0.2 * int(np.ceil(len(handles) / ncol)) + 0.3
    height = 5.8 * rows + head_in
    fig, axes = plt.subplots(rows, cols, figsize=(5.6 * cols, height), squeeze=False)
    for ax, q in zip(axes.ravel(), worst):
        draw_query(ax, view, q, view.featured, legend=False)
    for ax in axes.ravel()[len(worst) :]:
        ax.axis("off")
    if not worst:
        note = escape.mathtext(f"scene {view.scene}: no test query localized")
        axes[0, 0].text(0.5, 0.5, note, ha="center", va="center")
        return fig
    label = Run.parse(view.featured[0]).label
    title = escape.mathtext(f"scene {view.scene}: the test queries the {label} run localizes worst")
    if cols == 1:  # one panel: the title on two lines, as narrow as the panel
        title = title.replace(": ", ":\n", 1)
    fig.suptitle(title, fontsize=12, y=1 - 0.1 / height, va="top")
    fig.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 1 - (0.45 + 0.2 * (cols == 1)) / height),
        ncol=ncol,
        fontsize=9,
        frameon=False,
    )
    # rows 5 font sizes apart: the x labels of a row and the 3-line titles of the next did touch
    fig.tight_layout(rect=(0, 0, 1, 1 - (head_in + 0.2 * (cols == 1)) / height), h_pad=5.0)
    return fig


def write_query_figures(view: SceneView, folder: str | Path) -> list[Path]:
    """``{token}.png`` in ``folder`` for each test query the runs localize."""
    out = []
    for q in view.test_queries():
        if q.estimates:
            path = names.child(folder, q.token, ".png", "query token")
            figures.save(query_figure(view, q), path, dpi=80, tight=False)
            out.append(path)
    return out
