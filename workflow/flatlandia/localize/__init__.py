"""Localize your own query: the camera pose of one image's objects on a reference map.

The Python side of ``flatlandia localize`` (workflow/flatlandia/cli.py), on the benchmark's code
path: the pose is :func:`flatlandia.solver.locate`'s, the function rule fine_eval and the city
search call, so a published test query written as a query file comes back with the pose the
benchmark's whole-map run gives it.

A **map** is loaded once (:func:`load_map`) and answers many queries (:func:`localize`):

- a scene's reference map: the workflow's ``results/{scene}/maps/reference_map.parquet`` (or its
  ``.geojson``), or any GeoParquet / GeoJSON of classed points (a ``class_label``, ``class`` or
  ``label`` property holding a Mapillary Vistas label of ``classes.tsv``, or a ``class_id``; lon/lat
  as columns, Point geometries or, for GeoJSON, coordinates). The workflow's maps come with what
  the benchmark gives the solver when the files exist: the scene's training cameras (the train
  split of ``results/{scene}/queries/queries.parquet``: the camera prior and co-visibility) and,
  for depth queries, the learned scale prior and verifier (``results/solver/priors/whole.json``);
  any other map is searched without priors unless ``learned`` names a priors file;
- a city index (``results/city/{n}/index``, or one of its ``.npz``): the city search
  (:mod:`flatlandia.city.search`: the index proposes regions, the solver searches them with the
  training views there as priors); lon/lat come from the city's ``map.parquet`` beside the index
  (a tiled city: each tile is a published scene moved by a translation, and keeps its lon/lat).

A **query** is JSON, ``{"objects": [{"class": "<Vistas label>", "x": <forward>, "y": <left>}, ...]}``
(camera at the origin looking along +x, +y to its left; at least 3 objects), or a file of many,
``{"queries": [{"id": ..., "objects": [...]}, ...]}``. Map type ``gt``: x/y in metres; ``depth``: x/y
in any unit (the scale is unknown and solved for; bearings must be true).

A **photo** (:func:`read_photo`, ``flatlandia localize --image``) becomes a depth query as the images
branch sees objects: the configured segmentation's object classes (one object per connected region),
the configured monocular depth model's ranges, the bearings of the photo's EXIF camera
(:mod:`flatlandia.images.photo_query`; learned backends only: docs/backends.md).

A **prior** (optional): a phone's GPS fix ``gps=(lon, lat, sigma_m)`` and a compass heading
``compass=(heading_deg clockwise from north, sigma_deg)``, weighed as Gaussian likelihoods by the
solver (poses within 4 sigma of the fix are kept; on a city the fix's region replaces the index's).
A **sequence** (optional, depth maps): several frames localized together (:func:`read_sequence`,
:func:`localize_sequence`), ``{"frames": [{"objects": [...]}, {"objects": [...], "pose": {"x":
<forward m>, "y": <left m>, "theta_deg": <turn, counter-clockwise>}, "sigma_m": ..., "sigma_deg":
...}, ...]}``: the first frame is the anchor, whose pose is returned; each other frame gives where its
camera stood in the anchor's camera frame (odometry) and, optionally, that pose's noise.

Each answer is a dict (:func:`localize`): the pose (lon, lat, x_m, y_m in the map's metric frame,
heading_deg clockwise from north, theta_deg counter-clockwise from east as the benchmark's tables),
the depth map's scale, a confidence, which map object each query object matched, the next-best
distinct poses and the priors used, and the answer's ``status`` (``ok``, ``ambiguous`` or ``no pose``)
with its calibrated ``probability`` of being within (5 m, 5 deg) (each alternative has its own). Bad input raises :class:`flatlandia.plumbing.errors.InputError`, one
line naming the file and the problem.
"""

from flatlandia.localize.answers import answer_status, dumps, no_pose_reason
from flatlandia.localize.gps_fixes import check_prior, fixes, prior_warnings
from flatlandia.localize.maps import (
    MAP_TYPES,
    ObjectMap,
    Tile,
    load_map,
    place,
    scene_cities,
    scene_xy,
    set_training_priors,
)
from flatlandia.localize.query_files import (
    MIN_OBJECTS,
    Query,
    Sequence,
    class_id,
    parse_query,
    parse_sequence,
    query_json,
    read_photo,
    read_queries,
    read_sequence,
)
from flatlandia.localize.solve import ALTERNATIVES, localize, localize_file, localize_sequence

__all__ = [
    "ALTERNATIVES",
    "MAP_TYPES",
    "MIN_OBJECTS",
    "ObjectMap",
    "Query",
    "Sequence",
    "Tile",
    "answer_status",
    "check_prior",
    "class_id",
    "dumps",
    "fixes",
    "load_map",
    "localize",
    "localize_file",
    "localize_sequence",
    "no_pose_reason",
    "parse_query",
    "parse_sequence",
    "place",
    "prior_warnings",
    "query_json",
    "read_photo",
    "read_queries",
    "read_sequence",
    "scene_cities",
    "scene_xy",
    "set_training_priors",
]
