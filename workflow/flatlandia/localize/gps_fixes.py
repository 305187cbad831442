"""A phone's prior position: a GPS fix and a compass heading as the solver's
:class:`~flatlandia.solver.Fix` (:func:`fixes`), checked at the door (:func:`check_prior`), and
warnings where it cannot be right for the map (:func:`prior_warnings`: lon and lat swapped, a
position outside the map's area).
"""

from __future__ import annotations

import math

from flatlandia.localize.object_map import ObjectMap, metres_to_map
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

#: what a prior position is checked against: a fix (or --near) this many times nearer the map read
#: the other way round is reported as lon/lat swapped (as flatlandia score's FAR_SMALLER)
SWAP_NEARER = 5.0


def far(d: float) -> str:
    return f"{d / 1000:,.0f} km" if d >= 10_000 else f"{d:,.0f} m"


def prior_warnings(m: ObjectMap, gps=None, near=None, radius_m=None) -> list[str]:
    """Warnings (not errors: the answer is still computed) where a prior position cannot be right
    for this map, as ``flatlandia score`` warns on a convention mixed up: lon and lat that look
    swapped (read the other way round, the position lies near the map), or a position farther
    from every map object than its reach (a fix: its 4 sigma plus what a camera sees, the map
    objects the solver searches; ``--near``: its radius): outside the map's area."""
    from flatlandia.solver.priors import Fix

    out = []
    view = Fix.VIEW_M
    for flag, pos, reach, what in (
        (
            "--gps",
            gps,
            None if gps is None else Fix.GATE_SIGMAS * float(gps[2]) + view,
            "4 sigma plus the {view:g} m a camera sees",
        ),
        ("--near", near, radius_m, "--radius-m"),
    ):
        if pos is None or reach is None:
            continue
        lon, lat = float(pos[0]), float(pos[1])
        d = metres_to_map(m, lon, lat)
        if d is None or d <= reach:
            continue
        swapped = metres_to_map(m, lat, lon)
        if swapped is not None and swapped * SWAP_NEARER < d and swapped <= max(reach, 1000.0):
            out.append(
                f"{flag} {lon},{lat}: lon and lat look swapped: read as {lat},{lon} it lies {far(swapped)} "
                f"from the map's nearest object instead of {far(d)} (give LON,LAT: longitude first)"
            )
        else:
            lo, hi = m.lonlat.min(axis=0), m.lonlat.max(axis=0)
            out.append(
                f"{flag} {lon},{lat} is {far(d)} from the map's nearest object, beyond its reach ({reach:g} m: "
                f"{what.format(view=view)}): outside the map's area (lon {lo[0]:.5f} to {hi[0]:.5f}, lat "
                f"{lo[1]:.5f} to {hi[1]:.5f})? No pose can lie near it"
            )
    return out


def check_prior(gps, compass) -> None:
    """InputError unless ``gps`` is (lon, lat, sigma_m > 0) and ``compass`` (heading_deg, sigma_deg > 0)."""
    if compass is not None and gps is None:
        raise InputError("--compass", "a compass heading needs a GPS fix too (--gps and --gps-sigma-m)")
    if gps is not None:
        if len(gps) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in gps):
            raise InputError("--gps", f"{gps} is not lon, lat, sigma_m")
        if abs(gps[0]) > 180 or abs(gps[1]) > 90:
            raise InputError("--gps", f"{gps[:2]} is not lon, lat in degrees")
        if not 0 < gps[2] <= validate.MAX_PRIOR_M:
            raise InputError(
                "--gps-sigma-m", f"{gps[2]} is not a positive number of metres up to {validate.MAX_PRIOR_M:g}"
            )
    if compass is not None:
        if len(compass) != 2 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in compass):
            raise InputError("--compass", f"{compass} is not heading_deg, sigma_deg")
        if not 0 < compass[1] <= validate.MAX_COMPASS_SIGMA_DEG:
            raise InputError(
                "--compass-sigma-deg",
                f"{compass[1]} is not a positive number of degrees up to {validate.MAX_COMPASS_SIGMA_DEG:g}",
            )


def fixes(m: ObjectMap, gps, compass=None) -> list:
    """The prior as the solver's :class:`~flatlandia.solver.Fix` in the map's metres, one per
    position :meth:`~flatlandia.localize.object_map.ObjectMap.near_rows` gives it: one on a scene
    map; on a city, one per tile whose objects lie near the fix (each tile keeps its scene's
    lon/lat). ``gps``: (lon, lat, sigma_m); ``compass``: (heading_deg clockwise from north, sigma_deg)."""
    from flatlandia import solver

    check_prior(gps, compass)
    lon, lat, sigma = (float(v) for v in gps)
    theta = hsig = None
    if compass is not None:  # compass: clockwise from north; the solver's theta: counter-clockwise from east
        theta, hsig = math.radians(90.0 - float(compass[0])), float(compass[1])
    probe = solver.Fix(0.0, 0.0, sigma)
    centres = m.near_rows((lon, lat), probe.crop_m, "--gps")[1]
    return [solver.Fix(float(c[0]), float(c[1]), sigma, theta, hsig) for c in centres]


def gps_used(gps, compass) -> dict:
    out = {"lon": float(gps[0]), "lat": float(gps[1]), "sigma_m": float(gps[2])}
    if compass is not None:
        out.update(compass_deg=float(compass[0]), compass_sigma_deg=float(compass[1]))
    return out
