"""Rule solver_priors: the solver's learned priors of depth maps (noise model, scale prior,
likelihood model, verifier) from the benchmark scenes' training split, for one region
(flatlandia.solver.learned_priors); rule solver_calibration adds the answers' calibration."""

import pandas as pd

from flatlandia.plumbing import rule_log
from flatlandia.solver import learned_priors, verify


def main(smk, log):
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    region = smk.wildcards.region
    fitted = learned_priors.fit(
        scenes, dict(smk.params["solver"]), region if region in learned_priors.REGIONS else None
    )
    log.info("depth scale prior (log metres per unit): %s", fitted.scale)
    if fitted.noise is not None:
        log.info(
            "noise model: bearing sigma %s deg, log-range sigma %s per range bin, on %d detections; "
            "bearing correction %s",
            [round(v, 2) for v in fitted.noise.bearing_sigma_deg],
            [round(v, 3) for v in fitted.noise.log_range_sigma],
            fitted.noise.detections,
            {k: round(v, 3) for k, v in fitted.noise.distortion.items()},
        )
    if fitted.verifier is not None:
        weights = {f: round(float(w), 3) for f, w in zip(verify.FEATURES, fitted.verifier.weights)}
        log.info("verifier on %s, weights of the standardised features: %s", region, weights)
    if fitted.likelihood is not None:
        lik = fitted.likelihood
        log.info(
            "likelihood model: field of view +-%.1f deg, range %.1f m; p_d weight of the views' share %.2f",
            lik.fov_half_deg,
            lik.max_range_m,
            lik.share_w,
        )
    fitted.write(smk.output.priors)


rule_log.run(main, snakemake)  # noqa: F821
