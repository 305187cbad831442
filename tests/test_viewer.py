"""The query figures and the map viewer, checked as a person sees them: the true pose lands on
its objects, the worst queries come first, and in a real headless browser (Debian's Chromium) a
click on a test query draws its local map at the true and estimated poses with the errors."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import to_hex, to_rgb
from PIL import Image

from flatlandia import geo
from flatlandia.report.figures import METHOD_COLOURS, TRUTH_COLOUR
from flatlandia.viewer import page, query_figures, scene_view

#: (token, split, x, y, heading deg)
CAMERAS = [("q_train", "train", 0.0, 0.0, 30.0), ("q_val", "val", 40.0, -10.0, 120.0)]
CAMERAS += [("t1", "test", 10.0, 5.0, 45.0), ("t2", "test", 60.0, 50.0, 200.0)]


@pytest.fixture(scope="module")
def data():
    """A 14-object scene (obj_idx not equal to row order), four queries, four runs: the solver on
    depth maps (t1 placed 2 m off with one wrong match, t2 without a pose), the solver on GT maps
    (exact), and two learned models (8 m and 20 m off)."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(-20, 90, (14, 2))
    labels = np.array(["pole", "sign", "bench"])[np.arange(14) % 3]
    ref = pd.DataFrame(
        {"scene": "7", "obj_idx": np.arange(14) * 3 + 1, "class_label": labels, "x_m": xy[:, 0], "y_m": xy[:, 1]}
    )
    rows = []
    for token, split, x, y, th in CAMERAS:
        local_all = geo.world_to_local(xy, (x, y), np.radians(th))
        seen = [k for k in np.argsort(np.hypot(*local_all.T)) if local_all[k, 0] > 0][:5]
        rows.append(
            {
                "scene": "7",
                "token": token,
                "split": split,
                "x_m": x,
                "y_m": y,
                "theta_deg": th,
                "n_objects": len(seen),
                "ref_idx": ref["obj_idx"].to_numpy()[seen].tolist(),
                "gt_local_xy_m": local_all[seen].tolist(),
            }
        )
    queries = pd.DataFrame(rows)
    test = queries[queries["split"] == "test"]

    def run(offset, dtheta, matches=False):
        x, y, th = test["x_m"] + offset, test["y_m"] - offset, test["theta_deg"] + dtheta
        e = pd.DataFrame({"scene": "7", "token": test["token"], "n_objects": test["n_objects"], "x": x, "y": y})
        e["theta_deg"] = th
        if offset == 2.0:  # the solver on depth maps: no pose for t2
            e.loc[e["token"] == "t2", ["x", "y", "theta_deg"]] = np.nan
        em = np.hypot(e["x"] - test["x_m"], e["y"] - test["y_m"])
        ed = np.abs(np.degrees(geo.wrap_angle(np.radians(e["theta_deg"] - test["theta_deg"]))))
        e["error_m"] = np.where(np.isfinite(em), em, np.inf)
        e["error_deg"] = np.where(np.isfinite(ed), ed, 180.0)
        e["n_inliers"], e["n_correct_inliers"] = (4, 3) if matches else (0, 0)
        # the solver's matches (t1: its first object matched to a wrong reference object); a
        # learned run stores none (an empty list)
        wrong = [[int(ref["obj_idx"].iloc[0])] + r[1:] for r in test["ref_idx"]]
        e[scene_view.MATCH_COLUMN] = wrong if matches else [[] for _ in range(len(e))]
        return e

    errors = {
        "solver_depth_gtbb": run(2.0, 3.0, matches=True),
        "solver_gt_gtbb": run(0.0, 0.0),
        "mlp_depth_gtbb": run(8.0, 10.0),
        "mlp_att_depth_gtbb": run(20.0, 25.0),
    }
    return ref, queries, errors


@pytest.fixture(scope="module")
def view(data):
    ref, queries, errors = data
    return scene_view.scene_view("7", ref, queries, errors)


def test_the_local_map_at_the_true_pose_lies_on_its_reference_objects(view):
    for q in view.queries:
        assert np.allclose(q.truth(), view.object_xy(q.ref_idx), atol=1e-6), q.token


def test_the_featured_runs_are_the_solver_and_the_best_learned_model(view):
    assert view.featured == ("solver_depth_gtbb", "mlp_depth_gtbb")
    assert [r.name for r in view.runs][:2] == ["solver_gt_gtbb", "solver_depth_gtbb"]  # panel order


def test_only_the_solver_brings_matches(view):
    q = next(q for q in view.queries if q.token == "t1")
    assert q.estimate("solver_depth_gtbb").matches[1:] == q.ref_idx[1:]
    assert q.estimate("mlp_depth_gtbb").matches is None


def test_the_worst_queries_put_a_query_without_a_pose_first(view):
    assert [q.token for q in scene_view.worst_queries(view, 5)] == ["t2", "t1"]


def test_a_query_figure_draws_truth_estimates_matches_and_errors(view):
    q = next(q for q in view.queries if q.token == "t1")
    fig = query_figures.query_figure(view, q)
    (ax,) = fig.axes
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    e_geo, e_mlp = q.estimate("solver_depth_gtbb"), q.estimate("mlp_depth_gtbb")
    assert any(t.startswith("true pose") for t in texts)
    assert f"{e_geo.run.label}: {e_geo.error_m:.2f} m, {e_geo.error_deg:.1f}° (4 inliers, 3 correct)" in texts
    assert f"{e_mlp.run.label}: {e_mlp.error_m:.2f} m, {e_mlp.error_deg:.1f}°" in texts
    colours = [to_hex(ln.get_color()) for ln in ax.get_lines()]
    assert colours.count(query_figures.WRONG_COLOUR) == 1  # the one wrong match, in red
    assert colours.count(METHOD_COLOURS["solver"]) >= q.local.shape[0] - 1  # the right ones, in the solver's colour
    crosses = [c for c in ax.collections if len(c.get_offsets()) == len(q.local) and c.get_facecolor().size]
    assert {to_hex(c.get_facecolor()[0]) for c in crosses} >= {TRUTH_COLOUR, METHOD_COLOURS["mlp"]}


def test_the_gallery_shows_the_worst_queries_and_one_png_per_test_query(view, tmp_path):
    fig = query_figures.worst_figure(view)
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible() and ax.axison]
    assert [re.search(r"query (\w+)", t).group(1) for t in titles] == ["t2", "t1"]
    assert titles[0].splitlines()[1:] == [
        "solver: no pose",
        f"MLP: {view.queries[3].estimate('mlp_depth_gtbb').summary()}",
    ]
    (legend,) = fig.legends
    texts = [t.get_text() for t in legend.get_texts()]
    assert {f"{r.label}: estimate" for r in view.runs if r.name in view.featured} <= set(texts), texts
    written = query_figures.write_query_figures(view, tmp_path)
    assert sorted(p.name for p in written) == ["t1.png", "t2.png"]
    with Image.open(written[0]) as im:
        assert im.format == "PNG" and min(im.size) > 300


def _data_of(html: str) -> dict:
    return json.loads(re.search(r'<script type="application/json" id="scene-data">(.*?)</script>', html, re.S).group(1))


def test_the_page_is_self_contained_small_and_deterministic(view):
    html = page.render(view)
    assert html == page.render(view)
    assert len(html.encode()) < 60_000, len(html.encode())
    # nothing is loaded: the only link is the one a reader clicks to a published query's photo
    link = '<a class="photo" href='
    assert html.count(link) == 1
    assert not re.search(r"""(src|href)\s*=|@import|url\(|fetch\(|XMLHttpRequest|import\(""", html.replace(link, ""))
    assert set(re.findall(r"https?://[^\s\"']+", html)) == {"http://www.w3.org/2000/svg"}  # a namespace name only
    photo = page.render(view, page.MAPILLARY_PHOTO)
    assert '"photoUrl":"https://www.mapillary.com/app/?pKey="' in photo and '"photoUrl":null' in html
    d = _data_of(html)
    assert [q["token"] for q in d["queries"]] == ["q_train", "q_val", "t1", "t2"]
    assert {q["token"]: sorted(q["est"]) for q in d["queries"] if q["est"]} == {
        "t1": sorted(view_runs := [r.name for r in view.runs]),
        "t2": sorted(view_runs),
    }
    t2 = next(q for q in d["queries"] if q["token"] == "t2")
    assert t2["est"]["solver_depth_gtbb"][:3] == [None, None, None]
    assert sum(c["count"] for c in d["classes"]) == len(view.ref) == len(d["objects"])


def test_a_script_end_tag_in_the_data_cannot_break_the_page(data):
    ref, queries, errors = data
    odd = ref.assign(class_label=ref["class_label"].where(ref.index > 0, "</script><b>x"))
    html = page.render(scene_view.scene_view("7", odd, queries, errors))
    assert html.count("</script>") == 2 and "</script><b>" not in html
    assert any(c["label"] == "</script><b>x" for c in _data_of(html)["classes"])


# ----------------------------------------------------------------------------- in a real browser


@pytest.fixture(scope="module")
def browser():
    chromium, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not (chromium and driver):
        pytest.skip("Debian's Chromium is not installed: apt-get install chromium chromium-driver (make system-deps)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1200,800"):
        opts.add_argument(arg)
    d = webdriver.Chrome(options=opts, service=Service(driver))
    yield d
    d.quit()


def _pixels(png: bytes, colour: str, box, tol: int = 14) -> int:
    """How many pixels of the screenshot, inside ``box`` (left, top, right, bottom), have ``colour``."""
    import io

    im = np.asarray(Image.open(io.BytesIO(png)).convert("RGB").crop(box), int)
    return int((np.abs(im - np.array(to_rgb(colour)) * 255).max(axis=-1) <= tol).sum())


def test_clicking_a_test_query_shows_its_layers_in_chromium(browser, view, tmp_path):
    """Open the page, click the test query t1, read the page's state and a screenshot."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    path = tmp_path / "viewer.html"
    page.write_page(view, path)
    browser.get(path.as_uri())
    assert browser.execute_script("return window.flatlandiaViewer.ready") is True
    rect = browser.execute_script(
        "const r = document.getElementById('map').getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom];"
    )
    box = tuple(int(v) for v in rect)
    before = browser.get_screenshot_as_png()
    assert len(browser.find_elements(By.CSS_SELECTOR, ".camera")) == len(CAMERAS)
    assert not browser.find_elements(By.CSS_SELECTOR, "#layer-query [data-layer]")

    browser.find_element(By.CSS_SELECTOR, '.camera[data-token="t1"]').click()
    state = browser.execute_script("return window.flatlandiaViewer")
    assert state["selected"] == "t1" and state["drawn"] == ["truth", "solver_depth_gtbb", "mlp_depth_gtbb"]
    for layer in ('[data-layer="truth"]', '[data-run="solver_depth_gtbb"]', '[data-run="mlp_depth_gtbb"]'):
        r = browser.execute_script(f"return document.querySelector('#layer-query {layer}').getBoundingClientRect()")
        assert r["width"] > 5 and r["height"] > 5 and box[0] <= r["left"] and r["right"] <= box[2], (layer, r)
    after = browser.get_screenshot_as_png()
    (tmp_path / "after.png").write_bytes(after)
    assert _pixels(before, TRUTH_COLOUR, box) == 0
    assert _pixels(after, TRUTH_COLOUR, box) > 150  # the true camera, its objects and rings, in green
    rows = browser.find_elements(By.CSS_SELECTOR, "#errors tr[data-run]")
    assert len(rows) == len(view.runs)
    e = view.queries[2].estimate("mlp_att_depth_gtbb")
    assert f"{e.error_m:.2f}" in next(r.text for r in rows if r.get_attribute("data-run") == "mlp_att_depth_gtbb")

    # a run's check box adds its layer; scrolling zooms; Escape clears the query
    browser.find_element(By.CSS_SELECTOR, 'input[data-run="mlp_att_depth_gtbb"]').click()
    assert browser.find_elements(By.CSS_SELECTOR, '#layer-query [data-run="mlp_att_depth_gtbb"]')
    k = browser.execute_script("return window.flatlandiaViewer.view.k")
    ActionChains(browser).scroll_to_element(browser.find_element(By.ID, "map")).scroll_by_amount(0, -300).perform()
    assert browser.execute_script("return window.flatlandiaViewer.view.k") > k
    ActionChains(browser).send_keys("\ue00c").perform()  # Escape
    assert browser.execute_script("return window.flatlandiaViewer.selected") is None
    assert not browser.find_elements(By.CSS_SELECTOR, "#layer-query [data-layer]")
    assert browser.get_log("browser") == []  # no script error


def test_a_scene_without_objects_or_queries_still_gets_a_page(data):
    """An images scene without object classes: an empty map, no runs, still a page."""
    ref, queries, _ = data
    view = scene_view.scene_view("mine", ref.iloc[:0], queries.iloc[:0], {}, ("x (SfM unit)", "y (SfM unit)"))
    d = _data_of(page.render(view))
    assert (d["objects"], d["queries"], d["runs"], d["unit"]) == ([], [], [], "SfM unit")
    assert view.featured == () and scene_view.worst_queries(view, 6) == []
    fig = query_figures.worst_figure(view)
    assert "no test query" in fig.axes[0].texts[0].get_text()
