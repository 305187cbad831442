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
import json
import math
import os
import sys
from pathlib import Path

import pandas as pd

from flatlandia import __version__, config, release, vocabulary
from flatlandia.plumbing import escape, files, provenance, validate
from flatlandia.plumbing.errors import InputError


def _error(text: str) -> None:
    """An ``ERROR:`` line, on stderr: a result on stdout redirected into a file never hides one. Its
    text quotes files (names, values), so it is escaped for the terminal (:func:`escape.terminal`:
    one line, no ESC or bidi override of a file's reaching the terminal)."""
    print(f"ERROR: {escape.terminal(text)}", file=sys.stderr)


def _warning(text: str) -> None:
    """A ``WARNING:`` line, on stderr beside the errors (escaped as :func:`_error`'s)."""
    print(f"WARNING: {escape.terminal(text)}", file=sys.stderr)


def _records(args) -> pd.DataFrame:
    """The live provenance records (they describe the latest run, whatever its target), without
    those of outputs since deleted; the manifest is the fallback for a results folder copied
    without its logs."""
    skipped: list[str] = []
    df = provenance.manifest(args.provenance, skipped)
    for line in skipped:  # a broken or tampered record: said, and the others audited
        _warning(str(line))
    if not df.empty:
        df = df[[Path(a).exists() for a in df["artifact"]]]
    path = Path(args.manifest)
    if df.empty and path.exists():  # checked row by row: a copied manifest is as easily edited as a record
        skipped = []
        df = provenance.read_manifest(path, skipped)
        for line in skipped:
            _warning(line)
    if not df.empty:  # only what lies inside this run's folder is ever hashed
        inside = [provenance.in_run(a) for a in df["artifact"]]
        for a in df.loc[[not i for i in inside], "artifact"]:
            _warning(f"{str(a)[:200]}: an artifact outside the run's folder, left out of the audit")
        df = df[inside]
    return df


def _short(digest: str) -> str:
    return str(digest or "")[:12]


def _flat(d: dict, prefix: str = "") -> dict:
    """Nested settings as dotted keys, one value each."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        out.update(_flat(v, key) if isinstance(v, dict) and v else {key: v})
    return out


def audit_artifact(df: pd.DataFrame, artifact: str, tree: bool, configs: Path) -> str:
    """What produced one artifact, as text: rule, settings by value, inputs and their rules (each line
    escaped for the terminal: :func:`escape.terminal`)."""
    rows = provenance.producers(df)
    rec = rows.get(artifact)
    if rec is None:
        return ""
    now, _ = provenance.path_digest(artifact)
    lines = [
        f"artifact: {artifact}",
        f"  sha256 {_short(rec['sha256'])}, {int(rec['bytes']):,} bytes, "
        + ("the file matches its record" if now == rec["sha256"] else "CHANGED since the run wrote it"),
        f"rule: {rec['rule']}" + (f"  (wildcards {rec['wildcards']})" if rec["wildcards"] not in ("{}", "") else ""),
        f"settings the rule reads (hash {rec['config_hash']}):",
    ]
    settings = json.loads(rec.get("settings") or "{}")
    lines += [f"  {k}: {json.dumps(v, default=str)}" for k, v in _flat(settings).items()] or ["  (none)"]
    if rec.get("config_id"):
        lines.append(f"whole resolved config: {configs / (rec['config_id'] + '.json')}")
    dirty = rec.get("dirty")
    lines.append(
        f"code: commit {rec['git_commit'].removesuffix('+dirty')}"
        + (" with uncommitted changes" if dirty else " (clean)" if dirty is False else "")
        + f", flatlandia {rec['package_version']}"
    )
    sheet = json.loads(rec.get("scene_sheet") or "{}")
    if sheet.get("path"):
        lines.append(f"scene sheet: {sheet['path']} (sha256 {_short(sheet.get('sha256', ''))})")
    software = json.loads(rec.get("software") or "{}")
    if software:
        lines.append("software: " + ", ".join(f"{k} {v}" for k, v in software.items()))
    if rec.get("started_at"):
        lines.append(
            f"time: {rec['started_at']} to {rec['finished_at']}, "
            f"{rec.get('wall_seconds', float('nan')):.1f} s wall, {rec.get('cpu_seconds', float('nan')):.1f} s CPU"
        )
    lines.append("inputs" + (" (back to the files no rule produced: the sources)" if tree else "") + ":")
    if tree:  # each subtree once, shared ones referred back to
        lines += ["  " * depth + text for depth, text in provenance.lineage_tree(artifact, df)]
    else:
        for inp in provenance.lineage(artifact, df, tree):
            pad = "  " * inp["depth"]
            made = f"<- {inp['rule']}" if inp["rule"] else "(source)"
            flag = "  CHANGED since used" if inp["changed"] else ""
            lines.append(f"{pad}{inp['input']}  {_short(inp['sha256'])}  {made}{flag}")
    return "\n".join(escape.terminal(line) for line in lines)  # each line of names and values from records


def _run_relative(artifact: str) -> str:
    """An artifact as the records name it: relative to the run's folder (the working folder), also
    when given as an absolute path inside it (a shell's completion, a file manager's copy)."""
    path = Path(artifact)
    if path.is_absolute() or ".." in path.parts or path.is_symlink() or any(p.is_symlink() for p in path.parents):
        try:  # resolved: results/../results/x and a link into results/ name the record's artifact
            path = path.resolve().relative_to(Path.cwd().resolve())
        except (OSError, ValueError):  # outside the run's folder: no record names it
            pass
    return str(path)


def audit(args) -> int:
    try:
        df = _records(args)
    except InputError as e:  # the manifest fallback is not a manifest
        _error(str(e))
        return 1
    if df.empty:
        _error(
            f"no audit records in {Path.cwd()}: run flatlandia audit in the run's folder, or run the workflow "
            f"first ({args.manifest} and {args.provenance} are empty)"
        )
        return 1
    made_by = dict(zip(df["artifact"], df["rule"]))  # every recorded artifact, before --scene narrows df
    if args.check:  # every recorded artifact re-hashed
        bad = provenance.check(df)
        if bad.empty:
            print(f"all {len(df)} recorded artifacts match their records")
            return 0
        print(f"{len(bad)} of {len(df)} recorded artifacts changed since their rule wrote them:")
        for r in bad.itertuples(index=False):
            line = f"  {r.artifact} (rule {r.rule}): recorded {_short(r.recorded)}, now {_short(r.now)}"
            print(escape.terminal(line))
        return 1
    if args.artifact:
        text = audit_artifact(df, _run_relative(args.artifact), args.tree, Path(args.provenance) / "configs")
        if not text:
            near = [a for a in df["artifact"] if Path(a).name == Path(args.artifact).name][:5]
            _error(
                f"{args.artifact}: no audit record (not an output of this run's rules, or built before "
                "records existed)" + (f"; recorded artifacts of that name: {', '.join(near)}" if near else "")
            )
            return 1
        print(text)
        return 0
    if args.scene:
        known = sorted(set(df["scene"].dropna().astype(str)) - {""})
        df = df[df["scene"] == args.scene]
        if df.empty:
            _error(f"no audit records for scene {args.scene!r}; scenes with records: {', '.join(known)}")
            return 1
    if args.write:  # the manifest of any run, whatever its target (rule manifest comes with `all`)
        return _write_manifest(args, df, made_by)
    cols = ["artifact", "rule", "sha256", "bytes", "config_hash", "git_commit", "finished_at"]
    with pd.option_context("display.max_rows", None, "display.max_colwidth", 64, "display.width", 250):
        out = df[cols].assign(sha256=df["sha256"].str[:12])
        out = out.map(lambda v: escape.terminal(v) if isinstance(v, str) else v)  # names from the records
        print(out.to_string(index=False))
    print("\nflatlandia audit PATH shows one artifact's settings and inputs (--tree: back to the sources)")
    return 0


def _write_manifest(args, df: pd.DataFrame, made_by: dict[str, str]) -> int:
    """``audit --write FILE``: the records as a manifest, through the write door
    (:func:`files.check_target`), never onto a file the audit reads (the manifest, the records) nor
    onto or into an artifact any record names (compared resolved: ``results/../results/x`` and a
    link to ``results/`` are the artifact itself): its manifest would break the run it audits."""
    named = {a: r["rule"] for r in provenance.records(args.provenance) for a in r["outputs"]} | made_by
    target = files.resolved(args.write)
    rule = next((r for a, r in named.items() if target.is_relative_to(os.path.realpath(a))), None)
    if rule is not None:
        _error(f"--write {args.write}: an artifact of this run (rule {rule}): give a new file")
        return 1
    try:
        files.write_parquet(
            df.reset_index(drop=True), args.write, reads=[args.manifest, args.provenance], artifacts=named
        )
    except InputError as e:
        _error(f"--write {e}")
        return 1
    except OSError as e:  # a full disk, a folder that cannot be made
        _error(f"--write {args.write}: cannot be written ({e.strerror or e})")
        return 1
    print(f"wrote {args.write}: {len(df)} artifacts from {df['rule'].nunique()} rules")
    return 0


def config_files(args) -> int:
    """Rewrite (``--write``) or check config/config.yaml and config/README.md against the schema."""
    if release.pyproject_version(Path(args.repo) / "pyproject.toml") is None:
        _error(f"{args.repo} is not a clone of the workflow (no flatlandia pyproject.toml): give --repo")
        return 1
    stale, fresh = [], []
    for path, text in config.generated_files(Path(args.repo)).items():
        if path.exists() and path.read_text() == text:
            fresh.append(str(path))
            continue
        if args.write:
            path.write_text(text)
            print(f"wrote {path}")
        else:
            stale.append(str(path))
    if stale:
        _error(f"{', '.join(stale)} out of date with {config.SCHEMA_PATH}: run `flatlandia config --write`")
        return 1
    if fresh:  # a check that passes says so (it printed nothing)
        print(f"{', '.join(fresh)}: up to date with {config.SCHEMA_PATH}")
    return 0


def debug_rule(args) -> int:
    """Build one job of the workflow and run its script here (``--show``: only print the job)."""
    from snakemake.cli import parse_config

    from flatlandia.plumbing import debug

    wildcards = {}
    for item in args.wildcards:
        key, sep, value = item.partition("=")
        if not sep or not key:
            _error(f"wildcard {item!r}: expected key=value, e.g. scene=12")
            return 2
        wildcards[key] = value
    try:
        smk = debug.mock_snakemake(
            args.rule,
            workdir=args.directory,
            configfiles=args.configfile,
            config=parse_config(args.config),
            snakefile=args.snakefile,
            cores=args.cores,
            **wildcards,
        )
    except debug.DebugError as e:
        _error(str(e))
        return 2
    if args.log_to_terminal:
        smk.log = type(smk.log)()  # no log file: the script's logger writes to stderr
    print("\n".join(map(escape.terminal, debug.describe(smk).split("\n"))), flush=True)  # config values
    if args.show:
        return 0
    print(f"running {smk.script.name} in this process ...", flush=True)
    try:
        debug.run_script(smk)
    except debug.DebugError as e:
        _error(str(e))
        return 2
    except SystemExit as e:  # rule_log.run ends a script with bad input with exit status 1
        return int(e.code or 0) if not isinstance(e.code, str) else 1
    except Exception:
        if not args.pdb:
            raise
        import pdb
        import traceback

        traceback.print_exc()
        pdb.post_mortem()
        return 1
    print("done; outputs:")
    for p in smk.output:
        print(f"  {escape.terminal(p)}{'' if (smk.workdir / p).exists() else ' (not written)'}")
    if smk.log:
        print(f"log: {escape.terminal(smk.log[0])}")
    return 0


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


def _run_artifacts() -> dict[str, str]:
    """Every file the run's provenance records name -> the rule that made it ('' for a file the
    rules only read): what a command's --out must never replace."""
    made: dict[str, str] = {}
    for r in provenance.records():
        for a in r["inputs"]:
            made.setdefault(a, "")
        for a in r["outputs"]:
            made[a] = r["rule"]
    return made


def _refuse_overwriting(out: str, inputs: list, kind: str = "file") -> Path:
    """The resolved --out, or an InputError naming --out when the write door refuses it
    (:func:`flatlandia.plumbing.files.check_target`): one of the command's own inputs (or an existing
    file in a folder it reads), an artifact recorded by the run in this folder (its queries, maps,
    export), a link, a device, a folder in the way, a dot-folder, Python's or the source tree's
    folders; all compared resolved (``results/../results/x`` and links are caught). Checked before
    any work, and again by the writer."""
    try:
        return files.check_target(out, reads=[p for p in inputs if p], artifacts=_run_artifacts(), kind=kind)
    except InputError as e:
        raise InputError("--out", f"{out} {e.problem}") from None


def _priors_file(priors: str | None) -> str | None:
    """The priors JSON a command reads (None for auto and none)."""
    return None if priors in (None, "auto", "none") else priors


def _write_out(write, out: str, flag: str = "--out") -> bool:
    """Run ``write()``, a command's write of --out (or of ``flag``'s file); False after one ERROR line
    when the write door refused it or the write failed (a full disk, a folder in the way): nothing
    half-written is kept."""
    try:
        write()
    except InputError as e:
        _error(f"{flag}: {e.path} {e.problem}")  # the door names the file or a file below it
        return False
    except OSError as e:
        full = files.full_disk_error(e)
        why = files.FULL_ERRNOS[full.errno] if full is not None else (e.strerror or str(e))
        _error(f"{flag}: could not write {out}: {why}; nothing was written (free some space or give another {flag})")
        return False
    return True


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
        _refuse_overwriting(args.out, reads)
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
        _error(str(e))
        return 1
    if not _write_out(lambda: batch.write_poses(result, args.out, reads=reads, artifacts=_run_artifacts()), args.out):
        return 1
    for note in result.notes:
        print(f"note: {note}")
    for w in result.warnings:
        _warning(str(w))
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
            _refuse_overwriting(args.out, reads)
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
        _error(str(e))
        return 1
    _print_warnings(result)
    text = localize.dumps(result)
    if args.out and not _write_out(
        lambda: files.write_text(text + "\n", args.out, reads=reads, artifacts=_run_artifacts()), args.out
    ):
        return 1
    if drawn is not None and not _write_out(lambda: _write_plot(args, m, drawn, result, reads), args.plot, "--plot"):
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
        _refuse_overwriting(args.plot, [*reads, args.out])
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
    answer_figure.write_answer_figure(m, query, answer, args.plot, reads=[*reads, args.out], artifacts=_run_artifacts())


def _print_warnings(result: dict) -> None:
    """The answers' warnings (a fix that looks swapped or off the map) as WARNING lines on stderr,
    each once: stdout carries the JSON."""
    answers = result["results"] if "results" in result else [result]
    for w in dict.fromkeys(w for a in answers for w in a.get("warnings", [])):
        _warning(str(w))


def score_poses(args) -> int:
    """Score a poses file against a results folder's benchmark: DIR/{NAME}_{map_type}_{proposal}/
    (errors.parquet, summary.json: rule fine_eval's shapes) and DIR/scores.md, moved into place
    together (:func:`flatlandia.plumbing.files.staged`); a bad file, a refused --out or a failed
    write is one ERROR line, exit status 1 and nothing written."""
    from flatlandia import score

    try:
        _refuse_overwriting(args.out, [args.poses, args.results], kind="dir")
        scores = score.score_file(args.poses, args.name, args.results, args.split)
        _refuse_external(args.out, [r.run for r in scores.runs], args.results)
        reads = _score_inputs(args.poses, args.results, scores)
    except InputError as e:
        _error(str(e))
        return 1
    for note in scores.notes:
        print(f"note: {note}")
    for warning in scores.warnings:
        _warning(str(warning))
    for run in scores.runs:
        print(run.describe())
    if not _write_out(
        lambda: score.write_scores(scores, args.name, args.poses, args.out, reads=reads, artifacts=_run_artifacts()),
        args.out,
    ):
        return 1
    runs = ", ".join(f"{r.run}/" for r in scores.runs)
    print(f"wrote {Path(args.out) / 'scores.md'} and, in {args.out}, {runs} (errors.parquet, summary.json)")
    return 0


def _score_inputs(poses: str, results: str, scores) -> list[Path]:
    """The files ``flatlandia score`` read: the poses file and, in the results folder, the benchmark
    record, each scene's map and queries, the fine table and the coarse proposals of its runs (a
    score may write into the results folder, a new folder of its own, never over one of these)."""
    from flatlandia import paths, score

    record = Path(results) / score.BENCHMARK_RECORD
    inputs = [Path(poses), record, paths.within(results, paths.table("fine_localization"))]
    table = validate.read_table(record, validate.MAX_SCENES, validate.MAX_MAP_BYTES, columns=["scene"])
    for scene in table["scene"].astype(str):  # read once already through the door: sound
        inputs += [paths.within(results, paths.reference_map(scene)), paths.within(results, paths.queries(scene))]
    coarse = {r.proposal for r in scores.runs if vocabulary.coarse_source(r.proposal)}
    return inputs + [paths.within(results, paths.proposal_table(p)) for p in sorted(coarse)]


def _refuse_external(out: str, runs: list[str], results: str) -> None:
    """InputError naming --out when a run folder of the score would land in rule external_eval's
    tree (results/external/, of this folder or of --results): the workflow's runs of the config's
    ``external`` methods, which a score must never replace."""
    from flatlandia import paths

    trees = {files.resolved(paths.within(r, paths.external_run()).parents[1]) for r in ("results", results)}
    for run in runs:
        folder = files.resolved(Path(out) / run)
        tree = next((t for t in trees if folder.is_relative_to(t)), None)
        if tree is not None:
            raise InputError(
                "--out",
                f"{out}: its run folder {run}/ would lie in {tree}, rule external_eval's outputs: write the scores "
                "to a folder of their own",
            )


def main(argv: list[str] | None = None) -> int:
    from flatlandia.localize import ALTERNATIVES  # the library's default, said once (light: no solver)

    ap = argparse.ArgumentParser(prog="flatlandia", description=__doc__)
    ap.add_argument("--version", action="version", version=f"flatlandia {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    a = sub.add_parser("audit", help="print which rule, inputs, settings and commit produced each artifact")
    a.add_argument("artifact", nargs="?", help="one artifact: its rule, settings by value, inputs and their rules")
    a.add_argument("--tree", action="store_true", help="with PATH: follow the inputs back to the source files")
    a.add_argument("--check", action="store_true", help="re-hash every recorded artifact and name those changed")
    a.add_argument("--scene", help="only this scene's artifacts")
    a.add_argument("--manifest", default="results/manifest.parquet")
    a.add_argument("--provenance", default=str(provenance.PROVENANCE_DIR))
    a.add_argument("--write", metavar="FILE", help="write the records as a manifest (Parquet) instead of printing")
    a.set_defaults(func=audit)
    c = sub.add_parser("config", help="check (or --write) the config files generated from the schema")
    c.add_argument("--write", action="store_true", help="rewrite them instead of checking")
    c.add_argument(
        "--repo", default=str(release.PYPROJECT.parent), help="repository root (default: this package's clone)"
    )
    c.set_defaults(func=config_files)
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
    d.set_defaults(func=debug_rule)
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
    lq.set_defaults(func=localize_query)
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
    sc.set_defaults(func=score_poses)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except BrokenPipeError:  # the reader left (`| head`): no traceback, and none at exit either
        import os
        import sys

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
