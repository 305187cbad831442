"""Issue 42, the audit and what reaches a terminal or a spreadsheet: `audit --write` through `..` or
a link onto an artifact (finding 5), `audit --tree` over 1,500 chained records and a manifest that
is not one (finding 8), record names printed raw, C1 controls and bidi overrides in plain names,
`-2-3` and `-A1-B1` through the CSV rule (finding 10). Each test failed on f324544."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pandas as pd
import pytest

from flatlandia import cli
from flatlandia.plumbing import escape, names, provenance, validate
from flatlandia.plumbing.errors import InputError

MAP = "results/12/maps/reference_map.parquet"
#: the 18 published tokens that start with '-' (local_maps.json and maps/*/tokens.txt: 8,185 tokens,
#: 15 or 16 digits or 22 characters of [A-Za-z0-9_-])
DASHED_TOKENS = """-7s4S6d43neqk9_2W2epHw -AB21Af_LPev08UY_96ptQ -AlhZpsokH0OpN831ukrRQ -BJNCYgmZ35ucp2FsiR89Q
-C9fRN6bRCLpEaTc1__ACA -FZDCsvModzChDu6fy-UvQ -HiEHAgXU47WlSgImGUiIg -PFzv-GkwLnhbcvkT15_Dg -REYD0WVaiBFKhZMXzX_ow
-XH-w2CwXJEUC1L48f0seQ -dNv-q7FGPNpeg_Dzov06A -gfZ_Zbgj-7PMWZwALOxRg -m042ZxEuqpNiFEb9g_TSA -p7KqdhvC0fL8TSe48HdnQ
-s10VwM4U8lVOp5KS_JmLA -vrxjuQUxQYuYI5LAC8f8g -yQ68Hp5myM6SB-TeDNkRw -zLjzdBQv7PPtIwcTqz0aQ""".split()
FORMULAS = ["-2-3", "-A1-B1", "-1+2", "-SUM(A1)", "--A1", "-A1-B1-C1-D1-E1-F1-G12", "-TRUE-TRUE-TRUE-TRUE-1"]
FORMULAS += ["-R1C1-R2C2-R3C3-R4C444", "-A1*2", "-abc", "-AB21Af_LPev08UY_96ptQ1", "-\uff21\uff11", "-"]
NUMBERS = ["-1", "-1.5", "-3e-5", "-.5", "-2E+10"]
HIDDEN = ["\x1b[2J", "\x1b]0;pwned\x07", "\x85", "\x9b", "\x7f", "\u202e", "\u2066", "\u2069", "\u200b", "\ufeff"]


def _record(rule: str, outputs: list[str], inputs: dict | None = None, **over) -> dict:
    """A provenance record of ``rule`` naming ``outputs`` (their sha256 as they are on disk)."""
    outs = {}
    for p in outputs:
        digest, size = provenance.path_digest(p)
        outs[p] = {"sha256": digest, "bytes": size}
    rec = {
        "rule": rule,
        "wildcards": {"scene": "12"},
        "inputs": inputs or {},
        "outputs": outs,
        "config_hash": "0" * 16,
        "package_version": "0.1.0",
        "git_commit": "abc",
        "finished_at": "2026-11-28T00:00:00+00:00",
    }
    return {**rec, **over}


def _write_record(rec: dict, name: str) -> None:
    path = Path("logs/provenance") / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(rec))


def _file(path: str, text: str = "x") -> str:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(text)
    return path


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if ln.startswith("ERROR: ")]
    assert len(errors) == 1 and "Traceback" not in err, err
    return errors[0]


# ----------------------------------------------------------------------------- 5. audit --write


def test_audit_write_refuses_an_artifact_reached_through_dot_dot_or_a_link(tmp_path, monkeypatch, capsys):
    """`--write results/../results/12/maps/reference_map.parquet` and `--write r/12/...` (r a link to
    results/) replaced the map: the guard compared the paths as given."""
    monkeypatch.chdir(tmp_path)
    _write_record(_record("reference_map", [_file(MAP, "map")]), "reference_map/scene-12")
    _write_record(_record("masks", [_file("results/12/masks/a.png")]), "masks/scene-12")
    Path("r").symlink_to("results", target_is_directory=True)
    for given in ("results/../results/12/maps/reference_map.parquet", "r/12/maps/reference_map.parquet"):
        assert cli.main(["audit", "--write", given]) == 1
        assert _one_line_error(capsys).startswith(
            f"ERROR: --write {given}: an artifact of this run (rule reference_map)"
        )
        assert Path(MAP).read_text() == "map"
    assert cli.main(["audit", "--write", str(tmp_path / "r" / ".." / MAP)]) == 1 and Path(MAP).read_text() == "map"
    capsys.readouterr()
    # nor onto a record the audit reads
    record = Path("logs/provenance/masks/scene-12.json")
    before = record.read_bytes()
    assert cli.main(["audit", "--write", "r/../logs/provenance/masks/scene-12.json"]) == 1
    assert record.read_bytes() == before and "ERROR: --write " in capsys.readouterr().err
    assert cli.main(["audit", "--write", "r/../mine.parquet"]) == 0
    assert len(pd.read_parquet("mine.parquet")) == 2
    # the manifest it wrote is read back whole as the fallback (no record left), without a warning
    Path("logs").rename("old_logs")
    capsys.readouterr()
    assert cli.main(["audit", "--manifest", "mine.parquet", MAP, "--tree"]) == 0
    got = capsys.readouterr()
    assert "rule: reference_map" in got.out and "the file matches its record" in got.out and not got.err


def test_audit_finds_the_record_of_an_artifact_named_through_dot_dot_or_a_link(tmp_path, monkeypatch, capsys):
    """The guard resolves `results/../results/...` and a link to results/: so does the look-up (it
    said "no audit record" for the very file the guard had just named an artifact)."""
    monkeypatch.chdir(tmp_path)
    _write_record(_record("reference_map", [_file(MAP, "map")]), "reference_map/scene-12")
    Path("r").symlink_to("results", target_is_directory=True)
    for given in ("results/../results/12/maps/reference_map.parquet", "r/12/maps/reference_map.parquet"):
        assert cli.main(["audit", given]) == 0
        assert f"artifact: {MAP}" in capsys.readouterr().out


# ----------------------------------------------------------------------------- 8. tree and manifest


def test_audit_tree_over_1500_chained_records_is_no_recursion_error(tmp_path, monkeypatch, capsys):
    """Each record's output the next one's input, 1,500 deep: `audit --tree` was a RecursionError."""
    monkeypatch.chdir(tmp_path)
    n = 1500
    for i in range(n):
        out = _file(f"results/chain/{i}.txt", str(i))
        inputs = {f"results/chain/{i - 1}.txt": provenance.path_digest(f"results/chain/{i - 1}.txt")[0]} if i else {}
        _write_record(_record(f"step{i}", [out], inputs), f"step{i}/all")
    t0 = time.monotonic()
    assert cli.main(["audit", f"results/chain/{n - 1}.txt", "--tree"]) == 0
    out = capsys.readouterr().out
    assert time.monotonic() - t0 < 30
    assert "<- step1498" in out and "<- step1398" not in out
    assert f"the tree stops at {validate.MAX_TREE_DEPTH} levels" in out
    df = provenance.manifest()
    assert len(provenance.lineage(f"results/chain/{n - 1}.txt", df, tree=True)) == validate.MAX_TREE_DEPTH


def _manifest_rows() -> pd.DataFrame:
    _file("results/a.txt", "a")
    _file("results/b.txt", "b")
    rows = [_record("good", ["results/a.txt"]), _record("bad", ["results/b.txt"])]
    df = pd.DataFrame(
        [
            {
                "artifact": a,
                "rule": r["rule"],
                "scene": "12",
                "wildcards": "{}",
                "sha256": o["sha256"],
                "bytes": o["bytes"],
                "inputs": "{}",
            }
            for r in rows
            for a, o in r["outputs"].items()
        ]
    )
    return df


@pytest.mark.parametrize(
    "case",
    ["no artifact column", "not parquet", "a folder", "bad JSON", "a list of inputs", "NaN bytes", "no sha256"],
)
def test_a_manifest_that_is_not_one_is_one_line(tmp_path, monkeypatch, capsys, case):
    """The fallback for a results folder copied without its logs read any Parquet (pd.read_parquet):
    no `artifact` column was a KeyError, a file that is not Parquet an ArrowInvalid, bad JSON in a
    cell a JSONDecodeError (tracebacks)."""
    monkeypatch.chdir(tmp_path)
    df = _manifest_rows()
    path = Path("results/manifest.parquet")
    if case == "no artifact column":
        df.drop(columns="artifact").to_parquet(path)
    elif case == "not parquet":
        path.write_bytes(b"PAR1 this is not parquet PAR1")
    elif case == "a folder":
        path.mkdir()
    elif case == "bad JSON":
        df.loc[1, "inputs"] = '{"results/a.txt": '
        df.to_parquet(path)
    elif case == "a list of inputs":
        df.loc[1, "inputs"] = '["results/a.txt"]'
        df.to_parquet(path)
    elif case == "NaN bytes":
        df["bytes"] = df["bytes"].astype(float)
        df.loc[1, "bytes"] = float("nan")
        df.to_parquet(path)
    else:
        df.loc[1, "sha256"] = None
        df.to_parquet(path)
    if case in ("no artifact column", "not parquet", "a folder"):
        assert cli.main(["audit", "results/a.txt", "--tree"]) == 1
        line = _one_line_error(capsys)
        assert line.startswith("ERROR: results/manifest.parquet: "), line
        return
    assert cli.main(["audit", "results/a.txt", "--tree"]) == 0  # the good row is audited
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("WARNING: ")]
    assert len(warnings) == 1 and warnings[0].startswith("WARNING: results/manifest.parquet: row 1: "), warnings
    assert cli.main(["audit", "results/b.txt"]) == 1  # the bad one is left out, said once
    assert "no audit record" in _one_line_error(capsys)


def test_a_manifest_setting_of_5000_digits_is_audited(tmp_path, monkeypatch, capsys):
    """json.loads of the settings cell: a 5,000-digit integer was a ValueError (Python's digit limit)."""
    monkeypatch.chdir(tmp_path)
    df = _manifest_rows()
    df["settings"] = '{"solver.top_k": ' + "9" * 5000 + "}"
    df.to_parquet("results/manifest.parquet")
    assert cli.main(["audit", "results/a.txt"]) == 0
    got = capsys.readouterr()
    assert "solver.top_k: Infinity" in got.out and not got.err


def test_a_record_with_a_nul_in_an_output_is_left_out(tmp_path, monkeypatch, capsys):
    """in_run resolved the name: a NUL byte was a ValueError (traceback) in every audit."""
    monkeypatch.chdir(tmp_path)
    _write_record(_record("good", [_file("results/a.txt")]), "good/all")
    _write_record({**_record("nul", []), "outputs": {"results/a\0b": {"sha256": "0", "bytes": 1}}}, "nul/all")
    assert cli.main(["audit", "--check"]) == 0
    assert "not a provenance record" in capsys.readouterr().err


# ----------------------------------------------------------------------------- 10. the terminal


def test_audit_prints_names_from_records_escaped(tmp_path, monkeypatch, capsys):
    """Record names were printed raw: an ESC cleared the screen, an OSC retitled the terminal."""
    monkeypatch.chdir(tmp_path)
    evil = "".join(HIDDEN)
    art = _file(f"results/12/x{evil}y.txt")
    _write_record(_record(f"rule{evil}", [art], {f"resources/in{evil}": "0" * 64}, git_commit=evil), "evil/all")
    _write_record({"rule": f"broken{evil}"}, f"broken{evil}")
    runs = [["audit"], ["audit", "--check"], ["audit", art], ["audit", art, "--tree"], ["audit", f"no{evil}"]]
    runs += [["audit", "--scene", f"s{evil}"]]
    for argv in runs:
        cli.main(argv)
        got = capsys.readouterr()
        for text in (got.out, got.err):
            assert not [c for c in text if c != "\n" and escape.hidden(c)], (argv, text)
        assert "\\x1b" in got.out + got.err, argv
    _file(art, "changed")
    assert cli.main(["audit", "--check"]) == 1
    out = capsys.readouterr().out
    assert "\\x1b[2J\\x1b]0;pwned\\x07\\x85\\x9b\\x7f\\u202e\\u2066\\u2069\\u200b\\ufeff" in out
    assert not [c for c in out if c != "\n" and escape.hidden(c)]


def test_terminal_escapes_every_hidden_character_and_keeps_the_rest():
    for c in HIDDEN + ["\n", "\t", "\r", "\x00", "\u2028", "\U000e0001", "\ud800"]:
        assert not escape.hidden(escape.terminal(f"a{c}b")), repr(c)
    assert escape.terminal("\x1b\u202e\U000e0001") == "\\x1b\\u202e\\U000e0001"
    for plain in ["results/12/maps/reference_map.parquet", "Zürich", "東京", "a b", "-AB21Af_LPev08UY_96ptQ"]:
        assert escape.terminal(plain) == plain
    # what an error line quotes (validate.shown) and the JSON answers on stdout carry no control either
    from flatlandia.localize import answers

    for text in (validate.shown("".join(HIDDEN)), answers.dumps({"token": "".join(HIDDEN)})):
        assert not [c for c in text if c != "\n" and escape.hidden(c)], text


# ----------------------------------------------------------------------------- 10. plain names


@pytest.mark.parametrize("c", [*HIDDEN, "\x00", "\u061c", "\u2028", "\U000e0041", "\ud800"])
def test_plain_names_refuse_controls_bidi_overrides_and_invisible_characters(c):
    """U+0085 and U+202E passed (`photo\\u202egpj.exe` listed as `photoexe.jpg`); a lone surrogate
    was a UnicodeEncodeError."""
    assert names.name_problem(f"photo{c}gpj.exe"), repr(c)
    with pytest.raises(InputError, match="control or invisible character"):
        names.plain_name(f"a{c}b", "metadata.csv", "image name")
    for token in [*DASHED_TOKENS, "614012812849853", "1676249435896456", "IMG_0001.JPG", "Zürich 東京.jpg"]:
        assert names.name_problem(token) is None, token


# ----------------------------------------------------------------------------- 10. the CSV rule


def test_the_csv_rule_quotes_dash_formulas_and_passes_numbers_and_tokens():
    """`-2-3` and `-A1-B1` passed the CSV escape unchanged (a spreadsheet computes them)."""
    for cell in FORMULAS:
        assert escape.csv_cell(cell) == "'" + cell, cell
        assert escape.csv_cell_read(escape.csv_cell(cell)) == cell
    for cell in DASHED_TOKENS + NUMBERS:
        assert escape.csv_cell(cell) == cell, cell


@pytest.mark.slow  # the published data
def test_every_published_token_passes_the_csv_rule_and_is_a_plain_name(flat_root, all_local_maps):
    tokens = {t for scene in all_local_maps.values() for t in scene}
    tokens |= {t for f in flat_root.glob("maps/*/tokens.txt") for t in f.read_text().split()}
    assert len(tokens) > 8000 and sorted(t for t in tokens if t.startswith("-")) == sorted(DASHED_TOKENS)
    assert [t for t in tokens if escape.csv_cell(t) != t or names.name_problem(t)] == []
