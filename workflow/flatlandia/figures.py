"""Report figures: training curves, error distributions (CDFs, the paper's Fig. 8), coarse-score heat maps.

Pure plotting from the run's tables; each function writes one PNG atomically (matplotlib Agg).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia.io import atomic_path


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display on cluster nodes); imported on first use
    so that rules without figures do not pay for it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
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
        ax.set_title(label, fontsize=9)
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
    _save(fig, path)


def plot_error_cdfs(
    errors: dict[str, pd.DataFrame], path: str | Path, max_m: float = 100.0, max_deg: float = 180.0
) -> None:
    """CDF of position (m) and orientation (deg) error per run; failures never reach the top."""
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for label, e in errors.items():
        x, y = ecdf(e["error_m"])
        a.step(x, y, where="post", lw=1.2, label=label)
        x, y = ecdf(e["error_deg"])
        b.step(x, y, where="post", lw=1.2, label=label)
    for ax, lim, unit in ((a, max_m, "position error (m)"), (b, max_deg, "orientation error (deg)")):
        ax.set_xscale("symlog", linthresh=1.0)
        ax.set_xlim(0, lim)
        ax.set_ylim(0, 1)
        ax.set_xlabel(unit)
        ax.set_ylabel("share of test queries")
        ax.grid(alpha=0.3)
    a.legend(fontsize=7, loc="lower right")
    fig.suptitle("Fine localization: error CDFs on the test split", fontsize=10)
    fig.tight_layout()
    _save(fig, path)


def errors_by(errors: pd.DataFrame, column: str) -> pd.DataFrame:
    """Median position / orientation error and query count per value of ``column``."""
    g = errors.groupby(column)
    return pd.DataFrame(
        {"queries": g.size(), "median_m": g["error_m"].median(), "median_deg": g["error_deg"].median()}
    ).reset_index()


def plot_error_vs_objects(errors: dict[str, pd.DataFrame], path: str | Path) -> None:
    """The paper's Fig. 8: median error against the number of objects and of distinct classes."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for label, e in errors.items():
        for col, (ax_m, ax_d) in (("n_objects", axes[:, 0]), ("n_classes", axes[:, 1])):
            if col not in e:
                continue
            t = errors_by(e, col)
            t = t[t["queries"] >= 3]
            ax_m.plot(t[col], t["median_m"], "-o", ms=3, lw=1, label=label)
            ax_d.plot(t[col], t["median_deg"], "-o", ms=3, lw=1, label=label)
    for ax, (xl, yl) in zip(
        axes.ravel(),
        [
            ("objects in the local map", "median position error (m)"),
            ("distinct classes", "median position error (m)"),
            ("objects in the local map", "median orientation error (deg)"),
            ("distinct classes", "median orientation error (deg)"),
        ],
    ):
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_yscale("symlog", linthresh=1.0)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Error vs local-map content (values with >= 3 queries), test split", fontsize=10)
    fig.tight_layout()
    _save(fig, path)


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
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("x east (m)")
        ax.set_ylabel("y north (m)")
        fig.colorbar(sc, ax=ax, shrink=0.7, label="score rank (1 = best)")
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)
