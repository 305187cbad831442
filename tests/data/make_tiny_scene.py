"""Make tests/data/tiny: one synthetic street in the published Flatlandia format, for the fast tests.

    python tests/data/make_tiny_scene.py [--out tests/data/tiny]

Not Flatlandia data: a street of 30 objects and 12 query images, made here with a fixed seed
(the output is the same on every run; tests/test_tiny_scene.py checks the committed copy against
it). Built as the published scenes are built (../shared/DATA.md, "Conventions, verified
numerically"):

- objects are points X of a made-up SfM model (about one metre per unit) pushed through an
  SfM -> lon/lat chain, lonlat = s R2[:2,:2] (Rpp^T X)[:2] + t[:2], whose Rpp is a reflection (as
  in 18 of 20 published scenes) and not symmetric; they are placed on its principal plane (Rpp^T X
  = along the street, across it, up); the chain is written to maps/0/transformations.json, so lon
  and lat are scaled isotropically in degrees;
- a query is a camera on the street looking along it (either way); its GT local map is
  (2/tf) R(-theta) (p_lonlat - camera_lonlat) of the objects it sees (3 to 45 units ahead, at most
  50 degrees off its axis, the 8 nearest), in a shuffled order, theta the heading in lon/lat
  degrees; every object has x > 0;
- its depth local map is the GT map, object by object, with the range times exp(N(0, 0.08)) and
  the bearing turned by N(0, 1.5) degrees, all times one scale per query in [0.002, 0.008] (the
  published depth/GT ratios span 0.001-0.01).

Files: individual_reference_maps/map_0.json, local_maps.json, maps/0/transformations.json,
maps/0/tokens.txt (the query tokens and 8 more images), scenes.tsv, classes.tsv, SOURCE.md and
MANIFEST.tsv (size and sha256 of every other file). No SfM model, class cloud or boxes.
:func:`build` also returns the truth the files do not hold (SfM points, camera poses, which
objects each query sees).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np

SEED = 20240611
SCENE = "0"
CITY = "Flatland"
NAME = "Flatland_Synthetic_Street_0"
N_OBJECTS = 30
N_QUERIES = 12
TO_FLATLANDIA = 0.0033780547666424354  # the published constant (identical in all scenes)
ORIGIN_LONLAT = (11.0, 48.0)  # east-west stretch 1/cos(lat) = 1.49 there (published scenes: 1.28-1.64)
STREET_DEG = 20.0  # direction of the street, CCW from east in lon/lat degrees
DEG_PER_UNIT = 9.0e-6  # chain scale: lon/lat degrees per SfM unit (about 1 m north-south)
#: (class, share) of the objects: sidewalk furniture and road markings (labels of flatlandia.classes)
SIDEWALK = [
    ("object--street-light", 0.3),
    ("object--support--pole", 0.3),
    ("object--traffic-sign", 0.15),
    ("object--trash-can", 0.1),
    ("object--bench", 0.05),
    ("object--fire-hydrant", 0.1),
]
ROADWAY = [("object--manhole", 0.5), ("marking--discrete--arrow--straight", 0.25), ("crosswalk-zebra", 0.25)]
HERE = Path(__file__).resolve().parent


def _classes() -> list[str]:
    from flatlandia.classes import CLASSES

    return list(CLASSES)


def _principal_plane() -> np.ndarray:
    """Rpp: a reflection (det -1) that is not symmetric, so Rpp and Rpp^T put points metres apart."""
    a, b = np.radians(15.0), np.radians(30.0)
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    turn = np.array([[np.cos(b), -np.sin(b), 0.0], [np.sin(b), np.cos(b), 0.0], [0.0, 0.0, 1.0]])
    swap = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    return swap @ tilt @ turn


def chain() -> dict:
    """The SfM -> lon/lat chain of the tiny scene, in the published transformations.json layout."""
    a = np.radians(STREET_DEG)
    r2 = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return {
        "to_principal_plane": _principal_plane().tolist(),
        "to_mapillary": {
            "rotation": r2.tolist(),
            "scaling_factor_sfm_to_gps": DEG_PER_UNIT,
            "translation": [[ORIGIN_LONLAT[0], ORIGIN_LONLAT[1], 0.0]],
        },
        "to_flatlandia": TO_FLATLANDIA,
    }


def to_sfm(plane: np.ndarray, t: dict) -> np.ndarray:
    """SfM points X (N, 3) whose principal-plane coordinates Rpp^T X are ``plane`` (along the
    street, across it, up)."""
    return np.asarray(plane, float) @ np.asarray(t["to_principal_plane"]).T


def to_lonlat(points: np.ndarray, t: dict) -> np.ndarray:
    """DATA.md's chain in column form: lonlat = s R2[:2,:2] (Rpp^T X)[:2] + t[:2]."""
    rpp = np.asarray(t["to_principal_plane"])
    r2 = np.asarray(t["to_mapillary"]["rotation"])
    s = t["to_mapillary"]["scaling_factor_sfm_to_gps"]
    tr = np.asarray(t["to_mapillary"]["translation"]).reshape(-1)[:2]
    return np.array([s * r2[:2, :2] @ (rpp.T @ x)[:2] + tr for x in np.asarray(points, float)])


def _rot(theta: float) -> np.ndarray:
    return np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])


def _objects(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The street's objects on the principal plane (N, 3: along, across, up) and their classes:
    both sidewalks and the roadway, at least 2.5 units apart."""
    labels = _classes()
    kinds = [(+7.5, SIDEWALK)] * 11 + [(-7.5, SIDEWALK)] * 11 + [(0.0, ROADWAY)] * 8
    pts, cls = [], []
    for side, table in kinds:
        ids, shares = [labels.index(name) for name, _ in table], [share for _, share in table]
        while True:
            along = rng.uniform(0.0, 150.0)
            across = side + rng.normal(0.0, 0.6) if side else rng.uniform(-3.5, 3.5)
            if all(np.hypot(along - p[0], across - p[1]) >= 2.5 for p in pts):
                break
        pts.append((along, across, rng.uniform(0.0, 6.0) if side else 0.0))
        cls.append(int(rng.choice(ids, p=np.asarray(shares) / sum(shares))))
    return np.array(pts), np.array(cls)


def build(seed: int = SEED) -> dict:
    """Everything the tiny scene holds, and the truth behind it (not written to the files)."""
    rng = np.random.default_rng(seed)
    t = chain()
    plane, classes = _objects(rng)
    sfm = to_sfm(plane, t)
    lonlat = to_lonlat(sfm, t)
    unit_deg = TO_FLATLANDIA / 2.0
    deg_per_sfm = DEG_PER_UNIT  # lon/lat degrees per SfM unit, in every direction
    queries = []
    while len(queries) < N_QUERIES:
        along = rng.uniform(0.0, 150.0)
        backwards = bool(rng.integers(2))
        centre = np.array([along, rng.uniform(-2.0, 2.0), 1.5])
        look = np.radians(rng.normal(180.0 if backwards else 0.0, 8.0))
        ahead = centre + np.array([np.cos(look), np.sin(look), 0.0])
        cam_ll, ahead_ll = to_lonlat(to_sfm(np.array([centre, ahead]), t), t)
        theta = float(np.arctan2(*(ahead_ll - cam_ll)[::-1]))  # CCW from east, lon/lat degrees
        local = (lonlat - cam_ll) @ _rot(theta) / unit_deg  # R(-theta) (p - c), in local units
        rng_sfm = np.linalg.norm(local, axis=1) * unit_deg / deg_per_sfm
        bearing = np.degrees(np.arctan2(local[:, 1], local[:, 0]))
        seen = np.flatnonzero((rng_sfm >= 3.0) & (rng_sfm <= 45.0) & (np.abs(bearing) <= 50.0))
        seen = seen[np.argsort(rng_sfm[seen], kind="stable")][:8]
        if len(seen) < 3:
            continue
        seen = rng.permutation(seen)  # the published maps list objects in no particular order
        gt = local[seen]
        r = np.linalg.norm(gt, axis=1) * np.exp(rng.normal(0.0, 0.08, len(seen)))
        b = np.arctan2(gt[:, 1], gt[:, 0]) + np.radians(rng.normal(0.0, 1.5, len(seen)))
        depth = rng.uniform(0.002, 0.008) * np.column_stack([r * np.cos(b), r * np.sin(b)])
        token = str(rng.integers(10**14, 10**15))
        queries.append(
            dict(
                token=token,
                objects=seen.tolist(),
                lonlat=cam_ll,
                theta=theta,
                sfm=to_sfm(centre[None], t)[0],
                gt=gt,
                depth=depth,
            )
        )
    extra_tokens = [str(rng.integers(10**14, 10**15)) for _ in range(8)]  # images that are no query
    return dict(transformations=t, sfm=sfm, lonlat=lonlat, classes=classes, queries=queries, extra_tokens=extra_tokens)


def files(scene: dict) -> dict[str, str]:
    """The text of every file of the tiny data folder, by path relative to it (MANIFEST.tsv last)."""
    labels = _classes()
    ref = [[[float(lon), float(lat)], int(c)] for (lon, lat), c in zip(scene["lonlat"], scene["classes"])]
    local = {SCENE: {q["token"]: {"GT": q["gt"].tolist(), "depth": q["depth"].tolist()} for q in scene["queries"]}}
    tokens = [q["token"] for q in scene["queries"]] + scene["extra_tokens"]
    out = {
        f"individual_reference_maps/map_{SCENE}.json": json.dumps(ref) + "\n",
        "local_maps.json": json.dumps(local) + "\n",
        f"maps/{SCENE}/transformations.json": json.dumps(scene["transformations"]) + "\n",
        f"maps/{SCENE}/tokens.txt": "\n".join(tokens) + "\n",
        "scenes.tsv": f"scene\tcity\tname\n{SCENE}\t{CITY}\t{NAME}\n",
        "classes.tsv": "class_id\tmapillary_label\n" + "".join(f"{k}\t{c}\n" for k, c in enumerate(labels)),
        "SOURCE.md": (
            "# Tiny synthetic scene (not Flatlandia data)\n\n"
            f"One made-up street of {N_OBJECTS} objects and {N_QUERIES} queries in the published Flatlandia\n"
            "format, for the fast tests. Generated by `python tests/data/make_tiny_scene.py`\n"
            f"(seed {SEED}; its docstring says how): do not edit by hand, run the script again.\n"
        ),
    }
    rows = []
    for path in sorted(out):
        data = out[path].encode()
        rows.append(f"{path}\t{len(data)}\t{hashlib.sha256(data).hexdigest()}\n")
    out["MANIFEST.tsv"] = "path\tbytes\tsha256\n" + "".join(rows)
    return out


def write(dest: Path, seed: int = SEED) -> list[Path]:
    dest = Path(dest)
    written = []
    for rel, text in files(build(seed)).items():
        path = dest / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE / "tiny", help="data folder to write (default: %(default)s)")
    args = parser.parse_args(argv)
    paths = write(args.out)
    print(f"wrote {len(paths)} files under {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
