import pandas as pd
import pytest

from flatlandia.report import tables


def _recovery_row(**kw):
    row = dict(
        scene="1",
        queries=3,
        recovered=3,
        max_residual_m=1e-9,
        ambiguous=0,
        resolved_exact_fit=0,
        same_classes=0,
        unresolved=0,
        seconds=0.1,
    )
    row.update(kw)
    return pd.DataFrame([row])


def test_schema_is_enforced_when_written(tmp_path):
    df = _recovery_row()
    tables.write_table(df, "recovery", tmp_path / "r.parquet", tmp_path / "r.md", tmp_path / "r.tex", title="t")
    back = pd.read_parquet(tmp_path / "r.parquet")
    pd.testing.assert_frame_equal(back, df)
    with pytest.raises(ValueError, match="missing \\['seconds'\\]"):
        tables.write_table(df.drop(columns="seconds"), "recovery", tmp_path / "x.parquet")
    with pytest.raises(ValueError, match="queries: str instead of int"):
        tables.write_table(_recovery_row(queries="3"), "recovery", tmp_path / "x.parquet")
    assert not (tmp_path / "x.parquet").exists()


def test_renderings_hold_the_same_numbers(tmp_path):
    df = pd.concat([_recovery_row(), _recovery_row(scene="all_scenes", queries=10)], ignore_index=True)
    md = tables.to_markdown(df).splitlines()
    assert len(md) == 2 + len(df) and md[3].split("|")[2].strip() == "10"
    tex = tables.to_latex(df, caption="a_b")
    assert r"all\_scenes & 10 &" in tex and r"\caption{a\_b}" in tex


def test_docs_match_the_schemas(repo):
    assert (repo / "docs/tables.md").read_text() == tables.schema_markdown(), (
        "docs/tables.md is stale: regenerate it with tables.schema_markdown()"
    )
