"""The solver's learned priors: the depth maps' log-scale prior, the verifier, the likelihood ratio's
model and the answers' calibration, as one value.

Why one value written once: the fine runs, the coarse stage's proposals and the city search all
solve depth maps with the same priors learned from the benchmark's training split; rule
solver_priors fits them once per region the queries are solved on (the verifier learns on the
region the test queries get: the whole map, or the GT-BB box) and writes them as JSON, which the
other rules read (fitting in every rule that needed it cost seconds each: docs/measurements.md, "Code paths").
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia.plumbing import files
from flatlandia.solver import calibration, distortion, likelihood, noise, verify, verify_fit
from flatlandia.solver.calibration import Calibration, MapSize
from flatlandia.solver.likelihood import LikelihoodModel
from flatlandia.solver.noise import NoiseModel
from flatlandia.solver.priors import TrainingPriors, camera_priors, depth_scale_prior
from flatlandia.solver.settings import SolverConfig

#: the regions a verifier can be learned on (:data:`verify_fit.REGIONS`); on any other region
#: (a coarse proposal) the depth maps get the scale prior alone
REGIONS = tuple(verify_fit.REGIONS)
#: the priors file's format: 2 since the solver's one noise model (``noise``: the sigmas per range
#: bin and each scene's bearing correction, which format 1 kept in ``likelihood`` and ``distortion``)
FORMAT = 2


@dataclass(frozen=True)
class LearnedPriors:
    """What the solver learns from a benchmark's training split for depth maps (and, for the
    answers' probability, its validation split); any may be None (off in the settings, or nothing
    to learn)."""

    scale: tuple[float, float] | None = None  # (mean, std) of log(metres per local unit)
    verifier: verify.Verifier | None = None
    likelihood: LikelihoodModel | None = None  # the likelihood ratio against chance (training split)
    calibration: Calibration | None = None  # the answers' probability (validation split)
    #: the depth maps' noise per range bin and each scene's bearing correction (:mod:`flatlandia.solver.noise`)
    noise: NoiseModel | None = None

    def bearing_k(self, scene) -> float:
        """The radial bearing coefficient of ``scene``'s depth maps (0: none)."""
        return self.noise.bearing_k(scene) if self.noise is not None else 0.0

    def to_dict(self) -> dict:
        v = self.verifier
        return {
            "format": FORMAT,
            "scale_prior": list(self.scale) if self.scale else None,
            "verifier": {"weights": v.weights.tolist(), "mean": v.mean.tolist(), "scale": v.scale.tolist()}
            if v is not None
            else None,
            "features": list(verify.FEATURES),
            "likelihood": self.likelihood.to_dict() if self.likelihood is not None else None,
            "calibration": self.calibration.to_dict() if self.calibration is not None else None,
            "noise": self.noise.to_dict() if self.noise is not None else None,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str | Path = "learned priors") -> LearnedPriors:
        """The priors as :meth:`to_dict` writes them, checked field by field
        (:func:`flatlandia.plumbing.validate.learned_priors`, then the likelihood model's and the
        calibration's own ``from_dict``); one InputError naming ``source`` and the field."""
        from flatlandia.plumbing import validate
        from flatlandia.plumbing.errors import InputError

        validate.learned_priors(d, source, len(verify.FEATURES), FORMAT)
        scale = tuple(float(x) for x in d["scale_prior"]) if d["scale_prior"] is not None else None
        v, verifier = d["verifier"], None
        if v is not None:
            if d["features"] != list(verify.FEATURES):
                raise InputError(
                    source,
                    f"the verifier's features {validate.shown(d['features'])} are not this solver's {verify.FEATURES}",
                )
            verifier = verify.Verifier(*(np.asarray(v[k], float) for k in ("weights", "mean", "scale")))
        lik = LikelihoodModel.from_dict(d["likelihood"], source) if d["likelihood"] is not None else None
        cal = Calibration.from_dict(d["calibration"], source) if d["calibration"] is not None else None
        model = NoiseModel.from_dict(d["noise"], source) if d["noise"] is not None else None
        return cls(scale, verifier, lik, cal, model)

    def write(self, path: str | Path) -> None:
        files.write_json(self.to_dict(), path)

    def with_map_size(self, map_size: MapSize | None) -> LearnedPriors:
        """These priors with a city's map-size correction (None: without one)."""
        cal = self.calibration if self.calibration is not None else Calibration()
        return replace(self, calibration=replace(cal, map_size=map_size))

    @classmethod
    def read(cls, path: str | Path) -> LearnedPriors:
        """A priors JSON, checked field by field as it is read (:meth:`from_dict`)."""
        from flatlandia.plumbing.errors import InputError

        d = files.read_json(path)
        try:
            return cls.from_dict(d, path)
        except InputError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as e:  # a shape the checks above let through
            raise InputError(path, f"not the solver's learned priors ({e}); delete it to have it refitted") from None


def with_learned(priors: TrainingPriors, learned: LearnedPriors | None) -> TrainingPriors:
    """``priors`` with a benchmark's learned scale prior, verifier, likelihood model, calibration and
    noise model (None: without)."""
    if learned is None:
        return replace(priors, scale=None, verifier=None, likelihood=None, calibration=None, noise=None, bearing_k=0.0)
    return replace(
        priors,
        scale=learned.scale,
        verifier=learned.verifier,
        likelihood=learned.likelihood,
        calibration=learned.calibration,
        noise=learned.noise,
    )


def scene_priors(
    ref: pd.DataFrame, queries: pd.DataFrame, settings: dict | None = None, learned: LearnedPriors | None = None
) -> TrainingPriors:
    """The priors of one scene's whole map (rows of ``ref``): its training cameras and what they
    saw (:func:`flatlandia.solver.priors.camera_priors`), with a benchmark's ``learned`` priors
    (and the scene's bearing correction among them)."""
    out = with_learned(camera_priors(ref, queries, settings), learned)
    return out if learned is None else replace(out, bearing_k=learned.bearing_k(distortion.scene_of(ref)))


def read_map_size(path: str | Path) -> MapSize:
    """A city's map-size correction (rule city_calibration's record), checked as it is read."""
    from flatlandia.plumbing import validate

    d = files.read_json(path)
    validate.map_size_calibration(d, path, calibration.MAX_SHIFT, calibration.MAX_PER_LOG_ODDS)
    return MapSize.from_dict(d["map_size"], path)


def fit(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame]],
    settings: SolverConfig | dict | None,
    region: str | None = "whole",
    **fit_args,
) -> LearnedPriors:
    """The learned priors of depth maps from the training split of ``scenes`` (reference map,
    queries): first the noise model (:func:`noise.fit`: with ``solver.bearing_correction`` each
    scene's radial bearing correction, then the sigmas per range bin), which the MSAC cost, the
    likelihood and the verifier's pools then read; the log-scale prior, the likelihood ratio's
    model (:func:`likelihood.fit`, when ``solver.likelihood_weight`` > 0) and, when
    ``solver.verify`` and ``camera_prior`` are on (unset keys: the schema's defaults) and
    ``region`` is one of :data:`REGIONS`, the verifier learned on that region. No calibration:
    :func:`with_calibration` adds it from validation answers. ``fit_args``: ``fraction``, ``rng`` of
    :func:`verify_fit.fit_verifier`."""
    cfg = SolverConfig.of(settings)
    model = noise.fit(scenes, cfg.bearing_correction)
    scale = depth_scale_prior([q for _, q in scenes], cfg)
    lik = likelihood.fit(scenes) if cfg.likelihood_weight > 0 else None
    verifier = None
    if cfg.verify and cfg.camera_prior and region in REGIONS:
        verifier = verify_fit.fit_verifier(scenes, cfg.to_dict(), scale, region, noise=model, **fit_args)
    return LearnedPriors(scale, verifier, lik, noise=model)


def with_calibration(learned: LearnedPriors, answers: pd.DataFrame) -> LearnedPriors:
    """``learned`` with the answers' calibration fitted on ``answers`` (validation answers of the
    solver run with ``learned``: columns ``pool_share``, ``objects``, ``frames``, ``agreement``,
    ``right``), one
    logistic map for single frames and one for sequences (:func:`calibration.fit_logistic`)."""
    one = answers[answers["frames"] <= 1]
    seq = answers[answers["frames"] > 1]
    cal = Calibration(
        calibration.fit_logistic(one["pool_share"], one["objects"], one["frames"], one["agreement"], one["right"]),
        calibration.fit_logistic(seq["pool_share"], seq["objects"], seq["frames"], seq["agreement"], seq["right"]),
    )
    return replace(learned, calibration=cal)
