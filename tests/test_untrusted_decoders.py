"""Untrusted inputs, fourth pass (issue 42, findings 7 and 9's config bits): every decoder is bounded on
what it DECODES to, not only on what lies on disk. A 477-byte YAML alias bomb (14 min of CPU in
validate.depth), a key given twice in a config, `images.max_megapixels: 1e300` and `min_side_px: 1e23`,
a 5 kB Parquet whose dictionary value repeats 200,000 times (3.8 GB), a Parquet whose footer lies
about its pages, and a 1.5 MB checkpoint whose tensor record is deflated (2 GB in torch.load) are
each one refusal naming the file and the bound, fast and in little memory. Fast: files built here."""

from __future__ import annotations

import json
import math
import signal
import struct
import subprocess
import sys
import time
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
import yaml
from conftest import smk_dry_run

from flatlandia import checkpoints, config
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

MB = 1_000_000
#: the probe's bomb (477 bytes there, 491 here): nine lists of nine, each naming the one before nine
#: times (9**9 values)
ALIAS_BOMB = "fine:\n  a0: &a0 [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"  a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]\n" for i in range(1, 9)
)


@contextmanager
def within(seconds: float):
    """Fail (not hang) when the block takes longer: the unbounded walks took minutes to hours."""

    def stop(*_):
        raise TimeoutError(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# ----------------------------------------------------------------------------- 7. the YAML alias bomb


def test_an_alias_bomb_config_file_is_refused_in_milliseconds_naming_the_file(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(ALIAS_BOMB)
    assert len(ALIAS_BOMB) < 500
    t0 = time.process_time()
    with within(5), pytest.raises(InputError) as err:
        validate.read_config(path)
    assert str(err.value).startswith(
        f"{path}: its aliases expand to over 100,000 values"
    ) and "MAX_CONFIG_NODES" in str(err.value)
    assert time.process_time() - t0 < 1


def test_a_config_built_with_shared_subtrees_is_refused_fast_by_resolve():
    """What Snakemake hands the workflow: the bomb loaded with aliases as shared references."""
    cfg = yaml.safe_load(ALIAS_BOMB)
    t0 = time.process_time()
    with within(5), pytest.raises(config.ConfigError, match=r"'fine': .*over 100,000 values .*MAX_CONFIG_NODES"):
        config.resolve(cfg)
    assert time.process_time() - t0 < 1
    loop: list = []
    loop.append(loop)
    with within(5), pytest.raises(config.ConfigError, match="'select': the value holds itself"):
        config.resolve({"select": loop})


def test_validate_depth_is_linear_in_distinct_containers():
    """Each list of the bomb is walked once; its size, reused where it reappears, is what a
    recursive walk would have met (the old walk met every one of them: 14 min)."""
    value = yaml.safe_load(ALIAS_BOMB)
    sizes = [10]  # a0: itself and its nine x; each a_k: itself and nine a_(k-1)
    for _ in range(8):
        sizes.append(1 + 9 * sizes[-1])
    with within(5):
        assert validate.depth(value) == 11
        assert validate.tree_shape(value) == (11, 2 + sum(sizes))
        assert validate.tree_shape(value, max_nodes=1000)[1] > 1000  # stopped at the first list past it


def test_the_workflow_stops_at_an_alias_bomb_before_any_job(repo, tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(ALIAS_BOMB)
    t0 = time.monotonic()
    res = smk_dry_run(repo, tmp_path, "all", "--configfile", str(path))
    errors = [ln for ln in (res.stdout + res.stderr).splitlines() if "ERROR" in ln]
    assert res.returncode == 1 and errors == [
        f"ERROR: {path}: its aliases expand to over 100,000 values, over the limit "
        "(flatlandia.plumbing.validate.MAX_CONFIG_NODES): an alias bomb?"
    ], (res.stdout[-2000:], res.stderr[-2000:])
    assert "Traceback" not in res.stderr and time.monotonic() - t0 < 120


# ----------------------------------------------------------------------------- 9. a key given twice


@pytest.mark.parametrize(
    "text, says",
    [
        ("seed: 1\nsolver:\n  top_k: 3\n  top_k: 4\n", "line 4: key 'top_k' given twice (first on line 3)"),
        ("images: {missing_gps: keep, missing_gps: stop}\n", "line 1: key 'missing_gps' given twice"),
        ('{"seed": 1, "seed": 2}', "key 'seed' given twice in one object"),
    ],
)
def test_a_key_given_twice_in_a_config_file_is_refused_with_its_line(tmp_path, text, says):
    path = tmp_path / "twice.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        validate.read_config(path)
    assert str(err.value).startswith(f"{path}: {says}"), str(err.value)


def test_a_yte_template_config_is_refused(tmp_path):
    """Snakemake evaluates a `__use_yte__` file's `?...` expressions as Python while loading it (before
    the Snakefile runs: nothing the workflow does can stop that); the run then stops, saying so."""
    path = tmp_path / "template.yaml"
    path.write_text("__use_yte__: true\nseed: ?1 + 1\n")
    with pytest.raises(InputError, match=r"a YTE template \(__use_yte__\): Snakemake ran its Python expressions"):
        validate.read_config(path)


def test_merge_keys_still_merge_and_the_default_config_reads(repo, tmp_path):
    path = tmp_path / "merge.yaml"
    path.write_text("base: &b {top_k: 3, tau: 2.0}\nsolver:\n  <<: *b\n  top_k: 4\n")
    assert validate.read_config(path)["solver"] == {"top_k": 4, "tau": 2.0}
    assert validate.read_config(repo / "config" / "config.yaml") == config.section_defaults()
    assert validate.read_config(repo / "config" / "paper.yaml")["fine"]["train"]["epochs"] == 1000


# ----------------------------------------------------------------------------- 9. numbers bounded by the schema


@pytest.mark.parametrize(
    "section, key, value",
    [("images", "max_megapixels", 1e300), ("images", "min_side_px", 10**23), ("fine", "train", {"epochs": 10**12})],
)
def test_absurd_config_numbers_are_refused_before_any_job(section, key, value):
    with pytest.raises(config.ConfigError) as err:
        config.resolve({section: {key: value}})
    assert f"'{section}.{key}" in str(err.value) and "greater than the maximum" in str(err.value), str(err.value)


def _numeric_nodes(node, name=""):
    """(dotted name, schema node) of every number or integer of the schema, in lists and maps too."""
    if not isinstance(node, dict):
        return
    kinds = node.get("type", [])
    if {"number", "integer"} & set([kinds] if isinstance(kinds, str) else kinds):
        yield name, node
    for key, child in node.get("properties", {}).items():
        yield from _numeric_nodes(child, f"{name}.{key}" if name else key)
    for key, suffix in (("items", "[]"), ("additionalProperties", ".*")):
        yield from _numeric_nodes(node.get(key), name + suffix)


def test_every_number_of_the_schema_has_a_finite_minimum_and_maximum():
    nodes = dict(_numeric_nodes(config.schema()))
    assert len(nodes) > 80  # the walk finds them (fine.train's are shared by its overrides)
    for name, node in nodes.items():
        high = node.get("maximum", node.get("exclusiveMaximum"))
        low = node.get("minimum", node.get("exclusiveMinimum"))
        assert isinstance(high, (int, float)) and math.isfinite(high), f"{name}: no finite maximum"
        assert isinstance(low, (int, float)) and math.isfinite(low), f"{name}: no finite minimum"
        default = node.get("default")
        if isinstance(default, (int, float)) and not isinstance(default, bool):
            assert low <= default <= high, f"{name}: its default {default} lies outside [{low}, {high}]"


# ----------------------------------------------------------------------------- 7. Parquet dictionary bombs

#: a child reads the file under this address-space cap (what its imports take, and 1.3 GB more), so
#: an unbounded read fails there instead of taking the machine's memory
CHILD_CAP = 2_000_000_000
CHILD = """
import resource, sys
from pathlib import Path
resource.setrlimit(resource.RLIMIT_AS, ({cap}, {cap}))
from flatlandia.plumbing.errors import InputError
{imports}
try:
    {call}
    print("READ")
except InputError as e:
    print("ERROR:", e)
# this image's own peak (VmHWM: a new image at exec); ru_maxrss keeps the forking worker's peak on Linux
hwm = [line for line in open("/proc/self/status") if line.startswith("VmHWM:")]
print("MAXRSS_MB", int(hwm[0].split()[1]) / 1000 if hwm else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1000)
"""


def _child(imports: str, call: str) -> tuple[str, float]:
    """(the child's outcome line, its peak RSS in MB) of ``call`` run in a fresh Python."""
    code = CHILD.format(cap=CHILD_CAP, imports=imports, call=call)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    lines = res.stdout.strip().splitlines()
    assert res.returncode == 0 and lines and lines[-1].startswith("MAXRSS_MB"), (res.stdout, res.stderr[-3000:])
    return lines[-2], float(lines[-1].split()[1])


def _repeated(value: str, rows: int) -> pa.DictionaryArray:
    """``rows`` cells all naming one dictionary value: what the file holds, never decoded here."""
    return pa.DictionaryArray.from_arrays(pa.array(np.zeros(rows, np.int32)), pa.array([value]))


def _write_plain(table: pa.Table, path: Path) -> Path:
    """As a writer of plain text columns leaves it: dictionary-encoded pages, no Arrow schema."""
    pq.write_table(table, path, compression="zstd", use_dictionary=True, store_schema=False)
    return path


def test_a_poses_parquet_dictionary_bomb_is_refused_in_little_memory(tmp_path):
    """4 kB on disk, 64 kB by its footer, 3.8 GB once decoded (its token column)."""
    n = validate.MAX_POSES_ROWS
    zeros = pa.array(np.zeros(n))
    table = pa.table(
        {
            "scene": _repeated("9", n),
            "token": _repeated("a" * 19_000, n),
            "x_m": zeros,
            "y_m": zeros,
            "theta_deg": zeros,
        }
    )
    path = _write_plain(table, tmp_path / "bomb.parquet")
    assert path.stat().st_size < 10_000
    outcome, peak = _child("from flatlandia.score import poses", f"poses._read_table(Path({str(path)!r}))")
    assert outcome.startswith(f"ERROR: {path}: its columns (up to 'token') decode to 3,8"), outcome
    assert "MAX_POSES_BYTES" in outcome and peak < 1000, (outcome, peak)


def test_a_map_parquet_dictionary_bomb_is_refused_in_little_memory(tmp_path):
    """60 kB on disk, 20,000 objects each naming ten 19 kB texts: 3.8 GB once decoded."""
    n = validate.MAX_MAP_OBJECTS
    cols = {"obj_idx": pa.array(np.arange(n)), "class_label": _repeated("pole", n)}
    cols |= {c: pa.array(np.zeros(n)) for c in ("lon", "lat")}
    cols |= {f"note{k}": _repeated(str(k) * 19_000, n) for k in range(10)}
    path = _write_plain(pa.table(cols), tmp_path / "map.parquet")
    assert path.stat().st_size < 100_000
    outcome, peak = _child("from flatlandia import localize", f"localize.load_map(Path({str(path)!r}))")
    assert outcome.startswith(f"ERROR: {path}: its columns (up to 'note0') decode to"), outcome
    assert "MAX_MAP_BYTES" in outcome and peak < 1000, (outcome, peak)


def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b, v = v & 0x7F, v >> 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


def test_a_parquet_whose_footer_hides_a_70_mb_page_is_refused_from_its_page_headers(tmp_path):
    """The footer's sizes are the writer's word: forged to 1 kB (same-length varints), pyarrow still
    decompressed the 70 MB page its header declares. The pages' headers are read first."""
    path = tmp_path / "forged.parquet"
    big = pa.DictionaryArray.from_arrays(pa.array(np.zeros(10, np.int32)), pa.array([b"\0" * 70 * MB], pa.binary()))
    pq.write_table(pa.table({"token": big}), path, compression="zstd", store_schema=False)
    data = bytearray(path.read_bytes())
    length = struct.unpack("<I", data[-8:-4])[0]
    footer = bytes(data[-8 - length : -8])
    meta = pq.ParquetFile(path).metadata
    for size in {meta.row_group(0).total_byte_size, meta.row_group(0).column(0).total_uncompressed_size}:
        true = _varint(size << 1)  # thrift compact: zigzag varints
        small = bytearray(_varint(1000 << 1))
        while len(small) < len(true):  # the same length: a varint padded with continuation bytes
            small[-1] |= 0x80
            small.append(0)
        footer = footer.replace(true, bytes(small))
    data[-8 - length : -8] = footer
    path.write_bytes(bytes(data))
    assert pq.ParquetFile(path).metadata.row_group(0).total_byte_size == 1000 and path.stat().st_size < 10_000
    with pytest.raises(InputError) as err:
        validate.read_parquet(path, validate.MAX_POSES_ROWS, validate.MAX_POSES_BYTES, names=("", "MAX_POSES_BYTES"))
    assert "its pages decompress to 70,000,0" in str(err.value) and "MAX_POSES_BYTES" in str(err.value)


def test_the_bounded_reader_reads_what_pandas_reads(tmp_path):
    """Flat and list columns, text, categoricals, nulls: the same frame as pandas.read_parquet."""
    import pandas as pd

    df = pd.DataFrame(
        {
            "scene": ["9", "9", "12"],
            "token": ["a", None, "c"],
            "kind": pd.Categorical(["x", "y", "x"]),
            "ref_idx": [[1, 2], [], [3]],
            "x_m": [1.0, np.nan, 3.0],
            "ok": [True, False, True],
        }
    )
    path = tmp_path / "t.parquet"
    df.to_parquet(path)
    got = validate.read_parquet(path, 10, MB).to_pandas()
    pd.testing.assert_frame_equal(got, pd.read_parquet(path))


# ----------------------------------------------------------------------------- 7. a deflated checkpoint


def _deflated_checkpoint(tmp_path: Path, inflated: int) -> Path:
    """A checkpoint as torch.save writes it, its tensor record replaced by ``inflated`` zero bytes,
    deflated (a few hundred kB on disk), streamed: never held in memory here."""
    small, path = tmp_path / "small.pt", tmp_path / "deflated.pt"
    meta = json.dumps({"config": {}})
    torch.save({"format": checkpoints.FORMAT, "state_dict": {"w": torch.zeros(4)}, "meta": meta}, small)
    with zipfile.ZipFile(small) as src, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if info.filename.endswith("/data/0"):
                with dst.open(info.filename, "w", force_zip64=True) as out:
                    for _ in range(inflated // MB):
                        out.write(bytes(MB))
            else:
                dst.writestr(info.filename, src.read(info))
    return path


def test_a_checkpoint_whose_records_inflate_past_the_bound_is_refused_before_torch_load(tmp_path):
    path = _deflated_checkpoint(tmp_path, validate.MAX_CHECKPOINT_BYTES + 4 * MB)
    assert path.stat().st_size < 2 * MB
    t0 = time.process_time()
    with pytest.raises(InputError) as err:
        checkpoints.checkpoint_info(path)
    line = str(err.value)
    assert line.startswith(f"{path}: its records inflate to 260,") and "MAX_CHECKPOINT_BYTES" in line, line
    assert time.process_time() - t0 < 1


def test_a_checkpoint_of_too_many_members_or_not_a_zip_is_refused(tmp_path):
    many = tmp_path / "many.pt"
    with zipfile.ZipFile(many, "w") as z:
        for i in range(validate.MAX_CHECKPOINT_MEMBERS + 1):
            z.writestr(f"archive/data/{i}", b"")
    with pytest.raises(InputError, match=r"10,001 members, over the limit of 10,000 \(MAX_CHECKPOINT_MEMBERS\)"):
        checkpoints.checkpoint_info(many)
    legacy = tmp_path / "legacy.pt"
    torch.save({"format": checkpoints.FORMAT}, legacy, _use_new_zipfile_serialization=False)
    with pytest.raises(InputError, match=r"not a checkpoint \(torch.save's zip\)"):
        checkpoints.checkpoint_info(legacy)


@pytest.mark.parametrize(
    "crasher, said",
    [
        ("parquet_bad_repetition.parquet", "repetition"),  # a repetition of -2: read as required
        ("parquet_bad_histogram.parquet", "level histogram"),  # a repetition sent as i16: skipped
    ],
)
def test_a_footer_that_aborts_pyarrow_is_refused_before_pyarrow_reads_it(crasher, said):
    """The fuzz suite's find (test_fuzz_doors.py::test_results_door): a scene map whose footer names
    an unknown repetition (-2), or one sent as another Thrift type, makes pyarrow 26 read that column
    as required, then throw from a
    constructor its Python binding calls without exception handling: the process aborted
    ("terminate called after throwing parquet::ParquetException") at the first look at that column's
    metadata. The door reads the footer's schema itself first; run in a child, so an abort fails
    the test instead of the suite."""
    import subprocess
    import sys

    crasher = Path(__file__).parent / "data" / crasher
    code = (
        "from flatlandia.plumbing import validate\n"
        "from flatlandia.plumbing.errors import InputError\n"
        "try:\n"
        f"    validate.read_table({str(crasher)!r}, 20000, 256 * 10**6)\n"
        "except InputError as e:\n"
        "    print('refused:', e)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-500:]
    assert "refused:" in done.stdout and said in done.stdout


def test_a_real_sized_queries_table_of_distinct_doubles_is_read(tmp_path):
    """Found in a new user's walk: scene 7's queries.parquet (257 queries, 0.1 MB in memory) was
    refused by `score` and `--batch` as "may decode to 102 MB": pyarrow dictionary-encodes lists of
    doubles, and each value was bounded by the whole dictionary page. A fixed-width leaf decodes to
    its width per value, whatever its dictionary."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rng = np.random.default_rng(0)
    local = [[[float(x), float(y)] for x, y in rng.normal(size=(17, 2))] for _ in range(400)]
    table = pa.table({"token": [f"t{i}" for i in range(400)], "depth_local_xy": local})
    path = tmp_path / "queries.parquet"
    pq.write_table(table, path)
    got = validate.read_table(path, validate.MAX_QUERIES, 10 * table.nbytes)
    assert len(got) == 400 and got["depth_local_xy"].iloc[3][5][1] == local[3][5][1]
