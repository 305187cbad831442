"""Text from the scene sheet and result files reaches LaTeX, Markdown and HTML escaped for each
format (flatlandia.plumbing.escape), through the real writers; tables without specials are unchanged."""

from __future__ import annotations

import html as html_module
import re

import numpy as np
import pandas as pd
import pytest

from flatlandia.benchmark import fine_rows, metrics
from flatlandia.city import city_table
from flatlandia.coarse import evaluation as coarse_evaluation
from flatlandia.data import stats
from flatlandia.fine import fine_table, scene_localization
from flatlandia.plumbing import escape, files, summary
from flatlandia.report import tables
from flatlandia.viewer import page
from flatlandia.viewer.scene_view import SceneView

#: a scene sheet's `city` (free text a user or a download controls)
HOSTILE = r"\input{secret.tex}<img src=x onerror=alert(1)>|pipe"
LATEX_SPECIALS = "\\{}$&#^_~%"


# ----------------------------------------------------------------------------- helpers


def md_cells(line: str) -> list[str]:
    """The cells of a Markdown table row, split on unescaped pipes only (``\\x`` is one escape)."""
    assert line.startswith("|") and line.endswith("|"), line
    cells, cur = [], ""
    for tok in re.findall(r"\\.|[^|\\]+|\|", line[1:-1]):
        if tok == "|":
            cells.append(cur.strip())
            cur = ""
        else:
            cur += tok
    return cells + [cur.strip()]


def assert_markdown_safe(text: str) -> None:
    """No raw HTML tag, no unescaped ``\\input``, every table row as wide as its header."""
    assert "<img" not in text and HOSTILE not in text
    assert not re.search(r"(?<!\\)\\input", text), text
    width = None
    for line in text.splitlines():
        if not line.startswith("|"):
            width = None
            continue
        n = len(md_cells(line))
        width = n if width is None else width
        assert n == width, f"{line!r}: {n} cells instead of {width}"


def rendered_cells(text: str) -> list[str]:
    """The text of every table cell once the Markdown is rendered (CommonMark + tables)."""
    markdown_it = pytest.importorskip("markdown_it")
    out = markdown_it.MarkdownIt("commonmark").enable("table").render(text)
    assert "<img" not in out
    return [html_module.unescape(c) for c in re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", out, re.S)]


def stats_frame(cities: list[str]) -> pd.DataFrame:
    """The dataset_stats table as rule dataset_stats builds it (flatlandia.data.stats.city_table)."""
    per_scene = pd.DataFrame(
        {
            "city": cities,
            "area_km2": [0.5 + i for i in range(len(cities))],
            "kb_per_map": [2.0] * len(cities),
            "images": [10.0] * len(cities),
            "objects": [40] * len(cities),
            "queries": [30] * len(cities),
        }
    )
    return stats.city_table(per_scene, {c: 1.0 for c in [*cities, "all"]})


def fine_summaries(label: str = "MLP", strategy: str = "GT-BB", trained_on: str = "GT-BB") -> list[dict]:
    errors = pd.DataFrame(
        {
            "error_m": [0.5, 2.0, np.inf],
            "error_deg": [1.0, 4.0, 180.0],
            "solvable": [True, True, False],
            "seconds": [0.01] * 3,
            "error_paper_m": [0.5, 2.0, np.inf],
        }
    )
    slug = "mlp" if label == "MLP" else "other"  # a slug the report does not know: its label is the run's
    base = {"method": label, "method_slug": slug, "strategy": strategy, "trained_on": trained_on}
    return [
        {
            "run": f"{slug}_{mt}_gtbb",
            "map_type": mt,
            "epochs": 3,
            "train_s": 60.0,
            **base,
            **metrics.summarise(errors),
        }
        for mt in ("gt", "depth")
    ]


def coarse_table(loss: str = "Sim+Trip", strategy: str = "R_30") -> pd.DataFrame:
    t = pd.DataFrame({"loss": [loss] * 2, "strategy": [strategy] * 2, "map_type": ["gt", "depth"], "queries": [5, 5]})
    for c in ["precision", "recall", "success", "proposal_size", "paper_precision", "paper_recall", "paper_success"]:
        t[c] = [0.5, np.nan]
    return t


def city_frame(method: str = "index + solver") -> pd.DataFrame:
    row = {
        c.name: 1.5 if c.kind == "float" else 2 if c.kind == "int" else "tiled" for c in tables.SCHEMAS["city_scale"]
    }
    return city_table.table([{**row, "method": method}])


def scene_rows(method: str = "geometric solver") -> pd.DataFrame:
    s = fine_summaries()[0]
    return pd.DataFrame([{**s, "scene": "9", "method": method, "method_slug": "solver", "proposal": "whole"}])


# ----------------------------------------------------------------------------- the functions


def test_latex_escapes_all_ten_specials_in_one_pass():
    assert escape.latex(LATEX_SPECIALS) == (r"\textbackslash{}\{\}\$\&\#\textasciicircum{}\_\textasciitilde{}\%")
    assert escape.latex(HOSTILE) == (
        r"\textbackslash{}input\{secret.tex\}\textless{}img src=x onerror=alert(1)\textgreater{}\textbar{}pipe"
    )
    assert escape.latex("a\nb") == "a b" and escape.latex(3) == "3" and escape.latex("GAT+ATT") == "GAT+ATT"


def test_markdown_escapes_markup_but_keeps_plain_names():
    assert escape.markdown(HOSTILE) == r"\\input{secret.tex}&lt;img src=x onerror=alert(1)&gt;\|pipe"
    assert escape.markdown("*b* `c` [l](u) & x\ny") == r"\*b\* \`c\` \[l\](u) &amp; x y"
    assert escape.markdown("_em_ a__b") == r"\_em\_ a\_\_b"
    for plain in ["R_30", "2N_LM", "solver_gt_gtbb", "GAT+ATT", "Sim+Trip", "GT-BB", "-1.5e+03", "0.375 / 0.500"]:
        assert escape.markdown(plain) == plain
    text = ["| a | b |", "|---|---|", "| " + escape.markdown(HOSTILE) + " | " + escape.markdown("_em_ *b*") + " |"]
    assert rendered_cells("\n".join(text) + "\n")[2:] == [HOSTILE, "_em_ *b*"]


def test_html_escapes_tags_and_quotes():
    assert escape.html(HOSTILE) == r"\input{secret.tex}&lt;img src=x onerror=alert(1)&gt;|pipe"
    assert escape.html("\"'&") == "&quot;&#x27;&amp;"


def test_mathtext_escapes_dollars():
    assert escape.mathtext("a$x$") == r"a\$x\$"


# ----------------------------------------------------------------------------- the writers


def test_dataset_stats_escapes_a_hostile_city(tmp_path):
    df = stats_frame(["Barcelona", HOSTILE])
    tables.write_table(df, "dataset_stats", tmp_path / "d.parquet", tmp_path / "d.md", tmp_path / "d.tex", title="T")
    assert pd.read_parquet(tmp_path / "d.parquet")["city"].tolist() == ["Barcelona", HOSTILE, "all"]  # data as is
    tex = (tmp_path / "d.tex").read_text()
    assert r"\input" not in tex and "<img" not in tex and "|" not in tex
    assert escape.latex(HOSTILE) + " & 1 &" in tex
    for line in tex.splitlines():
        if line.endswith(r"\\"):  # every row as wide as the header: no unescaped &
            assert len(re.findall(r"(?<!\\)&", line)) == len(df.columns) - 1, line
    md = (tmp_path / "d.md").read_text()
    assert_markdown_safe(md)
    assert HOSTILE in rendered_cells(md)


def test_normal_tables_are_unchanged():
    df = pd.DataFrame({"scene": ["12", "all"], "strategy": ["R_30", "GAT+ATT"], "n": [3, 4], "x": [0.5, np.nan]})
    assert tables.to_markdown(df) == (
        "| scene | strategy | n | x |\n|---|---|---|---|\n| 12 | R_30 | 3 | 0.5 |\n| all | GAT+ATT | 4 |  |\n"
    )
    assert tables.to_latex(df.rename(columns={"n": "pct_%"}), caption="a_b") == (
        "\\begin{table}[t]\n\\centering\n\\begin{tabular}{llll}\n\\hline\n"
        "scene & strategy & pct\\_\\% & x \\\\\n\\hline\n12 & R\\_30 & 3 & 0.5 \\\\\nall & GAT+ATT & 4 & -- \\\\\n"
        "\\hline\n\\end{tabular}\n\\caption{a\\_b}\n\\end{table}\n"
    )


@pytest.mark.parametrize(
    "render",
    [
        lambda: tables.to_markdown(stats_frame(["Barcelona", "Sao Paulo"])),
        lambda: tables.to_latex(stats_frame(["Barcelona", "Sao Paulo"]), caption="Dataset statistics"),
        lambda: fine_table.render_markdown(fine_rows.table_rows(fine_summaries()), note="a **note**"),
        lambda: coarse_evaluation.render_markdown(coarse_table(), note="`x`"),
        lambda: city_table.markdown(city_frame(), "note `x`"),
        lambda: scene_localization.render_markdown(scene_rows(), "9"),
    ],
)
def test_escaping_changes_nothing_without_specials(render, monkeypatch):
    """Escaping is the only change to the renderers: with it a no-op, they give the same text."""
    escaped = render()
    monkeypatch.setattr(escape, "markdown", str)
    monkeypatch.setattr(escape, "latex", lambda v: str(v).replace("_", r"\_").replace("%", r"\%").replace("&", r"\&"))
    assert render() == escaped


def test_fine_markdown_escapes_run_values():
    df = fine_rows.table_rows(fine_summaries(label=HOSTILE, trained_on=HOSTILE))
    md = fine_table.render_markdown(df, note="the **note** stays bold")
    assert_markdown_safe(md)
    assert "the **note** stays bold" in md and "## Table 4 (GT-BB proposals)" in md
    cells = rendered_cells(md)
    assert cells.count(HOSTILE) >= 2  # the strategy and, in the cost table, the training proposals
    assert_markdown_safe(tables.to_markdown(df))
    assert r"\input" not in tables.to_latex(df)


def test_coarse_city_and_scene_markdown_escape_their_values():
    for md in (
        coarse_evaluation.render_markdown(coarse_table(loss=HOSTILE, strategy="R_30|x"), note="n"),
        city_table.markdown(city_frame(method=HOSTILE), "note"),
        scene_localization.render_markdown(scene_rows(method=HOSTILE), "<b>scene</b>"),
    ):
        assert_markdown_safe(md)
        assert HOSTILE in rendered_cells(md)
    head = scene_localization.render_markdown(scene_rows(), "<b>*x*</b>").splitlines()[0]
    assert head == r"# Scene &lt;b&gt;\*x\*&lt;/b&gt;: localization with the benchmark's methods (no retraining)"


def test_summary_escapes_what_it_reads(tmp_path):
    res = tmp_path / "results"
    scene = "<b>x|y"
    files.write_parquet(
        pd.DataFrame({"object_id": []}), res / scene / "objects/objects.parquet", {"empty_because": HOSTILE}
    )
    text = summary.write_summary(res, [scene])
    assert_markdown_safe(text)
    assert [scene, "yes"] == rendered_cells(text)[4:6] and HOSTILE in rendered_cells(text)


def test_viewer_title_is_html_escaped_and_filled_once():
    ref = pd.DataFrame({"x_m": [0.0, 1.0], "y_m": [0.0, 1.0], "class_label": ["pole", "tree"], "obj_idx": [0, 1]})
    for name in (HOSTILE, "__DATA__ __JS__"):
        view = SceneView(name, ("x east (m)", "y north (m)"), ref, (), (), ())
        html = page.render(view)
        title = re.search(r"<title>(.*?)</title>", html, re.S).group(1)
        assert title == escape.html(f"Flatlandia scene {name}") and "<img" not in html
        assert html.count("<script") == 2 and len(html) < 60_000
