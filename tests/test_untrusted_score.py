"""Untrusted inputs, third pass, `flatlandia score`'s door: a poses file is read within bounds (bytes
on disk and, compressed, once decompressed, as a stream; rows; regular files only: finding 5),
each pose is checked against its scene's extent and the unit mix-ups that would explain it
(kilometres, radians, swapped columns: finding 7), and only plain decimal numbers are numbers
(finding 10). On the tiny scene's results (the fixtures of tests/test_score.py): fast."""

# ruff: noqa: F811 (the tiny results' fixtures of tests/test_score.py, imported, are the tests' arguments)
from __future__ import annotations

import gzip
import os
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from test_score import _cli, _geographic, _metric, _noisy, _truth, _write, tiny_results, tiny_scenes  # noqa: F401

from flatlandia import score
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError
from flatlandia.score import poses

SCORE = ("--name", "mine", "--split", "train")


def _score(capsys, path, results, out) -> tuple[int, list[str]]:
    return _cli(capsys, path, *SCORE, "--out", out, "--results", results)


def _one_error(rc: int, lines: list[str], path, *says: str) -> str:
    assert rc == 1 and len(lines) == 1 and lines[0].startswith(f"ERROR: {path}: "), lines
    for s in says:
        assert s in lines[0], (s, lines[0])
    return lines[0]


# ----------------------------------------------------------------------------- 5. bounded reading


def test_a_compressed_file_is_decompressed_as_a_stream_and_stopped_at_its_bound(
    tiny_results, tiny_scenes, tmp_path, capsys
):
    """A few hundred kB of .csv.gz holding more than MAX_POSES_BYTES of rows: refused while reading
    (it took 7.2 GB and 3 min before its ERROR)."""
    rows = _metric(_truth(tiny_scenes)).to_csv(index=False, header=False).encode()
    path = tmp_path / "bomb.csv.gz"
    with gzip.open(path, "wb", compresslevel=1) as f:
        f.write(b"scene,token,x_m,y_m,theta_deg\n")
        for _ in range(validate.MAX_POSES_BYTES // len(rows) + 2):
            f.write(rows)
    assert path.stat().st_size < validate.MAX_POSES_BYTES / 20
    t0 = time.process_time()
    rc, lines = _score(capsys, path, tiny_results, tmp_path / "out")
    _one_error(rc, lines, path, "decompresses to over 64,000,000 bytes", "MAX_POSES_BYTES")
    assert time.process_time() - t0 < 30 and not (tmp_path / "out").exists()


def test_a_file_over_the_bound_on_disk_is_refused_before_it_is_read(tiny_results, tmp_path, capsys):
    path = tmp_path / "sparse.csv"
    with open(path, "wb") as f:
        f.write(b"scene,token,x_m,y_m,theta_deg\n")
        f.truncate(validate.MAX_POSES_BYTES + 1)  # sparse: nothing is written
    t0 = time.process_time()
    _one_error(
        *_score(capsys, path, tiny_results, tmp_path / "out"), path, "over the limit of 64,000,000", "MAX_POSES_BYTES"
    )
    assert time.process_time() - t0 < 2


def test_a_parquet_file_with_too_many_rows_is_refused_from_its_footer(tiny_results, tiny_scenes, tmp_path, capsys):
    t = _metric(_truth(tiny_scenes))
    many = t.iloc[np.arange(validate.MAX_POSES_ROWS + 1) % len(t)]
    path = tmp_path / "many.parquet"
    many.to_parquet(path, index=False)
    _one_error(*_score(capsys, path, tiny_results, tmp_path / "out"), path, "200,001 rows", "MAX_POSES_ROWS")


def test_a_pipe_as_poses_file_is_refused_without_being_opened(tiny_results, tmp_path):
    fifo = tmp_path / "poses.csv"
    os.mkfifo(fifo)
    args = ["score", str(fifo), *SCORE, "--out", str(tmp_path / "out"), "--results", str(tiny_results)]
    res = subprocess.run([sys.executable, "-m", "flatlandia.cli", *args], capture_output=True, text=True, timeout=60)
    assert res.returncode == 1 and res.stderr.strip().splitlines() == [
        f"ERROR: {fifo}: is not a regular file (a named pipe, a device or a socket): refused without reading it"
    ], (res.stdout, res.stderr[-2000:])


# ----------------------------------------------------------------------------- 7. pose by pose


def test_positions_in_kilometres_stop_the_file_and_a_few_are_named(tiny_results, tiny_scenes, tmp_path, capsys):
    """x_m, y_m in km (a median error of 38.7 m on the published scenes) passed without a word."""
    t = _noisy(_truth(tiny_scenes), metres=0.5)
    km = t.assign(x_m=t["x_m"] / 1000, y_m=t["y_m"] / 1000)
    path = _write(km, tmp_path / "km.csv")
    _one_error(
        *_score(capsys, path, tiny_results, tmp_path / "out"), path, "10 of its 10 poses look wrong", "kilometres"
    )
    assert not (tmp_path / "out").exists()
    some = pd.concat([km.iloc[:4], t.iloc[4:]], ignore_index=True)
    path = _write(some, tmp_path / "some.csv")
    rc, lines = _score(capsys, path, tiny_results, tmp_path / "out")
    warnings = [ln for ln in lines if ln.startswith("WARNING:")]
    assert rc == 0 and len(warnings) == 1 and "4 of its 10 poses look wrong" in warnings[0], lines
    assert all(f"line {k} (scene" in warnings[0] for k in (2, 3, 4, 5)) and "line 6 " not in warnings[0]


def test_lon_lat_in_radians_or_outside_the_scene_stop_the_file(tiny_results, tiny_scenes, tmp_path, capsys):
    """lon/lat in radians put the poses 5,326 km away: no warning before."""
    t = _noisy(_truth(tiny_scenes), metres=0.5)
    g = _geographic(t, tiny_scenes)
    rad = g.assign(lon=np.radians(g["lon"]), lat=np.radians(g["lat"]))
    path = _write(rad, tmp_path / "rad.csv")
    _one_error(*_score(capsys, path, tiny_results, tmp_path / "o1"), path, "poses look wrong", "radians")
    far = t.assign(x_m=t["x_m"] + 3000.0)  # 3 km east of every object and camera: no reading explains it
    path = _write(far, tmp_path / "far.csv")
    _one_error(*_score(capsys, path, tiny_results, tmp_path / "o2"), path, "outside the scene", "km outside the scene")


def test_honest_rows_are_never_suspected(tiny_scenes, tmp_path):
    t = _truth(tiny_scenes)
    rng = np.random.default_rng(7)
    for k, df in enumerate([_noisy(t, metres=3.0), _metric(t).assign(x_m=rng.uniform(-200, 200, len(t)))]):
        poses = score.read_poses(_write(df, tmp_path / f"h{k}.csv"), tiny_scenes, "train")
        assert score.row_plausibility(poses, tiny_scenes) == []


# ----------------------------------------------------------------------------- 10. numbers, long cells


@pytest.mark.parametrize("cell", ["1_000", "\uff11\uff12", "1 000", "0x10", "٣"])
def test_only_plain_decimal_numbers_are_numbers(tiny_results, tiny_scenes, tmp_path, capsys, cell):
    """float() takes '1_000' and full-width or Arabic-Indic digits; no CSV means them."""
    t = _metric(_truth(tiny_scenes)).astype(str)
    t.loc[0, "x_m"] = cell
    path = _write(t, tmp_path / "p.csv")
    _one_error(*_score(capsys, path, tiny_results, tmp_path / "out"), path, "x_m is not a number in line 2")


def test_a_long_token_is_quoted_by_its_start(tiny_results, tiny_scenes, tmp_path, capsys):
    t = _metric(_truth(tiny_scenes))
    t.loc[0, "token"] = "7" * 10_000_000
    path = _write(t, tmp_path / "long.csv")
    line = _one_error(*_score(capsys, path, tiny_results, tmp_path / "out"), path, "unknown token")
    assert len(line) < 2000, len(line)


def test_a_cell_the_export_made_safe_reads_back_as_its_value(tiny_scenes, tmp_path):
    """The export writes a token '=x' as "'=x" (flatlandia.plumbing.escape.csv_cell); scoring reads it as '=x'."""
    t = _metric(_truth(tiny_scenes)).astype(str)
    t["token"] = "'" + t["token"]  # a token that is text already: '123 stays '123 (not a formula)
    with pytest.raises(InputError, match="unknown token"):
        score.read_poses(_write(t, tmp_path / "q.csv"), tiny_scenes, "train")
    assert poses._text(["'=HYPERLINK(1)", "'-cmd|x", "-AB21Af_LPev08UY_96ptQ", "'abc"]) == [
        "=HYPERLINK(1)",
        "-cmd|x",
        "-AB21Af_LPev08UY_96ptQ",
        "'abc",
    ]
