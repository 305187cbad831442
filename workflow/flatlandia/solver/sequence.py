"""Several frames localized together: an anchor frame and companions tied to it by relative poses.

Why: one depth query of 3-5 common objects fits many places (docs/results.md, "Fine
localization"), while a user always has the frames just before and their relative motion (visual
or wheel odometry). A wrong place that explains one frame rarely explains the others at the poses
the odometry predicts, and objects seen from two camera centres a known baseline apart are
triangulated from their bearings, which depth maps get right.

Steps (:func:`locate_sequence`):

1. every frame hypothesises alone, as the single-frame solver does (3-bearing resections and
   2-point fits, gated by the training cameras and a fix, scored by MSAC with the priors), and
   keeps its ``frame_hypotheses`` cheapest distinct hypotheses;
2. each is mapped to the anchor through its frame's relative pose, and every mapped hypothesis is
   scored on *every* frame at the pose the odometry predicts for it, each depth frame with its own
   scale (a 1-D fit per frame: the median range ratio of its best-bearing candidates), plus each
   frame's camera, scale and co-visibility priors and the anchor's fix;
3. the ``refine_top_k`` cheapest distinct ones are refined jointly (robust Gauss-Newton of the
   anchor's pose, every frame's scale and each companion's odometry slack on the matches of every
   frame: bearings from several camera centres triangulate the objects), re-associated
   ``refine_rounds`` times, and scored again; the cheapest joint cost wins (or, with a verifier and
   ``verify``, the highest sum of the frames' verifier scores).

Inputs are the single-frame solver's (depth local maps, normalised to a median range of 1, and the
map's candidates), one :class:`~flatlandia.solver.priors.TrainingPriors` value for all frames (a
caller that evaluates on recorded queries must leave the companions' own cameras out of it:
:mod:`flatlandia.sequences.protocol`), and per companion frame its pose in the anchor's camera frame
with the odometry's noise.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from flatlandia import config, geo
from flatlandia.solver import calibration, distortion, hypotheses, likelihood, pipeline, scoring, verify
from flatlandia.solver import sequence_kernels as sk
from flatlandia.solver.pipeline import DISTINCT_DEG, DISTINCT_M, Solution
from flatlandia.solver.priors import Fix, Priors, TrainingPriors
from flatlandia.solver.problem import Problem
from flatlandia.solver.settings import SolverConfig


@config.settings("beyond.sequence")
class SequenceConfig:
    """The sequence solver's settings: the config section ``beyond.sequence`` (each is described in
    config/README.md, ``beyond.sequence.*``)."""


@dataclass
class FramePose:
    """One frame's refined pose in the map (x, y metres, theta radians) and its scale."""

    x: float
    y: float
    theta: float
    scale: float


@dataclass
class SequenceLocalization:
    """A sequence's answer: the anchor's best pose (None: none), the next-best distinct anchor poses,
    and every frame's pose under the best (anchor first)."""

    best: Solution | None
    alternatives: list[Solution] = field(default_factory=list)
    frames: list[FramePose] = field(default_factory=list)


def compose(anchor: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """(C, 3) poses of a frame whose pose in the anchor's camera frame is ``rel`` (dx forward, dy
    left, dtheta), for anchor poses ``anchor`` (C, 3) (x, y, theta)."""
    a = np.asarray(anchor, float).reshape(-1, 3)
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy, dth = (float(v) for v in rel)
    return np.column_stack([a[:, 0] + c * dx - s * dy, a[:, 1] + s * dx + c * dy, geo.wrap_angle(a[:, 2] + dth)])


def anchor_of(frame_pose: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """(C, 3) anchor poses of a frame at ``frame_pose`` (C, 3) whose pose in the anchor's frame is ``rel``."""
    p = np.asarray(frame_pose, float).reshape(-1, 3)
    dx, dy, dth = (float(v) for v in rel)
    th0 = geo.wrap_angle(p[:, 2] - dth)
    c, s = np.cos(th0), np.sin(th0)
    return np.column_stack([p[:, 0] - (c * dx - s * dy), p[:, 1] - (s * dx + c * dy), th0])


def relative_pose(anchor, other) -> np.ndarray:
    """(3,) pose ``other`` (x, y, theta) in the camera frame of ``anchor``: what odometry measures."""
    a, o = np.asarray(anchor, float), np.asarray(other, float)
    c, s = np.cos(a[2]), np.sin(a[2])
    d = o[:2] - a[:2]
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], float(geo.wrap_angle(o[2] - a[2]))])


class _Sequence:
    """The frames of one sequence, their problems and priors, and the joint cost."""

    def __init__(self, frames, rel_poses, ref_xy, ref_cls, cfg, seq, priors, odometry_sigma, fix):
        self.cfg, self.seq, self.fix = cfg, seq, fix
        k = priors.bearing_k if priors is not None else 0.0
        frames = [(distortion.undistort(xy, k), cls) for xy, cls in frames]  # the scene's lens, undone
        self.frames, self.ref_xy, self.ref_cls = list(frames), ref_xy, ref_cls
        noise = priors.noise if priors is not None else None
        self.problems = [Problem(xy, cls, ref_xy, ref_cls, False, cfg, noise) for xy, cls in frames]
        self.n = len(self.problems)
        #: the frames' own searches, at most ``seq.frame_max_hyp`` hypotheses each
        self.capped = self.problems
        if int(seq.frame_max_hyp) < int(cfg.max_hyp):
            capped_cfg = SolverConfig(**{**cfg.to_dict(), "max_hyp": int(seq.frame_max_hyp)})
            self.capped = [Problem(xy, cls, ref_xy, ref_cls, False, capped_cfg, noise) for xy, cls in frames]
        self.rel = np.asarray(rel_poses, float).reshape(self.n, 3).copy()
        self.rel[0] = 0.0
        sig = np.asarray(odometry_sigma, float).reshape(self.n, 2) if odometry_sigma is not None else None
        self.odo_sigma = sig if sig is not None else np.zeros((self.n, 2))
        # one Priors for every frame (they share the training cameras); the fix is the anchor's
        self.priors = Priors(cfg, False, priors, n_ref=len(self.problems[0].r))
        self.given = priors
        self.verifier = priors.verifier if priors is not None else None
        scale = self.priors.scale
        self.default_scale = float(np.exp(scale[0])) if scale is not None else 20.0

    def frame_poses(self, anchor: np.ndarray, f: int) -> np.ndarray:
        return compose(anchor, self.rel[f])

    # ---------------------------------------------------------------- step 0
    def frame_fix(self, f: int) -> Fix | None:
        """The fix as frame ``f`` sees it: the anchor's, widened for a companion by its distance."""
        if self.fix is None or f == 0:
            return self.fix
        return self.fix.widened(float(np.hypot(*self.rel[f, :2])))

    def single_answer(self, f: int, scored, pr) -> list[Solution]:
        """Frame ``f``'s own answer as the single-frame solver gives it (:func:`pipeline.locate`:
        its verifier and likelihood ratio too), from the frame's search ``scored`` (its priors
        ``pr``): best first, with up to ``frame_answers - 1`` alternatives; empty where it has none.
        They join the joint candidates and say how many frames agree with the joint answer (its
        probability's ``agreement``)."""
        k = int(self.seq.frame_answers)
        problem = self.capped[f]
        verified = self.verifier is not None and verify.usable(problem, pr)
        keep = self.cfg.verify_top_k if verified else self.cfg.top_k
        kept = scored.arrays(keep) if k > 0 else None
        if kept is None:
            return []
        cost, t, theta, s = kept
        chosen = hypotheses.distinct_best(cost, t, theta, keep)
        t, theta, s = scoring.refine(problem, pr, t[chosen], theta[chosen], s[chosen])
        pool = pipeline.Pool(problem, pr, t, theta, s, scored.n_hypotheses, verified)
        found = pipeline._ranked(pool, self.verifier if verified else None, k - 1)
        return [] if found.best is None else [found.best, *found.alternatives]

    def agreement(self, single: list[list[Solution]], poses: list[np.ndarray]) -> np.ndarray:
        """(C,) the share of frames whose own best answer lies within (5 m, 5 deg) of the frame's
        pose in each joint hypothesis (``poses[f]`` (C, 3)); nan without the frames' answers."""
        if int(self.seq.frame_answers) <= 0:
            return np.full(len(poses[0]), np.nan)
        agree = np.zeros(len(poses[0]))
        for f, answers in enumerate(single):
            if not answers:
                continue
            b = answers[0]
            near = np.hypot(poses[f][:, 0] - b.x, poses[f][:, 1] - b.y) < calibration.RIGHT_M
            near &= np.abs(geo.wrap_angle(poses[f][:, 2] - b.theta)) < np.radians(calibration.RIGHT_DEG)
            agree += near
        return agree / self.n

    def single_candidates(self, single: list[list[Solution]]) -> np.ndarray:
        """(H, 3) the frames' own answers mapped to the anchor."""
        out = [anchor_of(np.array([[a.x, a.y, a.theta]]), self.rel[f]) for f, ans in enumerate(single) for a in ans]
        return np.vstack(out) if out else np.zeros((0, 3))

    # ---------------------------------------------------------------- step 1
    def frame_hypotheses(self) -> tuple[np.ndarray, int, list[list[Solution]]]:
        """(H, 3) anchor poses of every frame's ``frame_hypotheses`` cheapest distinct hypotheses, the
        number of hypotheses scored, and every frame's own answer (:meth:`single_answer`, from the
        same search: each frame's hypotheses are generated and scored once)."""
        out, n_scored, single = [], 0, []
        keep = max(int(self.seq.frame_hypotheses), int(self.cfg.verify_top_k), int(self.cfg.top_k))
        for f, problem in enumerate(self.problems):
            if not problem.solvable():
                single.append([])
                continue
            pr = self.priors
            if self.fix is not None:
                pr = copy.copy(self.priors)
                pr.fix = self.frame_fix(f)
            scored = hypotheses.score_hypotheses(self.capped[f], pr, keep)
            n_scored += scored.n_hypotheses
            single.append(self.single_answer(f, scored, pr))
            kept = scored.arrays(self.seq.frame_hypotheses)
            if kept is None:
                continue
            cost, t, theta, s = kept
            chosen = hypotheses.distinct_best(cost, t, theta, self.seq.frame_hypotheses)
            t, theta, s = t[chosen], theta[chosen], s[chosen]
            if self.seq.refine_frames:
                t, theta, s = scoring.refine(problem, pr, t, theta, s)
            out.append(anchor_of(np.column_stack([t, theta]), self.rel[f]))
        return (np.vstack(out) if out else np.zeros((0, 3))), n_scored, single

    # ---------------------------------------------------------------- step 2
    def scales(self, f: int, poses: np.ndarray) -> np.ndarray:
        """(C,) frame ``f``'s scale at its poses ``poses`` (C, 3) (:func:`sequence_kernels.fit_scales`)."""
        pb = self.problems[f]
        s = sk.fit_scales(
            np.ascontiguousarray(poses[:, 0]),
            np.ascontiguousarray(poses[:, 1]),
            np.ascontiguousarray(poses[:, 2]),
            pb.q_bear,
            pb.q_range + pb.eps_q,
            pb.candidates,
            float(self.cfg.tau**2),
            pb.msac_noise.range_edges,
            pb.msac_noise.bearing_sigma,
            self.default_scale,
        )
        return np.clip(s, self.cfg.min_scale, self.cfg.max_scale)

    def frame_terms(self, f: int, poses: np.ndarray, s: np.ndarray):
        """Frame ``f``'s (data cost, cost with its priors, inliers, matches) at ``poses`` and scales
        ``s``. The frames of a sequence stand metres apart and see the same street: the training
        cameras near one are near all and their scales agree, so the priors (camera, co-visibility,
        scale) count ``prior_share`` in all, spread over the frames, while each frame's data counts
        in full."""
        data, cost, inl, match = scoring.score_terms(self.problems[f], self.priors, poses[:, :2], poses[:, 2], s)
        return data, data + (cost - data) * (float(self.seq.prior_share) / self.n), inl, match

    def joint_cost(self, anchor: np.ndarray, frame_poses=None, scales=None):
        """(C,) joint cost of anchor poses: every frame's MSAC cost with its priors at its pose (the
        odometry's prediction, or ``frame_poses[f]``) and scale (fitted, or ``scales[:, f]``), plus
        the anchor's fix; and the per-frame terms."""
        total = np.zeros(len(anchor))
        terms = []
        for f in range(self.n):
            poses = frame_poses[f] if frame_poses is not None else self.frame_poses(anchor, f)
            s = scales[:, f] if scales is not None else self.scales(f, poses)
            data, cost, inl, match = self.frame_terms(f, poses, s)
            total += cost
            terms.append((poses, s, data, cost, inl, match))
        if self.fix is not None:
            total += self.fix.cost(anchor[:, :2], anchor[:, 2])
        return total, terms

    def ranking_key(self, anchor, cost, terms, single, poses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(key, likelihood ratio, agreement) of refined anchor poses: the verifier's score (with the
        fix's cost) or the joint cost halved, less the likelihood ratio against chance and the frames'
        agreement with each place (their own answers: independent evidence); lower is better."""
        if self.seq.verify and self.verifier is not None and verify.usable(self.problems[0], self.priors):
            key = -self.verifier_scores(terms)
            if self.fix is not None:
                key = key + self.fix.cost(anchor[:, :2], anchor[:, 2]) / 2.0
        else:
            key = cost / 2.0
        llr = self.likelihood_ratio(terms)
        if np.isfinite(llr).all():
            key = key - float(self.cfg.likelihood_weight) * llr
        agree = self.agreement(single, poses)
        if np.isfinite(agree).all():
            key = key - float(self.seq.agreement_weight) * agree * self.n
        return key, llr, agree

    def terms(self) -> sk.SequenceTerms:
        """Every frame's observations, the odometry and the refinement's noise, as the joint
        refinement reads them."""
        return sk.SequenceTerms(
            np.concatenate([np.full(pb.m, f, np.int64) for f, pb in enumerate(self.problems)]),
            np.concatenate([pb.q_bear for pb in self.problems]),
            np.concatenate([pb.q_range + pb.eps_q for pb in self.problems]),
            np.array([pb.eps_q for pb in self.problems], float),
            np.ascontiguousarray(self.rel),
            np.ascontiguousarray(np.maximum(self.odo_sigma, 1e-3)),
            *self.problems[0].refine_noise,
        )

    # ---------------------------------------------------------------- step 3
    def refine(self, anchor: np.ndarray, terms) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
        """Joint refinement of anchor poses (C, 3) from their per-frame terms: (anchor poses, per-frame
        poses, (C, F) scales, (C,) odometry slack cost)."""
        n, c = self.n, len(anchor)
        p = np.zeros((c, 4 * n))
        p[:, :3] = anchor
        for f in range(n):
            p[:, 3 + f] = np.log(np.maximum(terms[f][1], 1e-9))
        seq_terms = self.terms()
        ref = self.problems[0].r
        for _ in range(self.cfg.refine_rounds):
            poses = self._frame_poses_of(p)
            inl, match = [], []
            for f in range(n):
                _, i_f, m_f = scoring.data_cost(self.problems[f], poses[f][:, :2], poses[f][:, 2], np.exp(p[:, 3 + f]))
                inl.append(i_f)
                match.append(m_f)
            inl_all = np.ascontiguousarray(np.concatenate(inl, axis=1))
            matched = np.ascontiguousarray(ref[np.concatenate(match, axis=1)])
            sk.refine_sequence(p, matched, inl_all, seq_terms, self._prior_terms(poses), 15)
        poses = self._frame_poses_of(p)
        slack = np.zeros(c)
        for f in range(1, n):
            base = 3 + n + 3 * (f - 1)
            sx = max(self.odo_sigma[f, 0], 1e-3)
            sh = max(self.odo_sigma[f, 1], 1e-3)
            slack += (p[:, base] ** 2 + p[:, base + 1] ** 2) / sx**2 + (p[:, base + 2] / sh) ** 2
        anchor = np.column_stack([p[:, :2], geo.wrap_angle(p[:, 2])])
        return anchor, poses, np.exp(p[:, 3 : 3 + n]), slack

    def _frame_poses_of(self, p: np.ndarray) -> list[np.ndarray]:
        n = self.n
        out = []
        for f in range(n):
            pose = compose(p[:, :3], self.rel[f])
            if f > 0:
                base = 3 + n + 3 * (f - 1)
                pose = pose + p[:, base : base + 3]
                pose[:, 2] = geo.wrap_angle(pose[:, 2])
            out.append(pose)
        return out

    def _prior_terms(self, poses: list[np.ndarray]) -> sk.SequencePriorTerms:
        cfg, pr, n = self.cfg, self.priors, self.n
        c = len(poses[0])
        use_cam = pr.tree is not None and cfg.prior_weight > 0
        use_head = use_cam and pr.heading is not None and cfg.prior_heading_sigma_deg > 0
        cam = np.zeros((c, n, 2))
        head = np.zeros((c, n))
        if use_cam:
            for f in range(n):
                q = np.column_stack([poses[f][:, :2], poses[f][:, 2], np.zeros(c)])
                cam[:, f], head[:, f] = pr._tied_cameras(q, use_head)
        use_scale = pr.scale is not None and cfg.scale_prior_weight > 0
        mu, sd = pr.scale if use_scale else (0.0, 1.0)
        fix = self.fix
        share = float(self.seq.prior_share) / n
        weight = float(cfg.prior_weight) * share if use_cam else 0.0
        return sk.SequencePriorTerms(
            np.ascontiguousarray(cam),
            np.ascontiguousarray(head),
            weight,
            float(cfg.prior_sigma_m),
            float(np.radians(cfg.prior_heading_sigma_deg)) if use_head else 0.0,
            float(mu),
            float(sd),
            float(cfg.scale_prior_weight) * share if use_scale else 0.0,
            fix.xy if fix is not None else np.zeros(2),
            float(fix.sigma_m) if fix is not None else 0.0,
            float(fix.heading) if fix is not None and fix.heading is not None else 0.0,
            float(np.radians(fix.heading_sigma_deg)) if fix is not None and fix.heading is not None else 0.0,
        )

    def likelihood_ratio(self, terms) -> np.ndarray:
        """(C,) the sum over frames of each frame's likelihood ratio against chance at its pose and
        scale (:func:`flatlandia.solver.likelihood.pose_llr`): what every frame saw and did not see
        counts; nan without the model or with ``likelihood_weight`` 0."""
        c = len(terms[0][0])
        if self.priors.likelihood is None or self.cfg.likelihood_weight <= 0:
            return np.full(c, np.nan)
        total = np.zeros(c)
        for f, (poses, s, *_) in enumerate(terms):
            total += likelihood.pose_llr(
                self.problems[f],
                self.priors,
                self.priors.likelihood,
                self.cfg.density_radius_m,
                poses[:, :2],
                poses[:, 2],
                s,
            )[0]
        return total

    def verifier_scores(self, terms) -> np.ndarray:
        """(C,) the sum over frames of the single-frame verifier's score at each frame's pose."""
        total = 0.0
        for f, (poses, s, data, _, inl, match) in enumerate(terms):
            feats = verify.features(self.problems[f], self.priors, poses[:, :2], poses[:, 2], s, data, inl, match)
            total = total + self.verifier.score(feats)
        return total


def locate_sequence(
    frames,
    rel_poses,
    ref_xy,
    ref_cls,
    config: SolverConfig | dict | None = None,
    priors: TrainingPriors | None = None,
    settings: SequenceConfig | dict | None = None,
    odometry_sigma=None,
    fix: Fix | None = None,
    alternatives: int = 0,
) -> SequenceLocalization:
    """The anchor's pose from several depth frames localized together.

    ``frames``: a list of (local map (M, 2), classes (M,)), the anchor first; each depth local map
    normalised to a median object range of 1 (as the single-frame solver's); ``rel_poses`` (F, 3):
    each frame's pose in the anchor's camera frame (dx forward, dy left in metres, dtheta in
    radians; row 0, the anchor, is ignored); ``odometry_sigma`` (F, 2): the noise of each relative
    pose (position in metres, heading in radians; None: rigid, 1 mm and 0.06 deg); ``ref_xy`` /
    ``ref_cls``: the candidate reference objects; ``config``: the solver's settings, ``priors`` its
    training priors (one value for every frame), ``settings`` the sequence solver's
    (:class:`SequenceConfig`), ``fix``: the anchor's position fix (and compass). One frame is
    :func:`flatlandia.solver.locate` (its verifier included). The answer's ``best.scale`` is the
    anchor's; ``frames`` holds every frame's refined pose."""
    cfg = config if isinstance(config, SolverConfig) else SolverConfig.from_dict(config)
    seq = settings if isinstance(settings, SequenceConfig) else SequenceConfig.from_dict(settings)
    frames = list(frames)
    if not frames:
        raise ValueError("a sequence needs at least one frame")
    if len(frames) == 1:  # one frame: the single-frame solver as every stage runs it (its verifier too)
        found = pipeline.locate(*frames[0], ref_xy, ref_cls, False, cfg, priors, alternatives, fix=fix)
        b = found.best
        poses = [FramePose(b.x, b.y, b.theta, b.scale)] if b is not None else []
        return SequenceLocalization(b, found.alternatives, poses)
    sq = _Sequence(frames, rel_poses, ref_xy, ref_cls, cfg, seq, priors, odometry_sigma, fix)
    anchor, n_scored, single = sq.frame_hypotheses()
    anchor = np.vstack([anchor, sq.single_candidates(single)])
    if not len(anchor):
        return SequenceLocalization(None)
    keep = sq.fix.near(anchor[:, :2]) if sq.fix is not None else np.ones(len(anchor), bool)
    anchor = anchor[keep]
    if not len(anchor):
        return SequenceLocalization(None)
    cost, _ = sq.joint_cost(anchor)
    chosen = hypotheses.distinct_best(cost, anchor[:, :2], anchor[:, 2], seq.refine_top_k)
    anchor = anchor[chosen]
    _, terms = sq.joint_cost(anchor)
    anchor, poses, scales, slack = sq.refine(anchor, terms)
    cost, terms = sq.joint_cost(anchor, poses, scales)
    cost = cost + slack
    ok = np.isfinite(cost) & np.all(np.isfinite(anchor), axis=1)
    if sq.priors.tree is not None:
        ok &= ~np.array([sq.priors.too_far(a[:2]) for a in anchor])
    if not ok.any():
        return SequenceLocalization(None)
    key, llr, agree = sq.ranking_key(anchor, cost, terms, single, poses)
    order = [int(k) for k in np.argsort(np.where(ok, key, np.inf), kind="stable") if ok[k]]
    best = order[0]
    m_total = sum(pb.m for pb in sq.problems)
    log_place, log_pool = calibration.log_evidence(anchor[:, :2], anchor[:, 2], key, ok)
    share = calibration.null_share(log_place, log_pool)
    prob = calibration.probability(
        sq.priors.calibration, share, sq.problems[0].m, sq.n, np.where(np.isfinite(agree), agree, 1.0)
    )

    def solution(k: int) -> Solution:
        inl0, match0 = terms[0][4], terms[0][5]
        inliers = [(int(j), int(match0[k, j])) for j in range(sq.problems[0].m) if inl0[k, j]]
        explained = sum(int(t[4][k].sum()) for t in terms)
        return Solution(
            float(anchor[k, 0]),
            float(anchor[k, 1]),
            float(anchor[k, 2]),
            float(scales[k, 0]),
            inliers,
            explained / max(m_total, 1),
            float(cost[k]),
            n_scored,
            float(key[k]) - float(key[best]),
            float(prob[k]),
            float(llr[k]) if np.isfinite(llr[k]) else None,
            float(share[k]),
            log_place=float(log_place[k]),
            log_pool=float(log_pool),
            agreement=float(agree[k]) if np.isfinite(agree[k]) else None,
        )

    chosen = [best]
    for other in order[1:]:
        if len(chosen) > alternatives:
            break
        if all(_distinct(anchor[other], anchor[c]) for c in chosen):
            chosen.append(other)
    frame_poses = [FramePose(*(float(v) for v in poses[f][best]), float(scales[best, f])) for f in range(sq.n)]
    return SequenceLocalization(solution(best), [solution(k) for k in chosen[1:]], frame_poses)


def _distinct(a, b) -> bool:
    turn = abs(float(geo.wrap_angle(a[2] - b[2])))
    return bool(np.hypot(a[0] - b[0], a[1] - b[1]) >= DISTINCT_M or turn >= np.radians(DISTINCT_DEG))


def true_match_poses(
    frames,
    rel_poses,
    matched_xy,
    start,
    scales,
    config: SolverConfig | dict | None = None,
    odometry_sigma=None,
    fix: Fix | None = None,
    iterations: int = 50,
) -> list[FramePose]:
    """What the geometry allows a sequence: every frame's pose refined jointly on its true matches
    from the truth (``start``: the anchor's true pose (x, y, theta); ``scales``: each frame's
    metres per local unit), on bearings alone (as the single-frame bound, ``solver.bound``), tied
    by the relative poses and their noise, and to the anchor's ``fix`` when given; no training
    priors. ``matched_xy``: per frame (M_f, 2) the map positions of its objects. Anchor first."""
    cfg = config if isinstance(config, SolverConfig) else SolverConfig.from_dict(config)
    cfg = SolverConfig(**{**cfg.to_dict(), "refine_range_inflation": 1e6})  # bearings only
    frames = list(frames)
    n = len(frames)
    zero = [np.zeros(len(xy), int) for xy, _ in frames]
    sq = _Sequence(
        [(xy, z) for (xy, _), z in zip(frames, zero)],
        rel_poses,
        np.zeros((2, 2)),
        np.zeros(2, int),
        SolverConfig(**{**cfg.to_dict(), "scale_prior": False}),
        SequenceConfig(),
        TrainingPriors(),
        odometry_sigma if odometry_sigma is not None else np.full((n, 2), 1e-3),
        fix,
    )
    p = np.zeros((1, 4 * n))
    p[0, :3] = start
    p[0, 3 : 3 + n] = np.log(np.asarray(scales, float))
    matched = np.ascontiguousarray(np.concatenate([np.asarray(m, float).reshape(-1, 2) for m in matched_xy])[None])
    terms = sq.terms()
    inl = np.ones(matched.shape[:2], bool)
    sk.refine_sequence(p, matched, inl, terms, sq._prior_terms(sq._frame_poses_of(p)), iterations)
    poses = sq._frame_poses_of(p)
    return [FramePose(*(float(v) for v in poses[f][0]), float(np.exp(p[0, 3 + f]))) for f in range(n)]
