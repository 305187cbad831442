"""Command line: ``flatlandia audit [PATH]`` prints the audit trail of a run (one artifact, one scene or all);
``flatlandia config`` checks or rewrites the files generated from the config schema;
``flatlandia debug RULE key=value ...`` runs one rule's script in this process (flatlandia.plumbing.debug);
``flatlandia localize --map MAP --query QUERY.json`` localizes your own query (flatlandia.localize; or
``--sequence FRAMES.json`` several frames together; ``--image PHOTO`` a photo, made into a query by the
configured segmentation and depth backends; ``--gps LON,LAT --gps-sigma-m M`` a phone's fix;
``--plot FILE.png`` the answer drawn on its map; ``--batch RESULTS --out POSES.csv`` a whole split);
``flatlandia score POSES --name NAME --out DIR`` scores your own poses as the benchmark's methods (flatlandia.score)."""

from __future__ import annotations

import argparse
import os
import sys

from flatlandia import __version__, release, vocabulary
from flatlandia.commands import audit_command, config_command, debug_command, localize_command, score_command
from flatlandia.plumbing import provenance


def parser() -> argparse.ArgumentParser:
    """The whole command line in one place: each command's options, help and the function of
    flatlandia.commands that does its work (``args.func``)."""
    ap = argparse.ArgumentParser(prog="flatlandia", description=__doc__)
    ap.add_argument("--version", action="version", version=f"flatlandia {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    _audit_options(sub)
    _config_options(sub)
    _debug_options(sub)
    _localize_options(sub)
    _score_options(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status (1 when the reader of its output left: ``| head``)."""
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except BrokenPipeError:  # the reader left (`| head`): no traceback, and none at exit either
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


def _audit_options(sub) -> None:
    """audit's options: one artifact, one scene or all; --tree, --check, --write."""
    a = sub.add_parser("audit", help="print which rule, inputs, settings and commit produced each artifact")
    a.add_argument("artifact", nargs="?", help="one artifact: its rule, settings by value, inputs and their rules")
    a.add_argument("--tree", action="store_true", help="with PATH: follow the inputs back to the source files")
    a.add_argument(
        "--check",
        action="store_true",
        help="re-hash every recorded artifact (with PATH: that one; with --scene: that scene's) and name those changed",
    )
    a.add_argument("--scene", help="only this scene's artifacts")
    a.add_argument("--manifest", default="results/manifest.parquet")
    a.add_argument("--provenance", default=str(provenance.PROVENANCE_DIR))
    a.add_argument("--write", metavar="FILE", help="write the records as a manifest (Parquet) instead of printing")
    a.set_defaults(func=audit_command.audit)


def _config_options(sub) -> None:
    """config's options: check, or --write, the files of --repo."""
    c = sub.add_parser("config", help="check (or --write) the config files generated from the schema")
    c.add_argument("--write", action="store_true", help="rewrite them instead of checking")
    c.add_argument(
        "--repo", default=str(release.PYPROJECT.parent), help="repository root (default: this package's clone)"
    )
    c.set_defaults(func=config_command.config_files)


def _debug_options(sub) -> None:
    """debug's options: the rule, its wildcards and the config, as snakemake takes them."""
    d = sub.add_parser(
        "debug",
        help="run one rule's script in this process (breakpoints and print work)",
        description="Build the job of RULE for the given wildcards from the workflow (default config, then "
        "--configfile and --config as for snakemake), print its input/output/params/log, then run the rule's "
        "script in this Python process in the working folder. Its inputs must exist (run snakemake first).",
    )
    d.add_argument("rule", help="rule name, e.g. reference_map")
    d.add_argument("wildcards", nargs="*", metavar="key=value", help="the job's wildcards, e.g. scene=12")
    d.add_argument("-d", "--directory", default=".", help="the workflow's working folder (default: here)")
    d.add_argument("--configfile", nargs="*", default=[], help="config files over config/config.yaml")
    d.add_argument("--config", nargs="*", default=[], metavar="KEY=VALUE", help="config overrides, as snakemake's")
    d.add_argument("--snakefile", default=None, help="default: this package's workflow/Snakefile")
    d.add_argument("--cores", type=int, default=1, help="caps the job's threads, as snakemake --cores (default 1)")
    d.add_argument("--show", action="store_true", help="only print the job, run nothing")
    d.add_argument("--log-to-terminal", action="store_true", help="log to stderr instead of the rule's log file")
    d.add_argument("--pdb", action="store_true", help="open pdb where the script fails")
    d.set_defaults(func=debug_command.debug_rule)


def _localize_options(sub) -> None:
    """localize's options: what is localized (a query, a sequence, a photo, a split) on which map."""
    lq = sub.add_parser(
        "localize",
        help="localize your own query: a camera pose from the objects one image sees, on a map",
        description='Localize the query of a JSON file ({"objects": [{"class": "<Vistas label>", "x": forward, '
        '"y": left}, ...]}, or {"queries": [{"id": ..., "objects": [...]}, ...]}) on a scene\'s reference map '
        "(.parquet, .geojson: the workflow's, with its training cameras and learned priors, or any map of classed "
        "points with lon/lat) or a city index (results/city/{n}/index or one of its .npz); print the pose(s) as JSON "
        "(flatlandia.localize). Optionally a phone's GPS fix (--gps, --gps-sigma-m) and compass (--compass, "
        '--compass-sigma-deg), or a sequence of depth frames ({"frames": [{"objects": [...]}, {"objects": [...], '
        '"pose": {"x": forward m, "y": left m, "theta_deg": turn}}, ...]}: each later frame\'s pose in the first '
        "frame's camera frame, from odometry) localized together: the first frame's pose and every frame's. Or a photo "
        "(--image, with the segmentation and depth backends of --configfile: docs/backends.md), made into a query.",
    )
    lq.add_argument(
        "--map",
        help="reference map (.parquet, .geojson) or city index (folder, .npz); with --batch: a city index (default: "
        "each query's scene map)",
    )
    lq.add_argument(
        "--batch",
        metavar="SOURCE",
        help="localize every query of a split of an export (results/export) or a finished run (results) on its "
        "scene's map (or on the city index of --map) and write the poses file of --out, in the shape flatlandia "
        "score reads (map type default depth)",
    )
    lq.add_argument("--split", default="test", choices=["train", "val", "test"], help="with --batch (default: test)")
    lq.add_argument(
        "--proposal",
        default=vocabulary.WHOLE,
        help=f"with --batch: the map region each query searches: {vocabulary.WHOLE} (default), {vocabulary.GTBB} (the "
        f"oracle box) or {', '.join(vocabulary.COARSE_PROPOSALS)} (a coarse stage's proposals), as rule fine_eval",
    )
    lq.add_argument(
        "--fixes",
        metavar="FILE.csv",
        help="with --batch: a GPS fix per query (columns scene, token, lon, lat, sigma_m; optional compass_deg, "
        "compass_sigma_deg); queries without a row get none",
    )
    lq.add_argument("--query", help='query JSON: one query, or {"queries": [...]} (or give --sequence)')
    lq.add_argument(
        "--sequence",
        metavar="FILE.json",
        help='instead of --query: frames localized together, {"frames": [...]} (depth local maps)',
    )
    lq.add_argument(
        "--image",
        metavar="PHOTO",
        help="instead of --query: a photo (JPEG, PNG, TIFF), made into a depth query as the images branch sees "
        "objects: the configured segmentation's object classes, the depth model's ranges, the EXIF camera's "
        "bearings (learned backends with local weights: docs/backends.md)",
    )
    lq.add_argument(
        "--configfile",
        metavar="FILE",
        help="with --image: a config file (YAML or JSON, as snakemake --configfile) whose segment, images.depth, "
        "images.photo and device settings make the photo's query (default: the schema's defaults)",
    )
    lq.add_argument(
        "--map-type",
        default=None,
        help="gt: x/y in metres (the default for --query); depth: any unit, scale unknown (the default, and the "
        "only type, for --sequence and --image)",
    )
    _localize_prior_options(lq)
    lq.set_defaults(func=localize_command.localize_query)


def _localize_prior_options(lq) -> None:
    """localize's options of what else is known (a position, a GPS fix, a compass, learned priors) and
    of the answer (its alternatives, --out, --plot)."""
    from flatlandia.localize import ALTERNATIVES  # the library's default, said once (light: no solver)

    lq.add_argument("--near", metavar="LON,LAT", help="a prior position: search only the map objects near it")
    lq.add_argument("--radius-m", metavar="R", help="with --near: the radius searched, metres")
    lq.add_argument(
        "--gps",
        metavar="LON,LAT",
        help="a GPS fix of the camera (of the sequence's first frame), weighed as a Gaussian likelihood; "
        "a western longitude as --gps=-0.12,51.5",
    )
    lq.add_argument("--gps-sigma-m", metavar="M", help="with --gps: the fix's sigma in metres (east and north)")
    lq.add_argument("--compass", metavar="DEG", help="with --gps: a compass heading, degrees clockwise from north")
    lq.add_argument("--compass-sigma-deg", metavar="S", help="with --compass: its sigma in degrees")
    lq.add_argument(
        "--alternatives",
        default=str(ALTERNATIVES),
        metavar="K",
        help=f"next-best distinct poses (default {ALTERNATIVES})",
    )
    lq.add_argument(
        "--priors",
        default="auto",
        metavar="auto|none|FILE",
        help="depth maps' learned priors: auto (the workflow's results/solver/priors/whole.json for its maps), "
        "none, or a priors JSON",
    )
    lq.add_argument(
        "--out", metavar="OUT.json", help="also write the JSON here; with --batch: the poses file (.csv, .parquet)"
    )
    lq.add_argument(
        "--plot",
        metavar="FILE.png",
        help="also draw the answer on its map (.png or .svg): the map's objects by class, the pose, the query's rays, "
        "the alternatives, the status and probability (needs matplotlib: the extra plot)",
    )


def _score_options(sub) -> None:
    """score's options: the poses file, the method's name, --out and the results folder scored against."""
    sc = sub.add_parser(
        "score",
        help="score your own poses of the benchmark's queries, as the built-in methods are scored",
        description="Score a poses file (CSV or Parquet; one row per query: scene, token and either x_m, y_m, "
        "theta_deg in the scene's metric frame or lon, lat, heading_deg with a compass heading; optional map_type, "
        "proposal, seconds: docs/usage.md 'Score your own method') against the benchmark of a results folder, with the "
        "functions of rule fine_eval. Writes OUT/{NAME}_{map_type}_{proposal}/errors.parquet and summary.json per "
        "setting and OUT/scores.md (its rows beside the built-in rows of the same setting); queries without a pose "
        "count as failures.",
    )
    sc.add_argument("poses", help="the poses file (.csv or .parquet)")
    sc.add_argument("--name", required=True, help="the method's name: a lowercase id, not a built-in method's")
    sc.add_argument("--out", required=True, metavar="DIR", help="where the runs and scores.md go")
    sc.add_argument("--results", default="results", metavar="RESULTS_DIR", help="the workflow's results folder")
    sc.add_argument("--split", default="test", choices=["train", "val", "test"], help="queries scored (default: test)")
    sc.set_defaults(func=score_command.score_poses)


if __name__ == "__main__":
    raise SystemExit(main())
