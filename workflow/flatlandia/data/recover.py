"""Rule recover: register every GT local map of a scene onto its reference map (docs/conventions.md).

The pair-registration algorithm is :mod:`flatlandia.data.registration`; this module runs it
over a scene and tabulates the recovered poses, matched objects and competing solutions.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatlandia import config, geo
from flatlandia.data import registration


def recover_scene(
    scene: str,
    ref_lonlat: np.ndarray,
    ref_classes: np.ndarray,
    local_maps: dict[str, dict[str, np.ndarray]],
    tol_m: float = config.section_defaults("recover")["tol_m"],
    progress=None,
) -> pd.DataFrame:
    """Register every GT local map of a scene; one row per query (pose in lon/lat + unit space)."""
    frame = geo.frame_for(ref_lonlat)
    mpd = frame.metres_per_degree()
    index = registration.PairIndex(ref_lonlat / geo.UNIT_DEG)
    rows = []
    items = sorted(local_maps.items())
    for token, maps in progress(items) if progress else items:
        rec = registration.register(maps["GT"], index, mpd, tol_m=tol_m)
        if rec is None:
            rows.append(dict(scene=scene, token=token, recovered=False))
            continue
        best = rec.best
        second = rec.others[0] if rec.others else None
        cam_lonlat = best.cam * geo.UNIT_DEG
        rows.append(
            dict(
                scene=scene,
                token=token,
                recovered=True,
                n_objects=len(maps["GT"]),
                ref_idx=list(best.ref_idx),
                lon=float(cam_lonlat[0]),
                lat=float(cam_lonlat[1]),
                theta_lonlat_deg=float(np.degrees(best.theta)),
                residual_m=best.max_m,
                n_solutions=1 + len(rec.others),
                second_residual_m=second.rms_m if second else float("nan"),
                second_cam_dist_m=float(registration.residual_metres(second.cam - best.cam, mpd))
                if second
                else float("nan"),
                second_ref_idx=list(second.ref_idx) if second else [],
                ambiguous=bool(rec.others),
                resolution=registration.classify_ambiguity(rec, ref_classes),
            )
        )
    return pd.DataFrame(rows)
