"""Rule city_calibration: the cities' map-size correction of the answers' probability
(flatlandia.solver.calibration.MapSize), fitted on the validation anchors of the city rows' maps
(`city-N`, `simulated-N`: rule beyond_city's entry functions, every frame count, no fix) with the
scene-calibrated priors; the record and the answers it was fitted on."""

import numpy as np
import pandas as pd

from flatlandia import solver
from flatlandia.city.index import ViewIndex
from flatlandia.plumbing import files, rule_log
from flatlandia.sequences import evaluation
from flatlandia.solver import calibration, calibration_fit


def main(smk, log):
    beyond = dict(smk.params["beyond"])
    scenes = list(smk.params.scene_ids)
    refs = {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.reference_maps)}
    learned = solver.LearnedPriors.read(smk.input.priors).with_map_size(None)
    common = dict(
        settings=[evaluation.Setting(int(k)) for k in beyond["frames"]],
        solver_settings=dict(smk.params["solver"]),
        search_settings=dict(smk.params["city.search"]),
        beyond=beyond,
        learned=learned,
        seed=int(smk.params["seed"]),
        split=calibration_fit.CITY_SPLIT,
        log=log,
    )
    parts, maps = [], {}
    for name in smk.params.maps:
        kind, n = name.split("-")
        if kind == "city":
            city_map = pd.read_parquet(smk.input[f"map_{n}"])

            def index_of(city: str, n=n) -> ViewIndex:
                return ViewIndex.load(f"{smk.input[f'index_{n}']}/{city}.npz")

            queries = pd.read_parquet(smk.input[f"queries_{n}"])
            errors = evaluation.tiled_city_errors(city_map, queries, index_of, map_name=name, **common)
            objects = float(city_map.groupby("city").size().mean())
        else:
            qs = {s: pd.read_parquet(p) for s, p in zip(scenes, smk.input.queries)}
            spacing = float(smk.params["city.spacing_m"])
            errors = evaluation.simulated_city_errors(
                scenes, refs, qs, int(n), dict(smk.params["city.simulate"]), spacing, **common
            )
            objects = float(errors.attrs.get("objects", n))
        parts.append(calibration_fit.city_answers(errors, objects))
        maps[name] = {"objects": objects, "answers": int(len(parts[-1]))}
    answers = (
        pd.concat(parts, ignore_index=True)
        if parts
        else calibration_fit.city_answers(
            pd.DataFrame(columns=["map", "frames_used", "error_m", "error_deg", "probability"]), 0
        )
    )
    reference = float(np.median([len(r) for r in refs.values()])) if refs else 1.0
    fitted = calibration.fit_map_size(answers, max(reference, 1.0))
    before = {}
    for (m, k), a in answers.groupby(["map", answers["frames"] > 1]):
        after = fitted.adjust(a["probability"], maps[m]["objects"], 2 if k else 1)
        before[f"{m}, {'sequences' if k else '1 frame'}"] = {
            "answers": int(len(a)),
            "ece_points_before": calibration.expected_calibration_error(a["probability"], a["right"]),
            "ece_points_after": calibration.expected_calibration_error(after, a["right"]),
        }
    record = {"map_size": fitted.to_dict(), "split": calibration_fit.CITY_SPLIT, "maps": maps, "validation": before}
    log.info("map-size correction: %s", record)
    files.write_parquet(answers, smk.output.answers, {"split": calibration_fit.CITY_SPLIT, "maps": maps})
    files.write_json(record, smk.output.calibration)


rule_log.run(main, snakemake)  # noqa: F821
