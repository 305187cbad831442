"""Map kinds as types (issue 46): a kind of map is one class of
:class:`flatlandia.localize.object_map.ObjectMap`, chosen once where the file is read
(:data:`flatlandia.localize.maps.KINDS`). A kind defined here, and added to the reader's list
alone, is answered by ``flatlandia localize`` and the API as the built-in kinds are: nothing else
of the localizer changes for it. (That no module of localize/ branches on a kind's name is
tests/test_architecture.py's check.) Fast: the tiny scene."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from one_tile_city import write_one_tile_city
from test_localize import query_file, run_cli, tiny_scene  # noqa: F401

from flatlandia import localize, solver
from flatlandia.data import localmaps, reference_map
from flatlandia.localize import maps
from flatlandia.localize.object_map import Found, ObjectMap
from flatlandia.plumbing.errors import InputError


@dataclass(kw_only=True)
class ObjectList(ObjectMap):
    """A kind of map of its own: a text file, one object per line (``class_id x y``, metres of a
    local frame), searched whole by the solver without priors. It defines how it is read and
    searched; every other answer (lon/lat, the scene a pose lies in, --near) is the base class's."""

    kind = "object list"
    suffixes = (".objects",)
    described = "an object list (.objects)"

    @classmethod
    def read(cls, path: Path, settings, learned, search) -> ObjectList:
        table = np.array([line.split() for line in path.read_text().splitlines() if line.strip()], float)
        return cls(
            path=path,
            obj_idx=np.arange(len(table)),
            cls=table[:, 0].astype(np.int64),
            xy=table[:, 1:3],
            lonlat=None,
            settings=solver.SolverConfig.of(settings),
            frame="an object list's local frame (metres)",
        )

    def locate(self, xy, cls, map_type, alternatives, *, rows=None, near=None, radius_m=None, fix=None) -> Found:
        rows = np.arange(len(self.xy)) if near is None else self.near_rows(near, radius_m)[0]  # the base refuses
        found = solver.locate(
            xy,
            cls,
            self.xy[rows],
            self.cls[rows],
            metric=map_type == "gt",
            config=self.settings,
            alternatives=alternatives,
        )
        return Found(found.best, found.alternatives, rows)

    def locate_sequence(self, frames, rel, sigma, settings, alternatives, fix=None):
        found = solver.locate_sequence(frames, rel, self.xy, self.cls, self.settings, None, settings, sigma, fix)
        return found, np.arange(len(self.xy))


@pytest.fixture
def object_list(tiny_scene, tmp_path, monkeypatch) -> Path:  # noqa: F811
    """The tiny scene's objects as an object list, its kind added to the reader's list (alone)."""
    ref, _, _ = tiny_scene
    path = tmp_path / "tiny.objects"
    path.write_text("".join(f"{r.class_id} {r.x_m!r} {r.y_m!r}\n" for r in ref.itertuples()))
    monkeypatch.setattr(maps, "KINDS", (*maps.KINDS, ObjectList))
    return path


def test_a_new_kind_of_map_is_its_class_and_its_line_in_the_reader(object_list, tiny_scene, tmp_path, capsys):  # noqa: F811
    """The command and the API answer on the new kind: a GT query comes back at its camera, the
    same pose as on a scene map of the same objects without lon/lat (the solver's, on the same
    rows); a sequence too; --near and --gps are refused with the base class's one line."""
    ref, meta, q = tiny_scene
    m = localize.load_map(object_list)
    assert isinstance(m, ObjectList) and m.kind == "object list"
    local = tmp_path / "local.geojson"  # the same objects as a scene map in a local frame, no priors
    reference_map.write_geojson(ref, {**meta, "frame": "local"}, local)
    scene = localize.load_map(local, learned=None)
    assert scene.kind == "scene" and scene.lonlat is None
    for r in q[q["split"] == "test"].itertuples(index=False):
        qfile = query_file(tmp_path / "q.json", r)
        status, text = run_cli(capsys, "--map", object_list, "--query", qfile)
        out = json.loads(text)
        assert status == 0 and out["found"] and math.hypot(out["x_m"] - r.x_m, out["y_m"] - r.y_m) < 1e-3
        assert (out["lon"], out["scene"], out["heading_deg"]) == (None, None, None)
        assert out["frame"] == "an object list's local frame (metres)" and out["priors"]["training_cameras"] == 0
        same = localize.localize_file(scene, qfile)
        for key in ("x_m", "y_m", "theta_deg", "cost", "confidence", "status", "probability"):
            assert out[key] == same[key], key
        assert [(a["query_object"], a["class"]) for a in out["matches"]] == [
            (a["query_object"], a["class"]) for a in same["matches"]
        ]
    anchor = q[q["split"] == "test"].iloc[0]
    seq = {"frames": [localize.query_json(localmaps.local_map(anchor, "depth"), anchor.classes)]}
    got, same = localize.localize_sequence(m, seq), localize.localize_sequence(scene, seq)
    assert got["found"] and [got[k] for k in ("x_m", "y_m", "scale", "cost")] == [
        same[k] for k in ("x_m", "y_m", "scale", "cost")
    ]
    qfile = query_file(tmp_path / "q.json", anchor)
    status, err = run_cli(capsys, "--map", object_list, "--query", qfile, "--near", "2.0,48.0", "--radius-m", "50")
    assert status and "--near needs a map with lon/lat; this one has a local frame" in err
    status, err = run_cli(capsys, "--map", object_list, "--query", qfile, "--gps", "2.0,48.0", "--gps-sigma-m", "5")
    assert status and "--gps needs a map with lon/lat; this one has a local frame" in err


def test_the_reader_names_every_kind_for_a_file_of_none(object_list, tmp_path):
    """A file no kind reads: the one line lists the kinds, the new one with them."""
    other = tmp_path / "map.txt"
    other.write_text("1 0 0\n")
    with pytest.raises(InputError) as e:
        localize.load_map(other)
    assert str(e.value).endswith(
        "not a map: expected a reference map (.parquet, .geojson) or a city index (.npz, folder) "
        "or an object list (.objects)"
    )


def test_a_sequence_whose_fix_falls_in_no_tile_of_a_city_has_no_pose(tiny_scene, tmp_path):  # noqa: F811
    """A fix 1 km off a city's tiles gives the sequence no region to search: no pose, and why (the
    single query's answer; it was an IndexError)."""
    ref, _, q = tiny_scene
    city = tmp_path / "results" / "city" / "1"
    _, cq = write_one_tile_city(ref, q, city)
    m = localize.load_map(city / "index")
    r = cq[cq["split"] == "test"].iloc[0]
    seq = {"frames": [localize.query_json(localmaps.local_map(r, "depth"), r.classes)]}
    gps = (float(r.lon), float(r.lat) + 0.01, 10.0)
    got = localize.localize_sequence(m, seq, gps=gps)
    one = localize.localize(m, localize.parse_query(seq["frames"][0]), "depth", gps=gps)
    assert not got["found"] and got["status"] == one["status"] == "no pose" and got["searched"] == 0
    assert got["reason"] == one["reason"] and "no map object within 4 sigma" in got["reason"]
