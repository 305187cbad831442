"""`flatlandia audit PATH --tree` (provenance.lineage_tree): each artifact's subtree once, shared
subtrees referred back to, one line per job; on a manifest shaped like the default run's (20 scenes,
40 fine runs reading every scene's map and queries, a table over the runs), built here (fast)."""

from __future__ import annotations

import json

import pandas as pd

from flatlandia.plumbing import provenance

SCENES = [str(s) for s in range(1, 21)]
RUNS = [
    f"{m}_{t}_{p}"
    for m in ("solver", "mlp", "gat", "mlp_att", "gat_att")
    for t in ("gt", "depth")
    for p in ("gtbb", "whole", "coarse-sim", "coarse-solver")
]


def _rec(artifact, rule, inputs, wildcards=None, scene="", sha=None):
    return {
        "artifact": artifact,
        "rule": rule,
        "scene": scene,
        "wildcards": json.dumps(wildcards or {}, sort_keys=True),
        "sha256": sha or f"{abs(hash(artifact)):064d}"[:64],
        "inputs": json.dumps(inputs, sort_keys=True),
    }


def _manifest() -> pd.DataFrame:
    """Sources -> per scene ingest, reference map and queries -> fine runs (errors and summary of one
    job, each reading every scene's map and queries; learned runs also a checkpoint) -> the table."""
    rows = []

    def digest(path):
        return next((r["sha256"] for r in rows if r["artifact"] == path), "s" * 64)

    for s in SCENES:
        src = f"../shared/flatlandia/individual_reference_maps/map_{s}.json"
        lm = "../shared/flatlandia/local_maps.json"
        w = {"scene": s}
        rows.append(_rec(f"results/{s}/ingest/ingest.json", "ingest", {src: "s" * 64, lm: "s" * 64}, w, s))
        ing = {f"results/{s}/ingest/ingest.json": digest(f"results/{s}/ingest/ingest.json")}
        for name in ("reference_map.parquet", "reference_map.geojson"):
            rows.append(_rec(f"results/{s}/maps/{name}", "reference_map", {**ing, src: "s" * 64}, w, s))
        ref = {f"results/{s}/maps/reference_map.parquet": digest(f"results/{s}/maps/reference_map.parquet")}
        rows.append(_rec(f"results/{s}/queries/queries.parquet", "queries", {**ref, lm: "s" * 64}, w, s))
    scenes_in = {}
    for s in SCENES:
        for p in (f"results/{s}/maps/reference_map.parquet", f"results/{s}/queries/queries.parquet"):
            scenes_in[p] = digest(p)
    table_in = {}
    for run in RUNS:
        method = run.split("_")[0]
        inputs = dict(scenes_in)
        if method != "solver":
            ckpt = f"results/fine/models/{method}_{run.split('_')[-2]}/checkpoint.pt"
            if not any(r["artifact"] == ckpt for r in rows):
                rows.append(_rec(ckpt, "fine_train", dict(scenes_in), {"model": method}))
            inputs[ckpt] = digest(ckpt)
        for name in ("errors.parquet", "summary.json"):
            rows.append(_rec(f"results/fine/{run}/{name}", "fine_eval", inputs, {"run": run}))
            table_in[f"results/fine/{run}/{name}"] = digest(f"results/fine/{run}/{name}")
    rows.append(_rec("results/tables/fine_localization.parquet", "fine_table", table_in, {}))
    return pd.DataFrame(rows)


def test_the_tree_lists_each_subtree_once_and_refers_back():
    df = _manifest()
    lines = provenance.lineage_tree("results/tables/fine_localization.parquet", df)
    text = "\n".join("  " * d + t for d, t in lines)
    assert len(lines) < 300, len(lines)
    # the table's runs: one line per job (errors and summary together), all 40 at the first level
    top = [t for d, t in lines if d == 1]
    assert sum("<- fine_eval" in t for t in top) == len(RUNS)
    assert "results/fine/solver_depth_whole/{errors.parquet,summary.json}" in text
    # each scene's map is expanded once (its ingest under it), then counted where read again
    for s in SCENES:
        assert sum(t.startswith(f"results/{s}/maps/reference_map.parquet") for _, t in lines) == 1, s
        assert sum(t.startswith(f"results/{s}/ingest/ingest.json") for _, t in lines) == 1, s
    assert "20 x results/{scene}/maps/reference_map.parquet, 20 x results/{scene}/queries/queries.parquet" in text
    # a run reading exactly what an earlier one read says so in one line
    assert "inputs are those of results/fine/" in text
    # every input of the lineage is named somewhere (as itself, or counted as results/{scene}/...)
    for artifact in {r["input"] for r in provenance.lineage("results/tables/fine_localization.parquet", df, True)}:
        s = next((x for x in SCENES if f"/{x}/" in artifact), None)
        folder = artifact.rsplit("/", 1)[0]
        pattern = folder.replace(f"/{s}/", "/{scene}/") if s else folder
        assert artifact.rsplit("/", 1)[-1] in text and (folder in text or pattern in text), artifact
    # the sources appear, once each
    assert text.count("local_maps.json") >= 1 and "(source)" in text


def test_a_changed_input_is_still_flagged_where_it_is_read_again():
    df = _manifest()
    table = df["artifact"] == "results/tables/fine_localization.parquet"
    inputs = json.loads(df.loc[table, "inputs"].iloc[0])
    inputs["results/fine/gat_gt_whole/errors.parquet"] = "0" * 64  # the table read an older file
    df.loc[table, "inputs"] = json.dumps(inputs, sort_keys=True)
    lines = provenance.lineage_tree("results/tables/fine_localization.parquet", df)
    flagged = [t for _, t in lines if "CHANGED since used" in t]
    assert flagged and "results/fine/gat_gt_whole/errors.parquet" in flagged[0]


# ---------------------------------------------------------------- a record's settings: what its rule read


def test_a_record_lists_only_the_settings_its_rule_read(tmp_path):
    """The settings of a fine_eval or external_eval record are the config keys the rule names
    (config_keys, by their dotted names: provenance.rule_settings), and only those the job reads: no
    coarse strategy for the whole map or GT-BB, no training regime or solver settings where nothing was
    trained or solved (an external method on the whole map reads no setting at all)."""
    from conftest import REPO

    from flatlandia.plumbing import debug

    tiny = [REPO / "config" / "test" / "tiny.yaml"]
    poses = tmp_path / "mine.csv"
    poses.write_text("scene,token,x_m,y_m,theta_deg\n")
    ext_cfg = {"external": [{"name": "mine", "poses": str(poses)}]}

    def settings(rule, config=None, **wildcards):
        job = debug.mock_snakemake(rule, workdir=tmp_path, configfiles=tiny, config=config or {}, **wildcards)
        return provenance.rule_settings(job)

    ext = settings("external_eval", ext_cfg, method="mine", map_type="depth", proposal="whole")
    assert ext == {}
    ext = settings("external_eval", ext_cfg, method="mine", map_type="depth", proposal="coarse-sim")
    assert ext == {"fine.coarse_strategy": "2N_LM"}
    ext = settings("external_eval", ext_cfg, method="mine", map_type="depth", proposal="coarse-solver")
    assert ext == {"coarse.solver.fine_strategy": "BB"}
    solver = settings("fine_eval", method="solver", map_type="depth", proposal="whole")
    assert list(solver) == ["solver"] and solver["solver"]["top_k"] == 6
    mlp = settings("fine_eval", method="mlp", map_type="depth", proposal="gtbb")
    assert mlp == {}
    coarse = settings("fine_eval", method="mlp", map_type="gt", proposal="coarse-sim")
    assert set(coarse) == {"fine.coarse_strategy", "fine.coarse_training.enabled", "fine.coarse_training.crop_m"}
    assert coarse["fine.coarse_strategy"] == "2N_LM" and coarse["fine.coarse_training.crop_m"] > 0
