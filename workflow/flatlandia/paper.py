"""Every figure the paper publishes, in one place, so that each result table can set the paper's
values beside ours (its ``paper_*`` columns) from a single source.

The paper's "metres" are local-map units x 215, not true metres (docs/conventions.md, "The
paper's metres"). The paper's training settings (epochs, batch size) are config, not figures:
they live in config/paper.yaml, a config file laid over config/config.yaml.
"""

from __future__ import annotations

#: The paper's code turns a local-map unit into "metres" with this factor.
METRES_PER_UNIT = 215.0

#: Table 2, as far as the paper gives it: per city (scenes, objects, queries per scene) and overall.
TABLE2 = {
    "Barcelona": {"scenes": 3, "objects": 73, "queries": 63},
    "Berlin": {"scenes": 2, "objects": 181, "queries": 89},
    "Lisbon": {"scenes": 7, "objects": 137, "queries": 120},
    "Paris": {"scenes": 7, "objects": 83, "queries": 83},
    "Vienna": {"scenes": 1, "objects": 223, "queries": 420},
    "all": {"scenes": 20, "area_km2": 0.025, "kb_per_map": 5.6, "images": 316, "objects": 118, "queries": 110},
}

#: Table 3 (coarse map localization): (loss, strategy, map type) -> (precision, recall, success).
TABLE3: dict[tuple[str, str, str], tuple[float, float, float]] = {
    ("-", "GT-BB", "gt"): (0.258, 1.0, 1.0),
    ("-", "GT-BB", "depth"): (0.258, 1.0, 1.0),
    ("Sim", "N_LM", "gt"): (0.146, 0.146, 0.168),
    ("Sim", "N_LM", "depth"): (0.176, 0.176, 0.179),
    ("Sim", "2N_LM", "gt"): (0.133, 0.266, 0.328),
    ("Sim", "2N_LM", "depth"): (0.149, 0.299, 0.326),
    ("Sim", "R_30", "gt"): (0.105, 0.439, 0.533),
    ("Sim", "R_30", "depth"): (0.134, 0.531, 0.533),
    ("Trip", "N_LM", "gt"): (0.222, 0.222, 0.211),
    ("Trip", "N_LM", "depth"): (0.214, 0.214, 0.211),
    ("Trip", "2N_LM", "gt"): (0.188, 0.376, 0.403),
    ("Trip", "2N_LM", "depth"): (0.173, 0.345, 0.372),
    ("Trip", "R_30", "gt"): (0.142, 0.471, 0.522),
    ("Trip", "R_30", "depth"): (0.137, 0.458, 0.496),
    ("Sim+Trip", "N_LM", "gt"): (0.236, 0.236, 0.269),
    ("Sim+Trip", "N_LM", "depth"): (0.219, 0.219, 0.247),
    ("Sim+Trip", "2N_LM", "gt"): (0.198, 0.396, 0.473),
    ("Sim+Trip", "2N_LM", "depth"): (0.193, 0.385, 0.452),
    ("Sim+Trip", "R_30", "gt"): (0.148, 0.543, 0.600),
    ("Sim+Trip", "R_30", "depth"): (0.139, 0.506, 0.590),
}

#: The accuracy thresholds of Tables 4 and 5: (metres, degrees).
THRESHOLDS: list[tuple[float, float]] = [(0.5, 2.0), (1.0, 5.0), (5.0, 10.0), (10.0, 20.0)]

#: Table 4 (GT-BB proposals) by (model, map type): % under each of THRESHOLDS, median "m"
#: (units x 215), median degrees.
TABLE4 = {
    ("MLP", "gt"): (0.0, 0.5, 10.0, 37.0, 12.5, 13.0),
    ("MLP", "depth"): (0.0, 1.9, 16.6, 36.0, 13.3, 12.9),
    ("MLP+ATT", "gt"): (0.0, 0.0, 13.3, 32.2, 12.8, 14.2),
    ("MLP+ATT", "depth"): (0.0, 0.5, 5.7, 25.6, 15.5, 17.9),
    ("GAT", "gt"): (0.0, 0.0, 3.3, 13.7, 19.0, 22.1),
    ("GAT", "depth"): (0.0, 0.0, 4.7, 17.1, 21.3, 15.9),
    ("GAT+ATT", "gt"): (0.0, 0.0, 8.1, 21.3, 18.2, 14.2),
    ("GAT+ATT", "depth"): (0.0, 0.5, 2.4, 16.1, 19.3, 21.1),
}

#: Table 5 (coarse proposals 2N_LM, its best rows, MLP) by (model, loss, map type): median "m",
#: median degrees.
TABLE5 = {("MLP", "Sim+Trip", "gt"): (25.1, 25.8), ("MLP", "Sim+Trip", "depth"): (25.3, 24.4)}

#: The query time the paper gives for its MLP, seconds.
MLP_QUERY_S = 0.02

#: NOT this paper, another benchmark: OrienterNet (Sarlin et al., CVPR 2023) on its MGL benchmark,
#: the field's recall in %: position within 1 / 3 / 5 m and, apart, heading within 1 / 3 / 5 deg,
#: keyed by threshold. Another task (one image against an OpenStreetMap raster, a 100-200 m
#: location prior, a GPU): quoted beside our recalls for scale, never as a baseline of this task.
ORIENTERNET_MGL_RECALL_M = {1.0: 14.4, 3.0: 48.7, 5.0: 61.7}
ORIENTERNET_MGL_RECALL_DEG = {1.0: 21.0, 3.0: 55.0, 5.0: 70.2}
#: NOT this paper either: OrienterNet's sequential mode on MGL (10 frames of a sequence with their
#: relative poses fused), the same recalls (the issue "Beyond one frame" quotes them); another task
#: as above, quoted beside our sequence rows for scale
ORIENTERNET_MGL_SEQUENTIAL_FRAMES = 10
ORIENTERNET_MGL_SEQUENTIAL_RECALL_M = {1.0: 29.7, 3.0: 73.3, 5.0: 91.2}
ORIENTERNET_MGL_SEQUENTIAL_RECALL_DEG = {1.0: 46.6, 3.0: 88.3, 5.0: 96.5}
