"""Rule recovery_table: how query recovery went per scene (residuals, ambiguity, timing)."""

import pandas as pd

from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables


def main(smk, log):
    rows = []
    for path in smk.input.recovered:
        rec = pd.read_parquet(path)
        meta = files.read_parquet_metadata(path)
        res = rec["resolution"].value_counts()
        rows.append(
            {
                "scene": str(rec["scene"].iloc[0]),
                "queries": len(rec),
                "recovered": int(rec["recovered"].sum()),
                "max_residual_m": float(rec["residual_m"].max()),
                "ambiguous": int(rec["ambiguous"].sum()),
                "resolved_exact_fit": int(res.get("exact_fit", 0)),
                "same_classes": int(res.get("same_classes", 0)),
                "unresolved": int(res.get("unresolved", 0)),
                "seconds": float(meta.get("seconds", float("nan"))),
            }
        )
    df = pd.DataFrame(rows)
    total = df.drop(columns="scene").sum(numeric_only=True).to_dict()
    total["max_residual_m"] = float(df["max_residual_m"].max())
    df = pd.concat([df, pd.DataFrame([{"scene": "all", **total}])], ignore_index=True)
    for c in ["queries", "recovered", "ambiguous", "resolved_exact_fit", "same_classes", "unresolved"]:
        df[c] = df[c].astype("int64")
    tables.write_table(
        df,
        "recovery",
        smk.output.parquet,
        smk.output.markdown,
        smk.output.latex,
        title="Query recovery by registration of the published GT local maps",
    )
    log.info("\n%s", tables.to_markdown(df))


rule_log.run(main, snakemake)  # noqa: F821
