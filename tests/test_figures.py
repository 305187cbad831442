"""The fine-error figures as a reader sees them: a panel per proposal setting, every curve told
apart by colour (method) and line style (local-map type), the paper's medians marked, counts on
integer axes. Built on the default config's runs, with synthetic errors (no training)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml
from matplotlib.colors import to_hex
from PIL import Image

from flatlandia import paper
from flatlandia.report import figures
from flatlandia.report.figures import MAP_TYPE_LABELS, METHOD_COLOURS, METHOD_LABELS, PROPOSAL_LABELS, Run


def default_runs(repo) -> list[str]:
    runs = yaml.safe_load((repo / "config" / "config.yaml").read_text())["fine"]["runs"]
    grid = [f"{m}_{t}_{p}" for m in runs["methods"] for t in runs["map_types"] for p in runs["proposals"]]
    return grid + [r for r in runs["extra"] if r not in grid]


@pytest.fixture(scope="module")
def errors(repo) -> dict[str, pd.DataFrame]:
    """Per run 40 test queries with errors that grow with the method's rank and fall with the
    number of objects; a few queries without a pose."""
    rng = np.random.default_rng(0)
    out = {}
    for k, name in enumerate(default_runs(repo)):
        run = Run.parse(name)
        n_obj = rng.integers(3, 9, 40)
        error_m = rng.lognormal(np.log(1 + k), 0.8, 40) * 6 / n_obj
        error_m[:2] = np.inf
        out[name] = pd.DataFrame(
            {
                "scene": "0",
                "token": [f"q{i}" for i in range(40)],
                "strategy": "Sim+Trip 2N_LM" if run.proposal.startswith("coarse") else PROPOSAL_LABELS[run.proposal],
                "n_objects": n_obj,
                "n_classes": np.minimum(n_obj, rng.integers(1, 5, 40)),
                "error_m": error_m,
                "error_deg": np.where(np.isfinite(error_m), rng.uniform(0, 40, 40), 180.0),
                "error_paper_m": error_m * 1.4,
            }
        )
    return out


def _curves(ax):
    """The error curves of a panel: lines with data, not the paper's star markers."""
    return [ln for ln in ax.get_lines() if ln.get_marker() != "*" and len(ln.get_xdata())]


def _panel_runs(ax) -> list[Run]:
    return [Run.parse(ln.get_label()) for ln in _curves(ax)]


def test_the_default_runs_get_a_panel_per_setting_with_a_curve_per_method(errors):
    fig = figures.error_cdf_figure(errors)
    groups = {(Run.parse(r).proposal, Run.parse(r).map_type) for r in errors}
    proposals = sorted({p for p, _ in groups}, key=list(PROPOSAL_LABELS).index)
    assert (
        len(fig.axes) == 4 * len(proposals) == 16
    )  # a row per proposal (GT-BB, Sim+Trip, Solver, whole map): GT and depth, position and orientation
    seen = set()
    for k, ax in enumerate(fig.axes):
        runs = _panel_runs(ax)
        assert 1 <= len(runs) <= 5, ax.get_title()
        ((proposal, map_type),) = {(r.proposal, r.map_type) for r in runs}
        assert proposal == proposals[k // 4] and map_type == ("gt", "depth")[(k % 4) // 2]
        assert ax.get_title().startswith(f"{PROPOSAL_LABELS[proposal]}, {MAP_TYPE_LABELS[map_type]}")
        assert ax.get_xlabel() == ("position error (m)", "orientation error (deg)")[k % 2]
        for ln, r in zip(_curves(ax), runs):  # colour = method, line style = local-map type
            assert to_hex(ln.get_color()) == METHOD_COLOURS[r.method]
            assert ln.get_linestyle() == {"gt": "-", "depth": "--"}[r.map_type]
        assert len({r.method for r in runs}) == len(runs)
        seen |= {r.name for r in runs}
    assert seen == set(errors)  # every run is drawn
    assert len(set(METHOD_COLOURS.values())) == len(METHOD_COLOURS)
    (legend,) = fig.legends
    texts = [t.get_text() for t in legend.get_texts()]
    used = {Run.parse(r).method for r in errors}
    assert {METHOD_LABELS[m] for m in used} | set(MAP_TYPE_LABELS.values()) <= set(texts), texts
    assert any("paper" in t for t in texts)


def test_the_papers_medians_are_marked_where_it_publishes_them(errors):
    fig = figures.error_cdf_figure(errors)
    stars = [(ax, ln) for ax in fig.axes for ln in ax.get_lines() if ln.get_marker() == "*"]
    assert stars and all(ln.get_ydata()[0] == 0.5 for _, ln in stars)
    gtbb_depth_pos, gtbb_depth_deg = fig.axes[2], fig.axes[3]
    want = {paper.TABLE4[(METHOD_LABELS[m], "depth")][5] for m in ("mlp", "mlp_att", "gat", "gat_att")}
    assert want == {float(ln.get_xdata()[0]) for ax, ln in stars if ax is gtbb_depth_deg}
    # the paper's "m" are local-map units x 215: in true metres with the run's own ratio (1 / 1.4 here)
    pos = {float(ln.get_xdata()[0]) for ax, ln in stars if ax is gtbb_depth_pos}
    assert any(np.isclose(x, paper.TABLE4[("MLP", "depth")][4] / 1.4) for x in pos), pos
    coarse_deg = {float(ln.get_xdata()[0]) for ax, ln in stars if ax is fig.axes[7]}
    assert coarse_deg == {paper.TABLE5[("MLP", "Sim+Trip", "depth")][1]}
    assert not [ln for _, ln in stars if to_hex(ln.get_color()) == METHOD_COLOURS["solver"]]  # no paper value


def test_error_vs_objects_has_integer_count_axes_and_a_row_per_setting(errors):
    """Fig. 8: a row per proposal setting in the CDF figure's order (4 rows of 4 panels, not 8), both
    local-map types in one panel (a colour per method, a line style per map type), text at 9-10 pt."""
    fig = figures.error_vs_objects_figure(errors)
    cdf = figures.error_cdf_figure(errors)
    proposals = list(dict.fromkeys(Run.parse(ln.get_label()).proposal for ax in cdf.axes for ln in _curves(ax)))
    assert len(fig.axes) == 4 * len(proposals) == 16
    fig.canvas.draw()
    for k, ax in enumerate(fig.axes):
        assert ax.get_title().startswith(PROPOSAL_LABELS[proposals[k // 4]] + ":"), (k, ax.get_title())
        lo, hi = ax.get_xlim()
        ticks = [t for t in ax.get_xticks() if lo <= t <= hi]
        assert ticks and all(float(t).is_integer() for t in ticks), (ax.get_xlabel(), ticks)
        assert ax.get_xlabel() in ("objects in the local map", "distinct classes")
        assert ax.xaxis.label.get_size() >= 10 and ax.title.get_size() >= 10
        assert all(t.get_size() >= 9 for t in ax.get_xticklabels() + ax.get_yticklabels())
        styles = [(to_hex(ln.get_color()), ln.get_linestyle()) for ln in ax.get_lines()]
        assert 1 <= len(styles) <= 10 and len(set(styles)) == len(styles)
        assert {ls for _, ls in styles} <= {"-", "--"}
    assert {ln.get_linestyle() for ax in fig.axes for ln in ax.get_lines()} == {"-", "--"}
    assert len(fig.legends) == 1


def test_the_figures_are_written_as_pngs(errors, tmp_path):
    figures.plot_error_cdfs(errors, tmp_path / "cdf.png")
    figures.plot_error_vs_objects(errors, tmp_path / "vs.png")
    for name, rows in (("cdf.png", 3), ("vs.png", 3)):
        with Image.open(tmp_path / name) as im:
            w, h = im.size
            assert im.format == "PNG" and w > 900 and h > 200 * rows, (name, im.size)


def test_a_proposal_setting_unknown_here_gets_a_row_of_its_own_last(errors):
    more = {**errors, "solver_depth_coarse-new": errors["solver_depth_gtbb"]}
    fig = figures.error_cdf_figure(more)
    assert len(fig.axes) == 20  # the 4 default settings, then the new one
    assert fig.axes[-2].get_title().startswith("coarse-new, depth local maps")
    assert not fig.axes[-4].has_data()  # no GT-map run on it: that panel is left blank
