"""The figures of the answers' probability (docs/results.md, "Knowing when it is right"), drawn by
rule beyond_table from the same rows as its table.

- risk-coverage: answering the surest anchors first, the share answered against the share of the
  answered that are wrong (not within (5 m, 5 deg); and, in a city, in the wrong scene), one line
  per map and frame count (1 and 5 frames, no fix, the camera prior on), the default threshold
  (``solver.answer_probability``) marked;
- reliability diagram: the anchors binned by probability (10 bins), the share within (5 m, 5 deg)
  against the bin's mean probability, per map and frame count, with each curve's expected
  calibration error.

Each ``*_figure`` returns the figure (tests read its axes), each ``plot_*`` writes one PNG.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia.benchmark.metrics import WITHIN, WRONG_SCENE_M
from flatlandia.plumbing import escape
from flatlandia.report import figures
from flatlandia.solver import calibration

#: the frame counts drawn
FRAMES = (1, 5)
#: line style per frame count, colour per map kind
STYLE = {1: "-", 5: "--"}
COLOURS = {"scene": "tab:blue", "city": "tab:orange", "simulated": "tab:red"}


def curves(errors: pd.DataFrame) -> dict[tuple[str, int], pd.DataFrame]:
    """(map, frames) -> its anchors without a fix and with the camera prior on, at :data:`FRAMES`,
    with a probability."""
    if errors.empty or "probability" not in errors:
        return {}
    e = errors[errors["gps_sigma_m"].isna() & (errors["camera_prior"] == "on") & errors["frames"].isin(FRAMES)]
    e = e[np.isfinite(e["probability"].to_numpy(float))]
    order = {k: i for i, k in enumerate(COLOURS)}
    keys = sorted(
        {(str(m), int(k)) for m, k in zip(e["map"], e["frames"])},
        key=lambda mk: (order.get(mk[0].split("-")[0], 9), mk[0], mk[1]),
    )
    return {(m, k): e[(e["map"] == m) & (e["frames"] == k)] for m, k in keys}


def _flags(e: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    em, ed = e["error_m"].to_numpy(float), e["error_deg"].to_numpy(float)
    within = (em < WITHIN[0]) & (ed < WITHIN[1])
    return e["probability"].to_numpy(float), within, np.isfinite(em) & (em > WRONG_SCENE_M)


def _label(m: str, k: int) -> str:
    return escape.mathtext(f"{m}, {k} frame" + ("s" if k > 1 else ""))


def risk_coverage_figure(errors: pd.DataFrame, threshold: float):
    """Two panels: % of the answered not within (5 m, 5 deg), and % in the wrong scene (only with a
    city among the maps: a scene map has no other scene), against % answered; the point at
    ``threshold`` marked on each line."""
    plt = figures.pyplot()
    drawn = curves(errors)
    cities = any(not m.startswith("scene") for m, _ in drawn)
    fig, axes = plt.subplots(1, 2 if cities else 1, figsize=(11, 4.2) if cities else (6, 4.2), squeeze=False)
    axes = axes[0]
    for (m, k), e in drawn.items():
        p, within, wrong = _flags(e)
        colour = COLOURS.get(m.split("-")[0], "tab:grey")
        at = int((p >= threshold).sum())
        for ax, bad in zip(axes, (~within, wrong)):
            cov, risk = calibration.risk_coverage(p, bad)
            ax.plot(cov, risk, STYLE.get(k, ":"), color=colour, label=_label(m, k))
            if at:
                ax.plot(cov[at - 1], risk[at - 1], "o", color=colour, ms=5)
    for ax, title in zip(axes, ("not within (5 m, 5°)", "in the wrong scene (> 500 m off)")):
        ax.set_xlabel("% answered (surest first)")
        ax.set_ylabel(f"% of the answered {title}")
        ax.set_xlim(0, 100)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    axes[0].set_title(escape.mathtext(f"Risk against coverage (dots: answered at probability >= {threshold:g})"))
    if cities:
        axes[1].set_title("Wrong scene against coverage")
    if axes[0].lines:
        axes[0].legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    return fig


def reliability_figure(errors: pd.DataFrame, bins: int = 10):
    """The share within (5 m, 5 deg) against the mean probability of each of ``bins`` bins, per map
    and frame count (marker size: the bin's anchors), the diagonal, each curve's ECE in its label."""
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.plot([0, 1], [0, 1], color="0.6", lw=1)
    for (m, k), e in curves(errors).items():
        p, within, _ = _flags(e)
        b = np.minimum((p * bins).astype(int), bins - 1)
        xs, ys, ns = [], [], []
        for j in range(bins):
            sel = b == j
            if sel.any():
                xs.append(p[sel].mean())
                ys.append(within[sel].mean())
                ns.append(sel.sum())
        ece = calibration.expected_calibration_error(p, within, bins)
        colour = COLOURS.get(m.split("-")[0], "tab:grey")
        ax.plot(xs, ys, STYLE.get(k, ":"), color=colour, label=escape.mathtext(f"{m}, {k} fr. (ECE {ece:.1f})"))
        ax.scatter(xs, ys, s=8 + 2 * np.sqrt(np.asarray(ns, float)) * 4, color=colour, alpha=0.6)
    ax.set_xlabel("probability of being within (5 m, 5°)")
    ax.set_ylabel("share within (5 m, 5°)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.set_title("Reliability of the answers' probability")
    if len(ax.lines) > 1:
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return fig


def plot_risk_coverage(errors: pd.DataFrame, threshold: float, path: str | Path) -> None:
    figures.save(risk_coverage_figure(errors, threshold), path)


def plot_reliability(errors: pd.DataFrame, path: str | Path) -> None:
    figures.save(reliability_figure(errors), path)
