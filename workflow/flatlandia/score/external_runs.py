"""An external method's runs, scored as the built-in runs are: a run's errors table
(:func:`errors_table`, rule fine_eval's rows) and summary, one setting (:func:`score_run`; rule
external_eval: :func:`external_run`) or every setting of a file (:func:`score_file`, ``flatlandia
score``); the method's name checked (:func:`check_name`).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo, paths, vocabulary
from flatlandia import proposals as proposals_module
from flatlandia.benchmark import metrics
from flatlandia.plumbing import files, validate
from flatlandia.plumbing.errors import InputError
from flatlandia.score.plausibility import plausibility
from flatlandia.score.poses import DEFAULT_MAP_TYPE, DEFAULT_PROPOSAL, Poses, read_poses
from flatlandia.score.scenes import BenchmarkScene, read_table, results_scenes

#: an external method's name: a plain lowercase id that is no built-in method's slug
#: (vocabulary.METHODS; it becomes results/external/{name}_{map_type}_{proposal}/, paths.external_run)
NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,39}$")


def check_name(name: str, source: str = "--name") -> str:
    """An external method's name, refused (InputError naming ``source``) unless it is a plain
    lowercase id that is not a built-in method's slug."""
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise InputError(
            source,
            f"name {name!r} is refused: a method name is a lowercase letter, then letters, digits or '_' (at most 40)",
        )
    if vocabulary.is_builtin(name):
        raise InputError(
            source, f"name {name!r} is a built-in method's ({', '.join(vocabulary.METHODS)}): pick another"
        )
    return name


def external_entries(entries: list[dict]) -> list[dict]:
    """Config ``external`` with each entry's defaults filled in from the schema (``map_types``,
    ``proposals``); a name given twice is refused (:class:`flatlandia.config.ConfigError`)."""
    from flatlandia import config

    item = config.schema()["properties"]["external"]["items"]["properties"]
    defaults = {k: v["default"] for k, v in item.items() if "default" in v}
    out, seen = [], set()
    for k, e in enumerate(entries or []):
        if e["name"] in seen:
            raise config.ConfigError(f"'external.{k}.name': {e['name']!r} is the name of an earlier entry")
        seen.add(e["name"])
        out.append({**defaults, **e})
    return out


def errors_table(
    poses: Poses,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
) -> pd.DataFrame:
    """One run's errors table (rule fine_eval's columns, :func:`metrics.error_row`): a row per
    ``split`` query of every scene, in the solver's order; the file's pose of that query in this
    (map_type, proposal) setting, or a failure (no pose: infinite error, 180 deg) where it has none.
    The proposal gives the row's proposal size and solvability (F%), as for the built-in runs. A file
    with answers (:func:`answer_of`) gives each row its ``answered`` and ``probability``."""
    mine = poses.table[(poses.table["map_type"] == map_type) & (poses.table["proposal"] == proposal)]
    columns = ["scene", "token", "x_m", "y_m", "theta_deg", "seconds", "status", "probability"]
    pose_of = {(s, t): rest for s, t, *rest in mine[columns].itertuples(index=False)}
    label = vocabulary.strategy_label(proposal, strategy)
    rows = []
    for b in scenes.values():
        ref, q = b.ref, b.queries
        test = q[q["split"] == poses.split]
        props = proposals_module.for_queries(ref, test, proposal, map_type, coarse, strategy)
        prop_of = {str(t): p for t, p in zip(props["token"], props["proposal"])}
        pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
        ref_cls = ref["class_id"].to_numpy()
        lat = float(ref["lat"].mean())
        for r in test.itertuples(index=False):
            idx = np.array([pos[int(o)] for o in prop_of.get(str(r.token), []) if int(o) in pos], int)
            given = pose_of.get((str(r.scene), str(r.token)))
            if given is None:
                pose, errors, seconds = (np.nan, np.nan, np.nan), (np.inf, 180.0), np.nan
            else:
                x, y, th, seconds = given[:4]
                pose = (x, y, math.radians(th))
                errors = geo.pose_errors(x, y, pose[2], r.x_m, r.y_m, math.radians(r.theta_deg))
            answered, probability = answer_of(poses, given[4:] if given is not None else None)
            rows.append(
                metrics.error_row(
                    r,
                    method=name,
                    map_type=map_type,
                    strategy=label,
                    proposal_classes=ref_cls[idx],
                    lat=lat,
                    pose=pose,
                    errors=errors,
                    fit=(float("nan"), 0, 0),
                    seconds=seconds,
                    cpu_seconds=float("nan"),
                    probability=probability,
                    answered=answered,
                )
            )
    return pd.DataFrame(rows)


def answer_of(poses: Poses, given: tuple | None) -> tuple[bool, float]:
    """(answered, probability) of a query whose pose row gives ``(status, probability)``, or None
    when the file has no pose of it. A file with a status column answers the poses it marks ``ok``
    (vocabulary.ANSWERED, the status of flatlandia localize: probability at least
    solver.answer_probability), never a query without a pose; a file without one answers every
    pose, as before (a method without a probability answers every query it places: rule
    fine_eval's error_row). A query without a pose has probability 0 where the file gives
    probabilities (the solver's own rows say so), NaN where it does not."""
    if given is None:
        return (not poses.has_status), (0.0 if poses.has_probability else float("nan"))
    status, probability = given
    return (status == vocabulary.ANSWERED if poses.has_status else True), float(probability)


def run_summary(
    errors: pd.DataFrame,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    strategy: str | None,
    poses: Poses,
) -> dict:
    """Rule fine_eval's summary of a run (:func:`metrics.summarise` and the same keys), with
    how many queries the file gave a pose (``scored``) and how many it left out (``missing``)."""
    out = metrics.summarise(errors)
    scored = int(np.isfinite(errors["x"].to_numpy(float)).sum()) if len(errors) else 0
    out.update(
        method=name,
        method_slug=name,
        map_type=map_type,
        proposal=proposal,
        strategy=vocabulary.strategy_label(proposal, strategy),
        run=f"{name}_{map_type}_{proposal}",
        ref_map_kb=float(np.mean([metrics.ref_map_kb(b.ref) for b in scenes.values()])) if scenes else float("nan"),
        train_s=0.0,
        epochs=0,
        trained_on="",
        external=True,
        poses=poses.path,
        pose_form=poses.form,
        split=poses.split,
        scored=scored,
        missing=int(len(errors) - scored),
        has_status=poses.has_status,
    )
    return out


@dataclass
class Run:
    """One scored setting of an external method: its errors table and summary."""

    name: str
    map_type: str
    proposal: str
    errors: pd.DataFrame
    summary: dict

    @property
    def run(self) -> str:
        return f"{self.name}_{self.map_type}_{self.proposal}"

    def metadata(self) -> dict:
        """The errors table's Parquet metadata (rule fine_eval's keys)."""
        return {
            "run": self.run,
            "method": self.name,
            "map_type": self.map_type,
            "proposal": self.proposal,
            "solver": None,
            "model_config": None,
            "external": True,
            "poses": self.summary["poses"],
        }

    def write(self, errors_path: str | Path, summary_path: str | Path) -> None:
        files.write_parquet(self.errors, errors_path, self.metadata())
        files.write_json(files.json_safe(self.summary), summary_path)

    def describe(self) -> str:
        """One paragraph for the terminal: queries, scored, missing, medians, recalls."""
        s = self.summary

        def f(v, spec):
            return "–" if v is None or not np.isfinite(v) else format(v, spec)

        rm = " / ".join(f(s[c], ".1f") for c in metrics.RECALL_COLUMNS[: len(metrics.RECALL_M)])
        rd = " / ".join(f(s[c], ".1f") for c in metrics.RECALL_COLUMNS[len(metrics.RECALL_M) :])
        ms = " / ".join(f"{m:g}" for m in metrics.RECALL_M)
        ds = " / ".join(f"{d:g}" for d in metrics.RECALL_DEG)
        return (
            f"{self.run} ({self.map_type} local maps, {s['strategy']} proposals): {s['queries']} {s['split']} queries, "
            f"{s['scored']} scored, {s['missing']} missing (failures); median {f(s['median_m'], '.2f')} m, "
            f"{f(s['median_deg'], '.2f')} deg; recall {ms} m: {rm} %; {ds} deg: {rd} %; "
            f"{f(s[metrics.WITHIN_COLUMN], '.1f')} % within ({metrics.WITHIN[0]:g} m, {metrics.WITHIN[1]:g} deg)"
            + (self.answers() if s.get("has_status") else "")
        )

    def answers(self) -> str:
        """The answered share and how many of the answered are within (5 m, 5 deg), as the fine
        table's % answered and % within of the answered (a file with a status column)."""
        s = self.summary
        within = s["within_answered_pct"]
        of_them = "none answered" if within is None or not np.isfinite(within) else f"{within:.1f} % of them within"
        return (
            f"; {s['answered_pct']:.1f} % answered (status {vocabulary.ANSWERED}), {of_them} "
            f"({metrics.WITHIN[0]:g} m, {metrics.WITHIN[1]:g} deg)"
        )


def score_run(
    poses: Poses,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
) -> Run:
    """One (map_type, proposal) setting of a poses file, scored."""
    errors = errors_table(poses, scenes, name, map_type, proposal, coarse, strategy)
    return Run(name, map_type, proposal, errors, run_summary(errors, scenes, name, map_type, proposal, strategy, poses))


def external_run(
    path: str | Path,
    scenes: dict[str, BenchmarkScene],
    name: str,
    map_type: str,
    proposal: str,
    coarse: pd.DataFrame | None = None,
    strategy: str | None = None,
    split: str = "test",
) -> tuple[Run, list[str]]:
    """Rule external_eval: one setting of the poses file at ``path``, scored, and the warnings
    (plausibility, poses outside the split). A file without a pose in this setting is refused."""
    check_name(name, "config external")
    poses = read_poses(path, scenes, split)
    if (map_type, proposal) not in poses.settings():
        held = ", ".join(f"{m}/{p}" for m, p in poses.settings())
        raise InputError(
            path,
            f"no poses for map_type {map_type}, proposal {proposal} (the file's settings: {held}; a file without "
            f"a map_type column is {DEFAULT_MAP_TYPE}, without a proposal column {DEFAULT_PROPOSAL})",
        )
    return score_run(poses, scenes, name, map_type, proposal, coarse, strategy), poses.notes + plausibility(
        poses, scenes
    )


def builtin_setting(table: pd.DataFrame | None, proposal: str) -> str | None:
    """The coarse strategy of the built-in runs of ``proposal`` in a fine table (its label is
    '{loss label} {strategy}'), None where the table has none."""
    if table is None or proposal not in vocabulary.COARSE_PROPOSALS:
        return None
    rows = table[table["proposal"] == proposal]
    prefix = vocabulary.COARSE_PROPOSALS[proposal] + " "
    labels = [s for s in rows["strategy"].astype(str) if s.startswith(prefix)]
    return labels[0][len(prefix) :] if labels else None


def default_strategy(proposal: str) -> str | None:
    """The default config's strategy of a coarse proposal table, picked by the key rule fine_eval
    reads for it (vocabulary.coarse_strategy: fine.coarse_strategy, or coarse.solver.fine_strategy
    for the solver's proposals); None for a map region."""
    from flatlandia import config

    return vocabulary.coarse_strategy(proposal, config.section_defaults())


@dataclass
class Scores:
    """``flatlandia score``'s result: the runs, the warnings, the built-in table beside them."""

    runs: list[Run]
    warnings: list[str]
    builtin: pd.DataFrame | None
    notes: list[str]


def _results_table(path: Path, columns: tuple[str, ...]) -> pd.DataFrame:
    """A table of the results folder (the fine table, a proposal table) with ``columns``, read within
    the bounds of a table of per-query rows (a poses file's: :func:`flatlandia.score.scenes.read_table`)."""
    t = read_table(path, validate.MAX_POSES_ROWS, validate.MAX_POSES_BYTES, ("MAX_POSES_ROWS", "MAX_POSES_BYTES"))
    validate.columns(t, columns, path)
    return t


def score_file(path: str | Path, name: str, results: str | Path, split: str = "test") -> Scores:
    """Every setting of a poses file scored against a results folder's benchmark (nothing written)."""
    check_name(name)
    results = Path(results)
    scenes = results_scenes(results)
    poses = read_poses(path, scenes, split)
    table_path = paths.within(results, paths.table("fine_localization"))
    builtin = _results_table(table_path, ("proposal", "strategy")) if os.path.lexists(table_path) else None
    notes = list(poses.notes)
    if builtin is None:
        notes.append(f"no built-in table at {table_path}: scores.md lists only {name}'s rows")
    runs = []
    for map_type, proposal in poses.settings():
        coarse = strategy = None
        if vocabulary.coarse_source(proposal):
            coarse_path = paths.within(results, paths.proposal_table(proposal))
            if not os.path.lexists(coarse_path):
                raise InputError(
                    coarse_path, f"missing: the {proposal} proposals are needed to score {map_type}/{proposal}"
                )
            coarse = _results_table(coarse_path, tuple(proposals_module.PROPOSAL_COLUMNS))
            strategy = builtin_setting(builtin, proposal) or default_strategy(proposal)
        runs.append(score_run(poses, scenes, name, map_type, proposal, coarse, strategy))
    return Scores(runs, plausibility(poses, scenes), builtin, notes)
