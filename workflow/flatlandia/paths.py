"""Where every artifact of a run lives: one function per artifact kind.

Each function returns the path relative to the run's working folder (``results/...``, as the rules
write it); called with wildcards (its defaults, e.g. ``"{scene}"``) it returns the rule's pattern,
called with values the file of one job: ``reference_map()`` is
``results/{scene}/maps/reference_map.parquet``, ``reference_map(12)`` is scene 12's. The rules
(inputs, outputs, the targets of ``all``), ``score``, ``localize``, ``export``, the tables, the
figures, the tests and the benchmarks build their paths here; a results folder elsewhere (``flatlandia
score --results``, a copy of a run) is reached with :func:`within`. The layout itself is described in
docs/usage.md, "What lands where".

It imports nothing but the standard library and ``vocabulary``: the rules read it while Snakemake
parses them.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

from flatlandia import vocabulary

#: the folder of a run's results, in its working folder
RESULTS = "results"
#: a rule's default wildcards: called without them, a function returns the rule's pattern
SCENE = "{scene}"


def _r(*parts) -> str:
    return "/".join((RESULTS, *(str(p) for p in parts)))


def within(results: str | Path, path: str) -> Path:
    """``path`` (one of this module's, under ``results/``) in another results folder ``results``
    (a run elsewhere, a copy, a folder a command is given)."""
    return Path(results) / PurePosixPath(path).relative_to(RESULTS)


# ----------------------------------------------------------------------------- data (per scene)


def ingest(scene=SCENE) -> str:
    """The published files of a scene, checked (rule ingest)."""
    return _r(scene, "ingest", "ingest.json")


def reference_map(scene=SCENE, ext: str = "parquet") -> str:
    """A scene's reference map: ``parquet`` (the workflow's, frame in its metadata), ``geojson`` (rule
    reference_map), ``png`` (rule plot_reference_map)."""
    return _r(scene, "maps", f"reference_map.{ext}")


def viewer(scene=SCENE) -> str:
    return _r(scene, "maps", "viewer.html")


def recovered(scene=SCENE) -> str:
    """A published scene's queries with their recovered ground truth (rule recover)."""
    return _r(scene, "queries", "recovered.parquet")


def queries(scene=SCENE) -> str:
    """A scene's queries: local maps, true poses, split (rule queries)."""
    return _r(scene, "queries", "queries.parquet")


def query_figures(scene=SCENE) -> str:
    """A folder: a figure per test query (rule query_figures)."""
    return _r(scene, "queries", "figures")


def worst_queries(scene=SCENE) -> str:
    return _r(scene, "queries", "worst_queries.png")


def scene_localization(scene=SCENE, ext: str = "parquet") -> str:
    """An images scene localized by the benchmark's methods (rule scene_localization): parquet, md."""
    return _r(scene, "localization", f"localization.{ext}")


# ----------------------------------------------------------------------------- images scenes


def image_table(scene=SCENE) -> str:
    """The audit of an images scene's photos (rule image_audit)."""
    return _r(scene, "images", "images.parquet")


def segment(scene=SCENE, part: str = "masks") -> str:
    """Rule segment's outputs: ``masks``, ``classes`` (folders), ``segment_stats.parquet``."""
    return _r(scene, "segment", part)


def sfm(scene=SCENE, part: str = "model") -> str:
    """The SfM folder's files: ``model`` (a folder), ``sfm_stats.parquet``, ``cameras.parquet`` (rule
    sfm), ``sfm_summary.png`` (plot_sfm)."""
    return _r(scene, "sfm", part)


def classified_points(scene=SCENE, ext: str = "parquet") -> str:
    """The SfM points with their classes (rule classify_points): parquet, ply."""
    return _r(scene, "sfm", f"classified_points.{ext}")


def point_instances(scene=SCENE) -> str:
    return _r(scene, "sfm", "point_instances.parquet")


def gps_alignment(scene=SCENE) -> str:
    return _r(scene, "sfm", "gps_alignment.json")


# ----------------------------------------------------------------------------- objects


def objects(scene=SCENE, ext: str = "parquet") -> str:
    """A scene's objects from classified points (rule objects): parquet, ply."""
    return _r(scene, "objects", f"objects.{ext}")


def point_objects(scene=SCENE) -> str:
    return _r(scene, "objects", "point_objects.parquet")


def principal_plane(scene=SCENE) -> str:
    return _r(scene, "objects", "principal_plane.json")


# ----------------------------------------------------------------------------- solver, coarse, fine


def solver_priors(region="{region}") -> str:
    """The solver's learned priors for ``region`` (vocabulary.PRIOR_REGIONS), the answers' calibration
    included (rule solver_calibration): what every rule that solves depth maps reads."""
    return _r("solver", "priors", f"{region}.json")


def solver_priors_gt(region="{region}") -> str:
    """The priors of GT local maps for ``region``: their answers' calibration alone, with its null
    hypothesis (rule solver_calibration_gt; GT maps learn nothing else)."""
    return _r("solver", "priors", f"{region}.gt.json")


def solver_fit(region="{region}") -> str:
    """The priors fitted on the training split for ``region``, before the calibration (rule
    solver_priors)."""
    return _r("solver", "priors", f"{region}.fit.json")


def proposal_priors(proposal: str) -> str:
    """The learned priors a depth-map solver run on ``proposal`` reads."""
    return solver_priors(vocabulary.prior_region(proposal))


def coarse_target(scene=SCENE) -> str:
    """A scene's neighbourhood similarity target (rule coarse_target)."""
    return _r(scene, "coarse", "target.parquet")


def coarse_model(loss="{loss}") -> str:
    return _r("coarse", loss, "model.pt")


def coarse_training(loss="{loss}") -> str:
    """A coarse model's training history."""
    return _r("coarse", loss, "training.parquet")


def coarse_proposals(source="{loss}") -> str:
    """A coarse source's proposal table: a loss's model (rule coarse_eval) or ``solver`` (coarse_solver)."""
    return _r("coarse", source, "proposals.parquet")


def proposal_table(proposal: str) -> str:
    """The proposal table a fine run on a coarse ``proposal`` reads."""
    return coarse_proposals(vocabulary.coarse_source(proposal))


def fine_model(model="{model}", map_type="{map_type}", train="{train}", part: str = "checkpoint.pt") -> str:
    """A learned model of the fine stage (rule fine_train): ``checkpoint.pt``, ``history.parquet``."""
    return _r("fine", "models", f"{model}_{map_type}_{train}", part)


def fine_run(method="{method}", map_type="{map_type}", proposal="{proposal}", part: str = "errors.parquet") -> str:
    """A built-in method's run (rule fine_eval): ``errors.parquet``, ``summary.json``."""
    return _r("fine", vocabulary.run_name(method, map_type, proposal), part)


def external_run(method="{method}", map_type="{map_type}", proposal="{proposal}", part: str = "errors.parquet") -> str:
    """An external method's run (config ``external``, rule external_eval): ``errors.parquet``,
    ``summary.json``; a tree of its own, beside the built-in runs."""
    return _r("external", vocabulary.run_name(method, map_type, proposal), part)


def run_file(run: str, part: str = "errors.parquet") -> str:
    """A run's file by its name, built-in (results/fine/) or external (results/external/)."""
    method, map_type, proposal = vocabulary.split_run(run)
    where = fine_run if vocabulary.is_builtin(method) else external_run
    return where(method, map_type, proposal, part)


# ----------------------------------------------------------------------------- city, beyond


def city(n="{n}", part: str = "map.parquet") -> str:
    """A tiled city of n scenes: ``map.parquet``, ``queries.parquet`` (rule city_maps), ``index``
    (a folder, city_index), ``errors_{method}.parquet`` and ``summary_{method}.json`` (city_eval)."""
    return _r("city", n, part)


def city_result(n="{n}", method="{method}", part: str = "summary") -> str:
    """A city method's rows (rule city_eval): ``summary`` (json) or ``errors`` (parquet)."""
    return city(n, f"{part}_{method}.{'json' if part == 'summary' else 'parquet'}")


def city_calibration(part: str = "calibration.json") -> str:
    """The cities' map-size correction of the answers' probability (rule city_calibration):
    ``calibration.json``, ``calibration_answers.parquet``."""
    return _r("city", part)


def simulated_city(objects="{objects}", part: str = "summary.json") -> str:
    """A simulated city of ``objects`` objects (rule city_simulate): summary.json, errors.parquet."""
    return _r("city", "simulated", objects, part)


def beyond_scene(prior="{prior}", part: str = "summary") -> str:
    """The scene rows of the sequence and fix protocol (rule beyond_scene), camera prior on/off:
    ``summary`` (json) or ``errors`` (parquet)."""
    return _r("beyond", "scene", f"{part}_{prior}.{'json' if part == 'summary' else 'parquet'}")


def beyond_city(map="{map}", part: str = "summary.json") -> str:
    """The city rows of the protocol (rule beyond_city) on ``city-N`` or ``simulated-N``."""
    return _r("beyond", map, part)


# ----------------------------------------------------------------------------- tables, figures


def table(name: str, ext: str = "parquet") -> str:
    """A result table: parquet (the data), md, tex, png."""
    return _r("tables", f"{name}.{ext}")


def tables_dir() -> str:
    return _r("tables")


#: the record of the scenes a results folder's benchmark was built on (common.smk and score read it)
BENCHMARK_RECORD = table("dataset_stats_per_scene")


def figure(name: str) -> str:
    """A report figure (``training_curves.png``...)."""
    return _r("figures", name)


def manifest() -> str:
    return _r("manifest.parquet")


def export(name: str, scene=None) -> str:
    """A file of the export (target ``export``): the index's (``README.md``...) or a scene's."""
    return _r("export", name) if scene is None else _r("export", scene, name)


def export_original(name: str) -> str:
    """A file of the export in the authors' form (rule ``export_original``): ``data/flatlandia.json``,
    ``data/region_proposal.json``, ``data/local_maps.json``, ``README.md``."""
    return _r("export", "original", name)


def locate(path: str | Path, artifact, **kwargs) -> tuple[Path, dict[str, str]] | None:
    """Where a file ``path`` sits as the artifact ``artifact`` (a function of this module, called with
    ``kwargs`` but its wildcards) of a results folder: (that folder, the wildcards' values), or None
    when it is not one: ``locate("run/results/12/maps/reference_map.parquet", reference_map)`` is
    ``(Path("run/results"), {"scene": "12"})``."""
    pattern = PurePosixPath(artifact(**kwargs)).relative_to(RESULTS).parts
    parts = Path(path).parts
    if len(parts) < len(pattern):
        return None
    wildcards = {}
    for want, got in zip(pattern, parts[len(parts) - len(pattern) :], strict=True):
        if want.startswith("{") and want.endswith("}"):
            wildcards[want[1:-1]] = got
        elif want != got:
            return None
    return Path(*parts[: len(parts) - len(pattern)]), wildcards
