"""2D similarities (rotation, uniform scale, translation) estimated by pycolmap.

Used by the GPS alignment of images scenes (camera centres on their ground plane -> GPS fixes)
and by the principal-plane audit (published plane coordinates -> metric frame).

pycolmap estimates 3D similarities (``estimate_sim3d``: Umeyama; ``estimate_sim3d_robust``:
LO-RANSAC). What it does not do, and this module adds: a 2D fit that cannot mirror the map.
Planar points lifted to z = 0 let a 3D rotation realise a 2D reflection for free (a half turn
about an in-plane axis flips z, which no point measures), so every point also comes with a copy
lifted by ``h`` along z on both sides: a mirrored fit puts those copies 2h apart, a proper one
keeps them. The lift is scale-consistent (source lift ``h / s``) and small, so it leaves the fit
unbiased once the scale is known; the final least-squares refit iterates it to its fixed point.
Reflections, where wanted, are fitted on mirrored source points and folded back. Optional
camera headings enter as one more point per camera, ahead of it along its heading.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from flatlandia import geo
from flatlandia.plumbing.errors import InputError


@dataclass
class ScaledRigid:
    """Rotation, uniform scale and translation:
    dst ~= scale * src @ rotation.T + translation (rotation may be a reflection if allowed)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def apply(self, src: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(src, float) @ self.rotation.T + self.translation

    @property
    def reflection(self) -> bool:
        return bool(np.linalg.det(self.rotation) < 0)

    def angle_deg(self) -> float:
        """Rotation angle (of its proper part for a reflection)."""
        r = self.rotation.copy()
        if self.reflection:
            r[:, 1] *= -1
        return float(np.degrees(np.arctan2(r[1, 0], r[0, 0])))


_MIRROR = np.diag([1.0, -1.0])


def _lifted(src: np.ndarray, dst: np.ndarray, h_src: float, h_dst: float) -> tuple[np.ndarray, np.ndarray]:
    """Each 2D pair at z = 0 and again at z = h (source h_src, target h_dst): see the module doc."""
    z = np.zeros((len(src), 1))
    s = np.vstack([np.hstack([src, z]), np.hstack([src, z + h_src])])
    d = np.vstack([np.hstack([dst, z]), np.hstack([dst, z + h_dst])])
    return s, d


def _to_2d(sim3d) -> ScaledRigid | None:
    """The in-plane part of a pycolmap Sim3d fitted on lifted points; None when it tilts or flips
    the plane (a mirrored or degenerate fit)."""
    r = sim3d.rotation.matrix()
    if r[2, 2] < 0.9:
        return None
    u, _, vt = np.linalg.svd(r[:2, :2])  # the closest proper 2D rotation (removes a residual tilt)
    r2 = u @ np.diag([1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    return ScaledRigid(scale=float(sim3d.scale), rotation=r2, translation=np.asarray(sim3d.translation)[:2].copy())


def least_squares(src: np.ndarray, dst: np.ndarray, allow_reflection: bool = False, refits: int = 6) -> ScaledRigid:
    """Least-squares 2D similarity src -> dst (pycolmap's Umeyama on lifted points), proper unless
    ``allow_reflection`` and a mirrored fit explains the points better."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    fits = [_proper_least_squares(src, dst, refits)]
    if allow_reflection:
        m = _proper_least_squares(src @ _MIRROR, dst, refits)
        fits.append(None if m is None else _fold_mirror(m))
    fits = [f for f in fits if f is not None]
    if not fits:
        raise InputError("points", "no similarity fits: degenerate point sets")
    return min(fits, key=lambda f: float(np.sum((f.apply(src) - dst) ** 2)))


def _proper_least_squares(src: np.ndarray, dst: np.ndarray, refits: int) -> ScaledRigid | None:
    import pycolmap

    h = 1e-3 * (float(np.ptp(dst, axis=0).max()) or 1.0)  # small: its share of the variance ~1e-6
    scale, fit = 1.0, None
    for _ in range(refits):  # the scale-consistent lift converges in a few refits
        sim = pycolmap.estimate_sim3d(*_lifted(src, dst, h / scale, h))
        fit = None if sim is None else _to_2d(sim)
        if fit is None:
            return None
        if abs(fit.scale / scale - 1) < 1e-13:
            break
        scale = fit.scale
    return fit


def _fold_mirror(sim: ScaledRigid) -> ScaledRigid:
    """A fit on mirrored source points as a transform of the original points (a reflection)."""
    return ScaledRigid(scale=sim.scale, rotation=sim.rotation @ _MIRROR, translation=sim.translation)


def _heading_residual(sim: ScaledRigid, src_heading: np.ndarray, dst_heading: np.ndarray) -> np.ndarray:
    """|angle| (rad) between mapped source headings and target headings."""
    v = np.column_stack([np.cos(src_heading), np.sin(src_heading)]) @ sim.rotation.T
    return np.abs(geo.wrap_angle(np.arctan2(v[:, 1], v[:, 0]) - dst_heading))


def _robust_proper(src, dst, threshold, iterations, seed, headings, heading_threshold_deg) -> ScaledRigid | None:
    """pycolmap's LO-RANSAC on the lifted (and heading) points, in coordinates normalised by each
    side's median spread so that the unknown scale is about 1 and one lift ``h`` serves both."""
    import pycolmap

    mu_s, mu_d = np.median(src, 0), np.median(dst, 0)
    sig_s = float(np.median(np.linalg.norm(src - mu_s, axis=1))) or 1.0
    sig_d = float(np.median(np.linalg.norm(dst - mu_d, axis=1))) or 1.0
    a, b, t = (src - mu_s) / sig_s, (dst - mu_d) / sig_d, threshold / sig_d
    s3, d3 = _lifted(a, b, t, t)
    if headings is not None:  # a point ahead of each camera: a wrong heading makes it an outlier
        ahead = t / (2 * np.sin(np.radians(heading_threshold_deg) / 2))
        hs, hd = headings
        s3 = np.vstack([s3, np.column_stack([a + ahead * np.column_stack([np.cos(hs), np.sin(hs)]), np.zeros(len(a))])])
        d3 = np.vstack([d3, np.column_stack([b + ahead * np.column_stack([np.cos(hd), np.sin(hd)]), np.zeros(len(b))])])
    opts = pycolmap.RANSACOptions(
        max_error=t, random_seed=int(seed), max_num_trials=int(iterations), min_num_trials=min(int(iterations), 100)
    )
    found = pycolmap.estimate_sim3d_robust(s3, d3, opts)
    fit = None if found is None else _to_2d(found["tgt_from_src"])
    if fit is None:
        return None
    scale = fit.scale * sig_d / sig_s  # back to the original coordinates
    return ScaledRigid(
        scale=scale,
        rotation=fit.rotation,
        translation=mu_d + sig_d * fit.translation - scale * fit.rotation @ mu_s,
    )


def ransac_scaled_rigid(
    src: np.ndarray,
    dst: np.ndarray,
    threshold: float = 10.0,
    iterations: int = 1000,
    seed: int = 0,
    allow_reflection: bool = True,
    src_heading: np.ndarray | None = None,
    dst_heading: np.ndarray | None = None,
    heading_threshold_deg: float = 30.0,
    source: str = "cameras",
) -> ScaledRigid:
    """Robust 2D similarity src -> dst (N, 2): pycolmap's LO-RANSAC, then a least-squares refit on
    the inliers (within ``threshold``, in dst units; with headings, in radians CCW, also within
    ``heading_threshold_deg``). A mirrored fit is tried too when ``allow_reflection``; the one with
    more inliers wins (ties: the lower residual sum). Seeded: the same input gives the same fit."""
    src, dst = _check(src, dst, source)
    headings = None
    if src_heading is not None and dst_heading is not None:
        hs, hd = np.asarray(src_heading, float), np.asarray(dst_heading, float)
        if hs.shape != (len(src),) or hd.shape != (len(src),):
            raise InputError(source, "one heading per camera is needed on both sides")
        headings = (hs, hd)
    h_thr = np.radians(heading_threshold_deg)

    def score(sim: ScaledRigid) -> tuple[np.ndarray, np.ndarray]:
        res = np.linalg.norm(sim.apply(src) - dst, axis=1)
        inl = res <= threshold
        if headings is not None:
            inl &= _heading_residual(sim, *headings) <= h_thr
        return inl, res

    best, best_key = None, None
    for mirrored in (False, True) if allow_reflection else (False,):
        s = src @ _MIRROR if mirrored else src
        hs = None if headings is None else (-headings[0] if mirrored else headings[0], headings[1])
        fit = _robust_proper(s, dst, threshold, iterations, seed, hs, heading_threshold_deg)
        if fit is None:
            continue
        fit = _fold_mirror(fit) if mirrored else fit
        inl, res = score(fit)
        if inl.sum() >= 2:  # the least-squares fit on the inliers (exact for exact inliers)
            ref = _proper_least_squares(src[inl] @ _MIRROR if mirrored else src[inl], dst[inl], refits=6)
            if ref is not None:
                ref = _fold_mirror(ref) if mirrored else ref
                if score(ref)[0].sum() >= inl.sum():
                    fit = ref
        inl, res = score(fit)
        key = (int(inl.sum()), -float(np.minimum(res, threshold).sum()))
        if best_key is None or key > best_key:
            best, best_key = fit, key
    if best is None or best_key[0] < 2:
        raise InputError(source, f"no scaled rigid transform explains at least 2 cameras within {threshold} m")
    best.inliers, best.residuals = score(best)
    return best


def _check(src, dst, source: str) -> tuple[np.ndarray, np.ndarray]:
    src_d = np.asarray(src, float)
    if src_d.ndim != 2 or src_d.shape[1] != 2:
        raise InputError(source, f"source points must be (N, 2), got shape {src_d.shape}")
    src = geo.check_points(src, 2, 3, source, "cameras with GPS")
    dst = geo.check_points(dst, 2, 3, source, "GPS positions")
    if len(src) != len(dst):
        raise InputError(source, f"{len(src)} camera positions but {len(dst)} GPS positions")
    if np.ptp(src, axis=0).max() == 0:
        raise InputError(source, "degenerate: all camera positions coincide or lie on one point")
    return src, dst


def transform_error(est: ScaledRigid, src: np.ndarray, true_dst: np.ndarray) -> dict:
    """Errors of an estimated transform against the truth on given points (metres)."""
    e = np.linalg.norm(est.apply(src) - true_dst, axis=1)
    ref = least_squares(src, true_dst, allow_reflection=True)
    return {
        "median_m": float(np.median(e)),
        "max_m": float(e.max()),
        "rms_m": float(np.sqrt(np.mean(e**2))),
        "scale_ratio": float(est.scale / ref.scale),
        "rotation_deg": float(abs(geo.wrap_angle(np.radians(est.angle_deg() - ref.angle_deg()))) * 180 / np.pi),
        "reflection_correct": bool(est.reflection == ref.reflection),
    }
