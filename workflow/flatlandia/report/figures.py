"""Report figures: training curves, error distributions (CDFs, the paper's Fig. 8), coarse-score heat maps.

Pure plotting from the run's tables; each ``plot_*`` function writes one PNG atomically (matplotlib
Agg), each ``*_figure`` function returns the figure it draws, so tests can read its panels and
legend. Fine runs are styled alike everywhere (a colour per method, a line style per local-map
type, a panel per proposal setting), the query figures and the map viewer included.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import paper, vocabulary
from flatlandia.plumbing import escape
from flatlandia.plumbing.files import atomic_path


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display on cluster nodes); imported on first use
    so that rules without figures do not pay for it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: str | Path, dpi: int = 110, tight: bool = True) -> None:
    """Write a figure as a PNG atomically and free it. ``tight=False`` for a figure already laid out
    (``tight_layout``): the tight bounding box costs a second draw (a third of the time of a
    many-figure rule such as query_figures)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight" if tight else None, format="png")
    pyplot().close(fig)


def ecdf(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted values and the share of values <= each (non-finite values count as failures)."""
    v = np.asarray(values, float)
    n = len(v)
    finite = np.sort(v[np.isfinite(v)])
    return finite, np.arange(1, len(finite) + 1) / max(n, 1)


def plot_training_curves(curves: dict[str, pd.DataFrame], path: str | Path) -> None:
    """One panel per model: training loss (left axis) and its validation metric (right axis).

    ``curves`` maps a label to a history table with columns epoch, train_loss and one
    validation column (val_metric: higher is better; val_median_m: lower is better).
    """
    plt = pyplot()
    n = max(1, len(curves))
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, (label, h) in zip(axes.ravel(), curves.items()):
        ax.plot(h["epoch"], h["train_loss"], c="tab:blue", lw=1)
        ax.set_xlabel("epoch")
        ax.set_ylabel("training loss", color="tab:blue")
        ax.set_title(escape.mathtext(label), fontsize=9)
        val = next((c for c in ("val_metric", "val_median_m") if c in h and h[c].notna().any()), None)
        if val:
            ax2 = ax.twinx()
            ok = h[val].notna()
            ax2.plot(h.loc[ok, "epoch"], h.loc[ok, val], c="tab:orange", lw=1)
            ax2.set_ylabel(
                {"val_metric": "validation score (higher better)", "val_median_m": "validation median error (m)"}[val],
                color="tab:orange",
                fontsize=8,
            )
    for ax in axes.ravel()[len(curves) :]:
        ax.axis("off")
    fig.tight_layout()
    save(fig, path)


# ----------------------------------------------------------------------------- fine runs, styled alike

#: one colour per method (vocabulary.METHODS), the same in every figure and in the map viewer
METHOD_COLOURS = {
    "solver": "#000000",
    "solver-noprior": "#7f7f7f",
    "mlp": "#1f77b4",
    "mlp_att": "#9467bd",
    "gat": "#ff7f0e",
    "gat_att": "#8c564b",
}
#: the methods' names as the paper writes them (its tables' keys); ``solver-noprior`` is the solver
#: without the training split's cameras (config solver.camera_prior off for that run)
METHOD_LABELS = vocabulary.METHOD_SHORT_LABELS
#: the geometric solver's methods: no training, matches per object
SOLVER_METHODS = vocabulary.SOLVER_METHODS
#: colours of external methods (config ``external``, ``flatlandia score``), none of the built-ins', the
#: truth's, the wrong match's or the splits': picked by a hash of the name, so a method keeps its colour
#: in every figure and viewer whatever else is shown (two of many externals may share one)
EXTERNAL_COLOURS = ("#17becf", "#e377c2", "#bcbd22", "#01665e", "#e6ab02")


def is_builtin(method: str) -> bool:
    """One of the benchmark's own methods (else an external one, scored from its poses)."""
    return vocabulary.is_builtin(method)


def method_colour(method: str) -> str:
    """A method's colour: the built-ins' own, an external method's from :data:`EXTERNAL_COLOURS`."""
    if is_builtin(method):
        return METHOD_COLOURS[method]
    return EXTERNAL_COLOURS[zlib.crc32(method.encode()) % len(EXTERNAL_COLOURS)]


def method_label(method: str) -> str:
    """A method's name in the figures: the paper's for the built-ins, an external method's own name."""
    return METHOD_LABELS.get(method, method)


def method_order(methods) -> list[str]:
    """Methods in legend order: the built-ins in :data:`METHOD_COLOURS` order, then the external ones by name."""
    methods = set(methods)
    return [m for m in vocabulary.METHODS if m in methods] + sorted(m for m in methods if not is_builtin(m))


#: one line style per local-map type (matplotlib, and the viewer's SVG dash pattern)
MAP_TYPE_STYLES = {"gt": "-", "depth": "--"}
MAP_TYPE_DASHES = {"gt": "", "depth": "6 3"}
MAP_TYPE_LABELS = vocabulary.MAP_TYPE_LABELS
#: proposal settings in panel order
PROPOSAL_LABELS = {slug: p.figure_label for slug, p in vocabulary.PROPOSALS.items()}
#: the colour of the true pose in the query figures and the viewer
TRUTH_COLOUR = "#00b050"


@dataclass(frozen=True)
class Run:
    """A fine run named ``{method}_{map_type}_{proposal}`` (config fine.runs, or an external method's:
    config ``external``), with its style."""

    name: str
    method: str
    map_type: str
    proposal: str

    @classmethod
    def parse(cls, name: str) -> Run:
        return cls(name, *vocabulary.split_run(name))

    def sort_key(self) -> tuple:
        """Panel order: proposal setting (one unknown here last, by name), method (the built-ins in
        their order, then external methods by name), local-map type."""
        known = list(PROPOSAL_LABELS)
        rank = known.index(self.proposal) if self.proposal in known else len(known)
        builtin = list(vocabulary.METHODS)
        return (
            rank,
            self.proposal,
            builtin.index(self.method) if self.method in builtin else len(builtin),
            "" if self.method in builtin else self.method,
            list(MAP_TYPE_STYLES).index(self.map_type),
        )

    @property
    def setting(self) -> str:
        """The proposal setting in words (its name where this module does not know it)."""
        return PROPOSAL_LABELS.get(self.proposal, self.proposal)

    @property
    def external(self) -> bool:
        """An external method's run (scored from its poses: no matches, no training)."""
        return not is_builtin(self.method)

    @property
    def colour(self) -> str:
        return method_colour(self.method)

    @property
    def short_label(self) -> str:
        """Method and local-map type: the run's name within its proposal setting's panel."""
        return f"{method_label(self.method)}, {MAP_TYPE_LABELS[self.map_type]}"

    @property
    def label(self) -> str:
        return f"{self.short_label}, {self.setting}"


def paper_median(run: Run, strategy: str) -> tuple[float, float] | None:
    """The paper's median error of a run, (its "m" = local-map units x 215, degrees), where it
    publishes one: Table 4 (GT-BB proposals), Table 5 (Sim+Trip coarse proposals, 2N_LM); none
    for an external method."""
    if run.external:
        return None
    model = METHOD_LABELS[run.method]
    if run.proposal == vocabulary.GTBB and (model, run.map_type) in paper.TABLE4:
        return paper.TABLE4[(model, run.map_type)][4:6]
    key = (model, "Sim+Trip", run.map_type)
    if run.proposal == "coarse-simtrip" and "2N_LM" in strategy and key in paper.TABLE5:
        return paper.TABLE5[key]
    return None


def _groups(errors: dict[str, pd.DataFrame]) -> dict[tuple[str, str], list[Run]]:
    """Runs by (proposal setting, local-map type), in panel order: one method per curve of a panel."""
    out = {}
    for run in sorted((Run.parse(name) for name in errors), key=Run.sort_key):
        out.setdefault((run.proposal, run.map_type), []).append(run)
    return out


def _panel_title(run: Run, what: str) -> str:
    return escape.mathtext(f"{run.setting}, {MAP_TYPE_LABELS[run.map_type]}s:\n{what}")


def _style_legend(fig, runs: list[Run], paper_marks: bool) -> None:
    """One legend for the figure: a colour per method, a line style per local-map type."""
    from matplotlib.lines import Line2D

    methods = method_order(r.method for r in runs)
    types = [t for t in MAP_TYPE_STYLES if any(r.map_type == t for r in runs)]
    handles = [Line2D([], [], c=method_colour(m), lw=2, label=escape.mathtext(method_label(m))) for m in methods]
    handles += [Line2D([], [], c="0.3", ls=MAP_TYPE_STYLES[t], lw=1.5, label=MAP_TYPE_LABELS[t]) for t in types]
    if paper_marks:
        handles.append(Line2D([], [], c="0.3", marker="*", ms=10, ls="", label="paper's median (Tables 4, 5)"))
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 0.95), fontsize=9, frameon=False)


def _paper_star(a, b, run: Run, e: pd.DataFrame) -> bool:
    """The paper's median of ``run`` as a star at 0.5 on its position (a) and orientation (b)
    panels; its "m" (local-map units x 215) in true metres with the run's own ratio of the two."""
    med = paper_median(run, str(e["strategy"].iloc[0]) if len(e) else "")
    ok = np.isfinite(e["error_m"]) & (e["error_paper_m"] > 0)
    if med is None or not ok.any():
        return False
    to_m = float(np.median(e.loc[ok, "error_m"] / e.loc[ok, "error_paper_m"]))
    a.plot(med[0] * to_m, 0.5, marker="*", ms=12, c=run.colour, mec="w", ls="", zorder=5)
    b.plot(med[1], 0.5, marker="*", ms=12, c=run.colour, mec="w", ls="", zorder=5)
    return True


def error_cdf_figure(errors: dict[str, pd.DataFrame], max_m: float = 100.0, max_deg: float = 180.0):
    """CDFs of position (m) and orientation (deg) error: a row per proposal setting, for each
    local-map type a position and an orientation panel, a colour per method (so a panel holds at
    most one curve per method), dashed for depth local maps; the paper's medians as stars at 0.5."""
    plt = pyplot()
    groups = _groups(errors)
    proposals = list(dict.fromkeys(p for p, _ in groups))
    types = [t for t in MAP_TYPE_STYLES if any(mt == t for _, mt in groups)]
    fig, axes = plt.subplots(len(proposals), 2 * len(types), figsize=(4.6 * len(types) * 2, 3.4 * len(proposals)))
    axes = np.asarray(axes).reshape(len(proposals), 2 * len(types))
    marked = False
    for (proposal, map_type), runs in groups.items():
        i, j = proposals.index(proposal), 2 * types.index(map_type)
        a, b = axes[i, j], axes[i, j + 1]
        for run in runs:
            e = errors[run.name]
            for ax, column in ((a, "error_m"), (b, "error_deg")):
                x, y = ecdf(e[column])
                style = {"c": run.colour, "ls": MAP_TYPE_STYLES[run.map_type], "lw": 1.5, "where": "post"}
                ax.step(np.r_[0.0, x], np.r_[0.0, y], label=escape.mathtext(run.name), **style)
            marked |= _paper_star(a, b, run, e)
        n = max(len(errors[r.name]) for r in runs)
        for ax, lim, unit in ((a, max_m, "position error (m)"), (b, max_deg, "orientation error (deg)")):
            ax.set_xscale("symlog", linthresh=1.0)
            ax.set_xlim(-0.1, lim)  # a curve at zero error stays off the axis
            ax.set_ylim(0, 1)
            ax.set_xlabel(unit)
            ax.set_ylabel("share of test queries")
            ax.set_title(_panel_title(runs[0], f"{unit.split(' (')[0]}, {n} queries"), fontsize=9)
            ax.grid(alpha=0.3)
    for ax in axes.ravel():
        if not ax.has_data():
            ax.axis("off")
    _style_legend(fig, [r for g in groups.values() for r in g], marked)
    fig.suptitle("Fine localization on the test split: error CDFs (higher and further left is better)", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.45 / fig.get_figheight()))
    return fig


def plot_error_cdfs(errors: dict[str, pd.DataFrame], path: str | Path) -> None:
    save(error_cdf_figure(errors), path)


def errors_by(errors: pd.DataFrame, column: str) -> pd.DataFrame:
    """Median position / orientation error and query count per value of ``column``."""
    g = errors.groupby(column)
    return pd.DataFrame(
        {"queries": g.size(), "median_m": g["error_m"].median(), "median_deg": g["error_deg"].median()}
    ).reset_index()


#: the columns of the error-vs-content figure: (count column, its axis name, median column, its axis name)
CONTENT_PANELS = [
    ("n_objects", "objects in the local map", "median_m", "median position error (m)"),
    ("n_classes", "distinct classes", "median_m", "median position error (m)"),
    ("n_objects", "objects in the local map", "median_deg", "median orientation error (deg)"),
    ("n_classes", "distinct classes", "median_deg", "median orientation error (deg)"),
]


def error_vs_objects_figure(errors: dict[str, pd.DataFrame], min_queries: int = 3):
    """The paper's Fig. 8: median error against the number of objects and of distinct classes. A row
    per proposal setting, in the CDF figure's order; GT and depth local maps in the same panel (solid
    and dashed, as the CDFs), a colour per method; counts on integer axes. Why this layout: a row per
    (setting, map type) made 8 rows of small panels whose text could not be read at the saved size."""
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    groups = _groups(errors)
    proposals = list(dict.fromkeys(p for p, _ in groups))  # the CDF figure's rows
    fig, axes = plt.subplots(len(proposals), 4, figsize=(17, 3.7 * len(proposals)), squeeze=False)
    for (proposal, _), runs in groups.items():
        row = axes[proposals.index(proposal)]
        for run in runs:
            for ax, (col, _, med, _) in zip(row, CONTENT_PANELS):
                if col not in errors[run.name]:
                    continue
                t = errors_by(errors[run.name], col)
                t = t[t["queries"] >= min_queries]
                ax.plot(t[col], t[med], marker="o", ms=3.5, lw=1.5, c=run.colour, ls=MAP_TYPE_STYLES[run.map_type])
    for proposal, row in zip(proposals, axes):
        setting = PROPOSAL_LABELS.get(proposal, proposal)
        for ax, (_, xl, _, yl) in zip(row, CONTENT_PANELS):
            ax.set_xlabel(xl, fontsize=10)
            ax.set_ylabel(yl, fontsize=10)
            ax.tick_params(labelsize=9)
            _error_axis(ax)
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            ax.set_title(f"{setting}:\n{yl.split(' (')[0]}", fontsize=10)
            ax.grid(alpha=0.3)
    _style_legend(fig, [r for g in groups.values() for r in g], False)
    fig.suptitle(
        f"Median error vs local-map content, test split (values shared by >= {min_queries} queries)", fontsize=12
    )
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.5 / fig.get_figheight()))  # the title above the first row's titles
    return fig


def _error_axis(ax) -> None:
    """A log-like error axis (symlog: zero errors stay visible) where the values span a decade or
    more; a linear one where they do not, so that every panel keeps labelled ticks."""
    ys = np.concatenate([np.asarray(line.get_ydata(), float) for line in ax.get_lines()] + [np.zeros(0)])
    ys = ys[np.isfinite(ys)]
    if len(ys) and ys.min() > 0 and ys.max() / ys.min() < 10:
        ax.set_ylim(0, ys.max() * 1.1)
        return
    ax.set_yscale("symlog", linthresh=1.0)


def plot_error_vs_objects(errors: dict[str, pd.DataFrame], path: str | Path) -> None:
    save(error_vs_objects_figure(errors), path)


def plot_score_heatmap(
    ref: pd.DataFrame,
    scores: dict[str, np.ndarray],
    positives: np.ndarray,
    cam_xy: np.ndarray,
    theta_deg: float,
    path: str | Path,
    title: str,
) -> None:
    """Coarse scores of one query over its scene's reference map (darker = more likely seen).

    Scores are distances in embedding space (lower = better), shown as rank percentiles so the
    models are comparable; the query's true objects are ringed and its camera drawn.
    """
    plt = pyplot()
    n = len(scores)
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 4.4), squeeze=False)
    xy = ref[["x_m", "y_m"]].to_numpy(float)
    for ax, (label, s) in zip(axes[0], scores.items()):
        rank = np.argsort(np.argsort(np.asarray(s, float))) / max(len(s) - 1, 1)
        sc = ax.scatter(xy[:, 0], xy[:, 1], c=1 - rank, cmap="magma_r", s=22, vmin=0, vmax=1)
        ax.scatter(
            xy[positives, 0],
            xy[positives, 1],
            s=90,
            facecolors="none",
            edgecolors="tab:green",
            lw=1.2,
            label="seen by the query",
        )
        ax.plot(*cam_xy, marker="^", c="tab:blue", ms=8, label="camera")
        d = np.array([np.cos(np.radians(theta_deg)), np.sin(np.radians(theta_deg))]) * 15
        ax.annotate("", xy=cam_xy + d, xytext=cam_xy, arrowprops={"arrowstyle": "->", "color": "tab:blue"})
        ax.set_aspect("equal")
        ax.set_title(escape.mathtext(label), fontsize=9)
        ax.set_xlabel("x east (m)")
        ax.set_ylabel("y north (m)")
        fig.colorbar(sc, ax=ax, shrink=0.7, label="score rank (1 = best)")
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle(escape.mathtext(title), fontsize=10)  # names a scene and a token: '$' would start mathtext
    fig.tight_layout()
    save(fig, path)
