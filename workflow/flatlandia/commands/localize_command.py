"""``flatlandia localize``: a user's query (``--query``), sequence (``--sequence``) or photo
(``--image``) localized on a map, the answer printed as JSON (``--out``: written too; ``--plot``: drawn
on its map), or a whole split into one poses file (``--batch``). The options are checked here, in the
order the command reads them, before the map loads; the work is flatlandia.localize's."""

from __future__ import annotations

import math

from flatlandia import config
from flatlandia.commands.messages import error, warning
from flatlandia.commands.out_option import refuse_overwriting, run_artifacts, write_out
from flatlandia.plumbing import files, validate
from flatlandia.plumbing.errors import InputError


def _numbers_of(flag: str, value: str, n: int, what: str) -> tuple[float, ...]:
    """``n`` comma-separated finite numbers of a flag's value; InputError naming the flag otherwise."""
    try:
        out = tuple(float(v) for v in str(value).split(","))
    except ValueError:
        out = ()
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise InputError(flag, f"{value!r} is not {what}")
    return out


def _prior_args(args) -> tuple[tuple | None, tuple | None]:
    """(gps (lon, lat, sigma_m) or None, compass (heading_deg, sigma_deg) or None) of the command's
    --gps/--gps-sigma-m and --compass/--compass-sigma-deg (each pair given together); their ranges
    are checked by flatlandia.localize."""
    gps = compass = None
    if (args.gps is None) != (args.gps_sigma_m is None):
        raise InputError("--gps", "a GPS fix needs both --gps LON,LAT and --gps-sigma-m M")
    if args.gps is not None:
        lon, lat = _numbers_of("--gps", args.gps, 2, "LON,LAT (degrees, e.g. 2.3704,48.8981)")
        (sigma,) = _numbers_of("--gps-sigma-m", args.gps_sigma_m, 1, "a number of metres")
        gps = (lon, lat, sigma)
    if (args.compass is None) != (args.compass_sigma_deg is None):
        raise InputError("--compass", "a compass heading needs both --compass DEG and --compass-sigma-deg S")
    if args.compass is not None:
        (heading,) = _numbers_of("--compass", args.compass, 1, "a heading in degrees (clockwise from north)")
        (hsig,) = _numbers_of("--compass-sigma-deg", args.compass_sigma_deg, 1, "a number of degrees")
        compass = (heading, hsig)
    return gps, compass


def _priors_file(priors: str | None) -> str | None:
    """The priors JSON a command reads (None for auto and none)."""
    return None if priors in (None, "auto", "none") else priors


def localize_batch(args) -> int:
    """Localize every query of a split of an export or a results folder (--batch) and write the
    poses file that `flatlandia score` reads."""

    from flatlandia.localize import batch

    try:
        if (
            args.query
            or args.sequence
            or args.image
            or args.configfile
            or args.near
            or args.gps
            or args.compass
            or args.plot
        ):
            raise InputError(
                "--batch",
                "localizes a whole split: give no --query, --sequence, --image, --configfile, --near, --gps, --compass "
                "or --plot "
                "(a fix per query: --fixes FILE.csv; --plot draws one query's answer)",
            )
        if not args.out:
            raise InputError("--batch", "needs --out POSES.csv (or .parquet): the poses file flatlandia score reads")
        batch.check_out(args.out)
        reads = [args.batch, args.map, args.fixes, _priors_file(args.priors)]
        refuse_overwriting(args.out, reads)
        fixes = batch.read_fixes(args.fixes) if args.fixes else None
        learned = {"auto": "auto", "none": None}.get(args.priors, args.priors)
        result = batch.localize_batch(
            args.batch,
            args.split,
            args.map_type or "depth",
            args.map,
            fixes,
            learned,
            progress=True,
            proposal=args.proposal,
        )
    except InputError as e:
        error(str(e))
        return 1
    if not write_out(lambda: batch.write_poses(result, args.out, reads=reads, artifacts=run_artifacts()), args.out):
        return 1
    for note in result.notes:
        print(f"note: {note}")
    for w in result.warnings:
        warning(str(w))
    print(result.describe())
    print(f"wrote {args.out}: score it with `flatlandia score {args.out} --name NAME --out DIR`")
    return 0


def localize_query(args) -> int:
    """Localize the query (or queries, or a sequence) of a JSON file on a map; print the answer as JSON."""
    from flatlandia import localize

    if args.batch:
        return localize_batch(args)
    try:
        if args.fixes:
            raise InputError("--fixes", "a fix per query is for --batch; one query takes --gps and --gps-sigma-m")
        if not args.map:
            raise InputError("--map", "which map: a reference map (.parquet, .geojson) or a city index (folder, .npz)")
        near = None
        if args.near is not None:
            near = _numbers_of("--near", args.near, 2, "LON,LAT (degrees, e.g. 2.3704,48.8981)")
        radius = None
        if args.radius_m is not None:
            (radius,) = _numbers_of("--radius-m", args.radius_m, 1, "a number of metres")
        if (near is None) != (radius is None):
            raise InputError("--near", "a prior position needs both --near LON,LAT and --radius-m R")
        try:
            alternatives = int(args.alternatives)
        except ValueError:
            raise InputError("--alternatives", f"{args.alternatives!r} is not a whole number") from None
        if alternatives < 0:
            raise InputError("--alternatives", f"{alternatives} is negative")
        gps, compass = _prior_args(args)
        reads = [args.query, args.sequence, args.image, args.configfile, args.map, _priors_file(args.priors)]
        if args.out:
            refuse_overwriting(args.out, reads)
        drawn = _plot_query(args, reads)
        photo = _photo_query(args, gps, compass)
        if photo is not None and args.plot:
            drawn = photo[0]
        learned = {"auto": "auto", "none": None}.get(args.priors, args.priors)
        loaded = drawn is not None or photo is not None
        m = localize.load_map(args.map, learned=learned) if loaded else args.map  # drawn on, too
        if photo is not None:  # a photo's query is one depth query, localized as --query's
            result = localize.localize(m, photo[0], "depth", near, radius, alternatives, gps, compass)
            result["photo"] = photo[1]
        else:
            result = localize.localize_file(
                m,
                args.query,
                args.map_type,
                near,
                radius,
                alternatives,
                gps=gps,
                compass=compass,
                sequence_path=args.sequence,
                learned=learned,
            )
    except InputError as e:
        error(str(e))
        return 1
    _print_warnings(result)
    text = localize.dumps(result)
    if args.out and not write_out(
        lambda: files.write_text(text + "\n", args.out, reads=reads, artifacts=run_artifacts()), args.out
    ):
        return 1
    if drawn is not None and not write_out(lambda: _write_plot(args, m, drawn, result, reads), args.plot, "--plot"):
        return 1
    print(text)
    return 0


def _plot_query(args, reads: list):
    """The query whose answer --plot draws (a sequence's anchor frame), read and checked before the
    map loads, with the plot's file (PNG or SVG, matplotlib installed, a place the write door
    allows); None without --plot, and for --image (its query is made next, :func:`_photo_query`).
    InputError for a file of several queries: a plot is one answer."""
    if not args.plot:
        return None
    from flatlandia import localize
    from flatlandia.localize import answer_figure

    answer_figure.check_plot(args.plot)
    try:
        refuse_overwriting(args.plot, [*reads, args.out])
    except InputError as e:
        raise InputError("--plot", e.problem) from None
    if args.image:
        return None
    if args.sequence:
        return localize.read_sequence(args.sequence).frames[0]
    if not args.query:
        return None  # localize_file says what is missing
    queries, _ = localize.read_queries(args.query)
    if len(queries) != 1:
        raise InputError("--plot", f"draws one answer: {args.query} holds {len(queries)} queries (give a file of one)")
    return queries[0]


def _photo_query(args, gps, compass):
    """--image: (the photo's depth query, the record of how it was made), by the segmentation and depth
    backends of --configfile (read and checked as the workflow reads a config file; without it the
    schema's defaults, whose segmentation labels no object: one ERROR line naming docs/backends.md);
    None without --image. The other inputs are checked first: the models take seconds."""
    from flatlandia import localize

    if not args.image:
        if args.configfile:
            raise InputError("--configfile", "holds the settings of --image (segment, images.depth, images.photo)")
        return None
    if args.query or args.sequence:
        raise InputError(
            "--image", "give a query file (--query), a sequence (--sequence) or a photo (--image), one of them"
        )
    if args.map_type not in (None, "depth"):
        raise InputError("--map-type", "a photo's query is a depth local map (its depths are up to scale): depth")
    localize.check_prior(gps, compass)
    settings = None
    if args.configfile:
        settings = validate.read_config(args.configfile)
        try:
            config.resolve(settings)
        except config.ConfigError as e:
            raise InputError(args.configfile, str(e)) from None
    return localize.read_photo(args.image, settings)


def _write_plot(args, m, query, result: dict, reads: list) -> None:
    """--plot: the answer drawn on its map (flatlandia.localize.answer_figure)."""
    from flatlandia.localize import answer_figure

    answer = result["results"][0] if "results" in result else result
    answer_figure.write_answer_figure(m, query, answer, args.plot, reads=[*reads, args.out], artifacts=run_artifacts())


def _print_warnings(result: dict) -> None:
    """The answers' warnings (a fix that looks swapped or off the map) as WARNING lines on stderr,
    each once: stdout carries the JSON."""
    answers = result["results"] if "results" in result else [result]
    for w in dict.fromkeys(w for a in answers for w in a.get("warnings", [])):
        warning(str(w))
