"""No text over text in any figure the workflow draws, at its saved size: every figure type drawn on
the tiny scene (training curves, error CDFs, error vs content, the coarse heat map, a query figure,
the worst-queries gallery, the reference map, the reproduction audit, the SfM summary, the answers' risk-coverage and reliability) is saved as
its rule saves it, and no two of its visible text boxes overlap (matplotlib's renderer extents, at
the saved dpi). Fast lane: no published data."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from conftest import TINY_SCENE
from tiny_results import tiny_scene

from flatlandia import config
from flatlandia.benchmark import solver_runs
from flatlandia.data import reference_map
from flatlandia.report import figures
from flatlandia.viewer import query_figures, scene_view

#: pixels two boxes may share (antialiasing, a glyph's bearing): less than a stroke
TOLERANCE_PX = 1.0
#: a title keeps at least this many pixels from any other text: the worst-queries gallery had its
#: top row's x labels 2-4 px above the next row's titles, which read as one line (issue 36)
TITLE_CLEARANCE_PX = 6.0


def _drawn_tick_labels(fig) -> tuple[set[int], list]:
    """(ids of every tick label Text, the tick labels matplotlib draws: those of ticks inside the
    axis's view; the others exist as Text objects but are never drawn)."""
    every, drawn = set(), []
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            span = (hi - lo) or 1.0
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                labels = (tick.label1, tick.label2)
                every |= {id(t) for t in labels}
                if ax.get_visible() and lo - 1e-9 * span <= tick.get_loc() <= hi + 1e-9 * span:
                    drawn += [t for t in labels if t.get_visible() and t.get_text().strip()]
    return every, drawn


def _texts(fig):
    """The texts a figure draws, non-empty: titles, labels, the tick labels in view, legends, annotations."""
    from matplotlib.text import Text

    ticks, out = _drawn_tick_labels(fig)
    for t in fig.findobj(Text):
        if id(t) in ticks or not t.get_visible() or not t.get_text().strip() or t.get_alpha() == 0:
            continue
        ax = t.axes
        if ax is not None and not ax.get_visible():
            continue
        out.append(t)
    return out


def _titles(fig) -> set[int]:
    """ids of the figure's title and its axes' titles."""
    out = {id(t) for ax in fig.axes for t in (ax.title, ax._left_title, ax._right_title)}
    return out | ({id(fig._suptitle)} if fig._suptitle is not None else set())


def overlapping_texts(fig, renderer) -> list[tuple[str, str]]:
    """Pairs of texts whose boxes overlap (a title: that come within TITLE_CLEARANCE_PX of it), as
    ``renderer`` draws the figure (call it while the figure is drawn for its file: a draw_event, at
    the saved dpi and layout)."""
    titles = _titles(fig)
    boxes = []
    for t in _texts(fig):
        try:
            bb = t.get_window_extent(renderer)
        except RuntimeError:
            continue
        if bb.width > 0 and bb.height > 0 and np.isfinite([bb.x0, bb.y0, bb.x1, bb.y1]).all():
            boxes.append((t, bb))
    hits = []
    for (a, ba), (b, bb) in itertools.combinations(boxes, 2):
        margin = TITLE_CLEARANCE_PX if id(a) in titles or id(b) in titles else -TOLERANCE_PX
        if ba.padded(margin / 2).overlaps(bb.padded(margin / 2)):
            hits.append((a.get_text()[:60], b.get_text()[:60]))
    return hits


@pytest.fixture
def saved(monkeypatch):
    """Every figure saved while the test runs: its file name and its overlapping texts, checked right
    after matplotlib drew it for the file."""
    from matplotlib.figure import Figure

    out = {}
    original = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        drawn = []  # the texts' boxes of each draw: the last is the file's (a tight box draws twice)
        cid = self.canvas.mpl_connect("draw_event", lambda e: drawn.append(overlapping_texts(self, e.renderer)))
        try:
            original(self, fname, *args, **kwargs)
        finally:
            self.canvas.mpl_disconnect(cid)
        out[str(fname)] = drawn[-1]  # keyed by the atomic writers' temporary name, beside the file

    monkeypatch.setattr(Figure, "savefig", savefig)
    return out


@pytest.fixture(scope="module")
def tiny():
    """The tiny scene's reference map and queries, and the solver's runs on its train split (both
    map types, GT-BB and the whole map) as rule fine_eval's errors tables."""
    tiny = tiny_scene()
    ref, meta, q = tiny.ref, tiny.meta, tiny.queries
    errors = {}
    settings = config.section_defaults("solver")
    for map_type in ("gt", "depth"):
        for proposal in ("gtbb", "whole"):
            e = solver_runs.solver_errors([(ref, q)], map_type, proposal, settings, split="train")
            e["strategy"] = {"gtbb": "GT-BB", "whole": "whole map"}[proposal]
            errors[f"solver_{map_type}_{proposal}"] = e
            # a second method, so that panels hold several curves (the MLP's poses: the solver's, moved)
            errors[f"mlp_{map_type}_{proposal}"] = e.assign(
                x=e["x"] + 3.0, error_m=e["error_m"] + 3.0, error_deg=e["error_deg"] * 2 + 1, method="MLP"
            )
    q = q.assign(split=q["split"].replace({"train": "test"}))  # the figures draw test queries: ten of them
    return ref, meta, q, errors


def _check(saved: dict) -> None:
    assert saved, "no figure was saved"
    bad = {name: hits for name, hits in saved.items() if hits}
    assert not bad, bad


def test_fine_figures(tiny, saved, tmp_path):
    _, _, _, errors = tiny
    figures.plot_error_cdfs(errors, tmp_path / "fine_error_cdf.png")
    figures.plot_error_vs_objects(errors, tmp_path / "fine_error_vs_objects.png")
    _check(saved)


def test_query_figures_and_the_worst_queries(tiny, saved, tmp_path):
    ref, _, q, errors = tiny
    view = scene_view.scene_view(TINY_SCENE, ref, q, errors)
    written = query_figures.write_query_figures(view, tmp_path / "figures")
    assert len(written) >= 6
    figures.save(query_figures.worst_figure(view), tmp_path / "worst_queries.png")
    # galleries of one and of two queries (a scene with few test queries): narrower than the legend
    for k in (1, 2):
        few = scene_view.scene_view(TINY_SCENE, ref, q.assign(split=["test"] * k + ["train"] * (len(q) - k)), errors)
        figures.save(query_figures.worst_figure(few), tmp_path / f"worst_{k}.png")
    _check(saved)


def test_training_curves_and_heat_map(tiny, saved, tmp_path):
    ref, _, q, _ = tiny
    rng = np.random.default_rng(0)
    epochs = np.arange(1, 41)
    curves = {
        label: pd.DataFrame({"epoch": epochs, "train_loss": 1 / epochs, val: np.linspace(0.2, 0.8, 40)})
        for label, val in (
            ("coarse Sim", "val_metric"),
            ("coarse Trip", "val_metric"),
            ("coarse Sim+Trip", "val_metric"),
            ("fine MLP, depth", "val_median_m"),
            ("fine GAT+ATT, depth, coarse proposals", "val_median_m"),
        )
    }
    figures.plot_training_curves(curves, tmp_path / "training_curves.png")
    r = q.iloc[0]
    scores = {name: rng.normal(size=len(ref)) for name in ("Sim", "Trip", "Sim+Trip")}
    positives = np.isin(ref["obj_idx"], r["ref_idx"])
    figures.plot_score_heatmap(
        ref,
        scores,
        positives,
        np.array([r["x_m"], r["y_m"]]),
        r["theta_deg"],
        tmp_path / "heat.png",
        f"scene {TINY_SCENE}, query {r['token']}: coarse scores",
    )
    _check(saved)


def test_map_audit_and_sfm_figures(tiny, saved, tmp_path):
    from flatlandia.images import sfm
    from flatlandia.objects import audit

    ref, meta, q, _ = tiny
    reference_map.plot_reference_map(
        ref, q, tmp_path / "reference_map.png", f"scene {TINY_SCENE}: {len(ref)} objects, {len(q)} queries"
    )
    xy = ref[["x_m", "y_m"]].to_numpy(float)
    audit.plot_audit_grid([(f"scene {s}", xy + 0.2, xy) for s in range(6)], tmp_path / "audit_grid.png")
    rng = np.random.default_rng(1)
    cams = pd.DataFrame(
        {
            "name": [f"{k:02d}.jpg" for k in range(12)],
            "x": np.arange(12.0),
            "y": rng.normal(0, 0.3, 12),
            "z": rng.normal(0, 0.1, 12),
            "lon": 11.0 + np.arange(12) * 1e-5,
            "lat": 48.0 + rng.normal(0, 1e-6, 12),
            "heading": np.full(12, 90.0),
        }
    )
    stats = pd.Series({"registered": 12, "images_input": 12, "mean_reprojection_error_px": 0.63})
    points = rng.normal(size=(300, 3)) * [6, 2, 1]
    sfm.plot_summary(cams, points, stats, tmp_path / "sfm.png", "scene lund: SfM")
    for name, alignment in _alignments(cams).items():
        sfm.plot_summary(cams, points, stats, tmp_path / f"sfm_{name}.png", "scene lund: SfM", alignment=alignment)
    sfm.plot_summary(cams.assign(lat=np.nan, lon=np.nan), points, stats, tmp_path / "no_gps.png", "scene lund: SfM")
    _check(saved)


def _alignments(cams: pd.DataFrame) -> dict[str, dict]:
    """Alignment records (as rule gps_alignment writes them) of the cameras of
    test_map_audit_and_sfm_figures: to the GPS fixes (the SfM frame turned 90 degrees, 2 m per unit)
    and a local frame without GPS."""
    from flatlandia import geo

    lonlat = cams[["lon", "lat"]].to_numpy(float)
    frame = geo.frame_for(lonlat)
    A = 2.0 * np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    xyz = cams[["x", "y", "z"]].to_numpy(float)
    b = (frame.to_xy(lonlat) - xyz @ A.T).mean(axis=0)
    gps = {"mode": "gps", "A": A.tolist(), "b": b.tolist(), "frame_lon0": frame.lon0, "frame_lat0": frame.lat0}
    local = {"mode": "none", "A": np.eye(2, 3).tolist(), "b": [0.0, 0.0], "unit": "SfM unit"}
    return {"gps": gps, "local": local}


def _drawn(monkeypatch) -> list:
    """The figures the code draws, kept when it closes them."""
    plt = figures.pyplot()
    kept, close = [], plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig) or close(fig))
    return kept


def test_the_sfm_figure_draws_the_model_on_the_map_when_it_is_aligned(tmp_path, monkeypatch):
    """sfm_summary.png's left panel was the cameras' best-fit plane in SfM units, rotated against the
    map (issue 45): with the scene's GPS alignment it is the map's frame, east and north in metres,
    beside the GPS track in the same frame; without GPS the axes say it is the SfM frame."""
    from flatlandia import geo
    from flatlandia.images import sfm

    rng = np.random.default_rng(1)
    cams = pd.DataFrame(
        {
            "name": [f"{k:02d}.jpg" for k in range(12)],
            "x": np.arange(12.0),
            "y": rng.normal(0, 0.3, 12),
            "z": rng.normal(0, 0.1, 12),
            "lon": 11.0 + np.arange(12) * 1e-5,
            "lat": 48.0 + rng.normal(0, 1e-6, 12),
            "heading": np.full(12, 90.0),
        }
    )
    stats = pd.Series({"registered": 12, "images_input": 12, "mean_reprojection_error_px": 0.63})
    kept = _drawn(monkeypatch)
    alignments = _alignments(cams)
    for name, alignment in alignments.items():
        sfm.plot_summary(cams, rng.normal(size=(30, 3)), stats, tmp_path / f"{name}.png", "scene", alignment=alignment)
    sfm.plot_summary(cams, rng.normal(size=(30, 3)), stats, tmp_path / "none.png", "scene")
    (model, track), (local, _), (unaligned, _) = (fig.axes for fig in kept)
    assert (model.get_xlabel(), model.get_ylabel()) == ("x east (m)", "y north (m)")
    drawn = np.column_stack(model.get_lines()[0].get_data())
    assert np.allclose(drawn, geo.alignment_points(alignments["gps"], cams[["x", "y", "z"]].to_numpy(float)))
    assert np.ptp(drawn[:, 1]) > 3 * np.ptp(drawn[:, 0])  # the walk east in SfM runs north on the map
    assert "SfM unit" not in model.get_title() + model.get_xlabel() + model.get_ylabel()
    assert track.get_xlim() == model.get_xlim() and track.get_ylim() == model.get_ylim()  # one frame, one view
    assert "SfM frame" in local.get_xlabel() and "SfM frame" in local.get_ylabel()
    assert "SfM frame" in unaligned.get_xlabel() and "SfM units" in unaligned.get_xlabel()


def test_an_empty_map_says_no_objects(tmp_path, monkeypatch, saved):
    """An images scene with the default segmentation ends with a map of 0 objects: its figure was blank
    axes, and matplotlib warned "No artists with labels found to put in legend" (issue 45)."""
    import warnings

    kept = _drawn(monkeypatch)
    ref = tiny_scene().ref.iloc[:0]
    queries = tiny_scene().queries.iloc[:0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reference_map.plot_reference_map(
            ref, queries, tmp_path / "empty.png", "scene mine (Lund): 0 objects, 0 queries", empty_because="why it is"
        )
    (fig,) = kept
    texts = [t.get_text() for t in _texts(fig)]
    assert "no objects" in texts and "why it is" in texts, texts
    assert not any(ax.axison for ax in fig.axes) and fig.axes[0].get_legend() is None
    assert (tmp_path / "empty.png").stat().st_size > 0
    _check(saved)


def test_the_check_finds_text_over_text(saved, tmp_path):
    """The check itself: two labels written over each other are found."""
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(3, 3))
    ax.text(0.5, 0.5, "one label", transform=ax.transAxes)
    ax.text(0.52, 0.5, "another label", transform=ax.transAxes)
    figures.save(fig, tmp_path / "bad.png")
    ((name, hits),) = saved.items()
    assert "bad.png" in name and [set(h) for h in hits] == [{"one label", "another label"}]


def test_the_answers_risk_coverage_and_reliability_figures(saved, tmp_path):
    """Rule beyond_table's figures of the answers' probability, with the three maps at 1 and 5 frames
    (the legend's six entries over the lines' start)."""
    from flatlandia.sequences import sequence_figures

    rng = np.random.default_rng(1)
    rows = []
    for m in ("scene", "city-20", "simulated-100000"):
        for k in (1, 5):
            p = rng.random(200)
            right = rng.random(200) < p
            rows.append(
                pd.DataFrame(
                    {
                        "map": m,
                        "frames": k,
                        "gps_sigma_m": np.nan,
                        "camera_prior": "on",
                        "probability": p,
                        "error_m": np.where(right, 1.0, 900.0),
                        "error_deg": np.where(right, 1.0, 40.0),
                    }
                )
            )
    errors = pd.concat(rows, ignore_index=True)
    sequence_figures.plot_risk_coverage(errors, 0.7, tmp_path / "risk_coverage.png")
    sequence_figures.plot_reliability(errors, tmp_path / "reliability.png")
    _check(saved)
