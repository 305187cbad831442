"""Rule fine_solver: the bearing solver on the test split of every scene, one map type x proposal."""

import pandas as pd

from flatlandia import fine_solver_eval as fse
from flatlandia import io, runlog


def main(smk, log):
    mt, prop = smk.wildcards.map_type, smk.wildcards.proposal
    parts = []
    for ref_path, q_path in zip(smk.input.reference_maps, smk.input.queries):
        ref, q = pd.read_parquet(ref_path), pd.read_parquet(q_path)
        prior = q.loc[q["split"] == "train", ["x_m", "y_m"]].to_numpy() if prop == "whole" else None
        q = q[q["split"] == "test"]
        parts.append(fse.evaluate_scene(ref, q, mt, prop, dict(smk.params.solver), prior_xy=prior,
                                        progress=runlog.progress(log, f"scene {ref['scene'].iloc[0]}")))
    errors = pd.concat(parts, ignore_index=True)
    io.write_parquet(errors, smk.output.errors, {"map_type": mt, "proposal": prop, "solver": dict(smk.params.solver)})
    summary = fse.summarise(errors)
    io.write_json({"map_type": mt, "proposal": prop, **summary}, smk.output.summary)
    log.info("%s maps, %s proposals: %s", mt, prop, summary)


runlog.run(main, snakemake)  # noqa: F821
