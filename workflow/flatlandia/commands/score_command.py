"""``flatlandia score POSES --name NAME --out DIR``: a user's poses scored against a results
folder's benchmark as the built-in methods are (flatlandia.score), --out checked first: never over
what the score reads, never in rule external_eval's tree."""

from __future__ import annotations

from pathlib import Path

from flatlandia import vocabulary
from flatlandia.commands.messages import error, warning
from flatlandia.commands.out_option import refuse_overwriting, run_artifacts, write_out
from flatlandia.plumbing import files, validate
from flatlandia.plumbing.errors import InputError


def score_poses(args) -> int:
    """Score a poses file against a results folder's benchmark: DIR/{NAME}_{map_type}_{proposal}/
    (errors.parquet, summary.json: rule fine_eval's shapes) and DIR/scores.md, moved into place
    together (:func:`flatlandia.plumbing.files.staged`); a bad file, a refused --out or a failed
    write is one ERROR line, exit status 1 and nothing written."""
    from flatlandia import score

    try:
        refuse_overwriting(args.out, [args.poses, args.results], kind="dir")
        scores = score.score_file(args.poses, args.name, args.results, args.split)
        _refuse_external(args.out, [r.run for r in scores.runs], args.results)
        reads = _score_inputs(args.poses, args.results, scores)
    except InputError as e:
        error(str(e))
        return 1
    for note in scores.notes:
        print(f"note: {note}")
    for w in scores.warnings:
        warning(str(w))
    for run in scores.runs:
        print(run.describe())
    if not write_out(
        lambda: score.write_scores(scores, args.name, args.poses, args.out, reads=reads, artifacts=run_artifacts()),
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
