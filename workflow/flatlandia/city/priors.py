"""The solver's learned pieces for the city benchmark, fitted once on the published scenes.

Why fitted per scene and not on a city: they describe depth maps (the log-scale prior) and which
of the solver's best hypotheses is right near the training cameras (the verifier, whose features
read only views within 15 m of a pose), so they do not depend on the map's size; fitting the
verifier on the whole 20-scene city instead took 128 s of CPU and left the validation figures
unchanged (25.9 % wrong scene either way). The same fit as rule fine_eval's, kept as JSON.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia.fine import solver_verify, solver_verify_fit


def fit(scenes: list[tuple[pd.DataFrame, pd.DataFrame]], geo: dict) -> dict:
    """``{"scale_prior": [mean, std] or None, "verifier": {weights, mean, scale} or None}`` from the
    training split of the (reference map, queries) of every scene, as fine_eval fits them."""
    scale, v = solver_verify_fit.depth_priors(scenes, geo)
    verifier = {"weights": v.weights.tolist(), "mean": v.mean.tolist(), "scale": v.scale.tolist()} if v else None
    return {"scale_prior": list(scale) if scale else None, "verifier": verifier}


def load(d: dict):
    """(scale prior or None, verifier or None) of :func:`fit`'s dict."""
    scale = tuple(d["scale_prior"]) if d["scale_prior"] else None
    v = d["verifier"]
    verifier = solver_verify.Verifier(*(np.asarray(v[k], float) for k in ("weights", "mean", "scale"))) if v else None
    return scale, verifier
