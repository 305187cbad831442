"""Untrusted inputs, fourth pass (issue 42): the write door (flatlandia.plumbing.files.check_target).

Every write resolves its target (links and '..' of its folder resolved) and refuses a device, a
link, a folder in the way, a Python installation or environment, the source tree, a dot-folder, an
input of the command and an artifact of the run; a fetch writes only below resources/ or into the
declared data folder while it does not exist; `flatlandia score` moves its run folders and
scores.md into place together. One plain test per finding of the issue this door closes (1-6, 8);
each failed on f324544. Fast: the tiny scene (tests/data/tiny) and files built here.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
import tiny_results as tiny_results_folder
import yaml
from conftest import REPO, smk_dry_run
from zip_archives import make_zip

from flatlandia import cli, localize
from flatlandia.data import fetch, localmaps
from flatlandia.plumbing import files, rule_log
from flatlandia.plumbing.errors import InputError

SCENES = pd.DataFrame({"scene": ["12"], "city": ["Paris"], "name": ["ParisRosaPark"]})
TINY = REPO / "config" / "test" / "tiny.yaml"


def tree(root: Path) -> set[str]:
    """Every path under ``root`` (links not followed), relative to it."""
    out = set()
    for dirpath, dirnames, filenames in os.walk(root):
        out |= {str(Path(dirpath, n).relative_to(root)) for n in dirnames + filenames}
    return out


def errors_of(capsys) -> tuple[list[str], str]:
    """(the ERROR lines, all of stderr) of the command just run in this process."""
    err = capsys.readouterr().err
    return [ln for ln in err.splitlines() if ln.startswith("ERROR:")], err


def one_error(capsys, status: int, *says: str) -> str:
    lines, err = errors_of(capsys)
    assert status == 1 and len(lines) == 1 and "Traceback" not in err, err
    for s in says:
        assert s in lines[0], (s, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def tiny_results(tmp_path_factory) -> Path:
    """A results folder of the tiny scene as the workflow lays it out (tests/tiny_results.py)."""
    return tiny_results_folder.build(tmp_path_factory.mktemp("tiny_results") / "results")


@pytest.fixture(scope="module")
def query(tiny_results) -> Path:
    """A query file of the tiny scene (its first test query, GT local map)."""
    q = pd.read_parquet(tiny_results / "0" / "queries" / "queries.parquet")
    r = q[q["split"] == "test"].iloc[0]
    path = tiny_results.parent / "q.json"
    path.write_text(json.dumps(localize.query_json(localmaps.local_map(r, "gt"), r.classes)))
    return path


@pytest.fixture(scope="module")
def poses(tiny_results) -> Path:
    """A poses file of the tiny scene's train split: its true poses, in two settings (whole, gtbb)."""
    q = pd.read_parquet(tiny_results / "0" / "queries" / "queries.parquet")
    t = q[q["split"] == "train"][["scene", "token", "x_m", "y_m", "theta_deg"]]
    path = tiny_results.parent / "poses.csv"
    pd.concat([t.assign(proposal="whole"), t.assign(proposal="gtbb")]).to_csv(path, index=False)
    return path


def localize_out(tiny_results, query, out) -> int:
    ref = tiny_results / "0" / "maps" / "reference_map.parquet"
    return cli.main(["localize", "--map", str(ref), "--query", str(query), "--map-type", "gt", "--out", str(out)])


def score(tiny_results, poses, out, name="mine") -> int:
    args = ["score", str(poses), "--name", name, "--out", str(out), "--results", str(tiny_results)]
    return cli.main([*args, "--split", "train"])


# ----------------------------------------------------------------------------- 1, 2: fetch.dest


def test_finding_1_a_fetch_into_the_venv_is_refused_at_the_config_check(tmp_path):
    """`fetch.dest: .venv/lib/python3.11/site-packages/sitecustomize` counted as inside the working
    folder: the archive's __init__.py then ran at every start of that venv's Python."""
    (tmp_path / ".venv" / "lib" / "python3.11" / "site-packages").mkdir(parents=True)
    (tmp_path / ".venv" / "pyvenv.cfg").write_text("home = /usr/bin\n")
    evil = make_zip(tmp_path / "evil.zip", {"Flatlandia-main/data/__init__.py": b"print('owned')\n"})
    dest = ".venv/lib/python3.11/site-packages/sitecustomize"
    cfg = tmp_path / "evil.yaml"
    cfg.write_text(yaml.safe_dump({"flatlandia_root": "/nonexistent", "fetch": {"url": evil.as_uri(), "dest": dest}}))
    res = smk_dry_run(REPO, tmp_path, "results/0/ingest/ingest.json", "--configfile", str(TINY), str(cfg))
    lines = [ln for ln in (res.stdout + res.stderr).splitlines() if ln.startswith("ERROR:")]
    assert res.returncode != 0 and len(lines) == 1, (res.stdout + res.stderr)[-3000:]
    assert lines[0].startswith(f"ERROR: config: fetch.dest '{dest}'") and "nothing was downloaded" in lines[0]
    with pytest.raises(fetch.FetchError, match="Python"):
        fetch.check_dest(dest, tmp_path, data_folder="/nonexistent")
    assert not (tmp_path / dest).exists()


def test_finding_2_a_declared_data_folder_in_a_dot_folder_or_existing_is_refused(tmp_path, monkeypatch):
    """`flatlandia_root` and `fetch.dest` set to the same absent `~/.ssh` made the fetch create it."""
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    run = tmp_path / "run"
    run.mkdir()
    archive = make_zip(tmp_path / "a.zip", {"Flatlandia-main/data/authorized_keys": b"ssh-ed25519 AAAA evil"})
    ssh = home / ".ssh"
    with pytest.raises(fetch.FetchError, match=r"hidden \(dot\) folder"):
        fetch.check_dest(ssh, run, data_folder=ssh)
    with pytest.raises(fetch.FetchError, match="is refused"):
        fetch.fetch_flatlandia(ssh, SCENES, url=archive.as_uri(), timeout_s=5, workdir=run, data_folder=ssh)
    assert not ssh.exists()
    mine = tmp_path / "mine"  # an existing folder is never a fetch's destination outside resources/
    mine.mkdir()
    with pytest.raises(fetch.FetchError, match="already exists"):
        fetch.check_dest(mine, run, data_folder=mine)
    for outside in ("data", str(tmp_path / "data")):  # not declared: refused
        with pytest.raises(fetch.FetchError, match="outside the working folder's resources/"):
            fetch.check_dest(outside, run)
    fetch.check_dest(tmp_path / "data", run, data_folder=tmp_path / "data")  # declared and absent
    fetch.check_dest("resources/flatlandia", run)


def test_fetched_files_carry_no_exec_bit(tmp_path):
    """A member stored as 0o755 (a script) is written 0o666 less the umask."""
    archive = make_zip(tmp_path / "x.zip", [("top/imgs/run.sh", b"#!/bin/sh\n", stat.S_IFREG | 0o755)])
    dest = fetch.fetch_images(archive.as_uri(), "imgs", tmp_path / "resources" / "s", workdir=tmp_path)
    assert not os.stat(dest / "run.sh").st_mode & 0o111


# ----------------------------------------------------------------------------- 3: devices and links


def test_finding_3_a_link_or_a_pipe_as_out_is_refused_and_kept(tiny_results, query, tmp_path, capsys):
    """`localize --out /dev/stdout` replaced the system's /dev/stdout (the temporary went into /dev,
    os.replace swapped the link for a file); here a link to /dev/null and a named pipe stand for it."""
    link = tmp_path / "stdout"
    link.symlink_to("/dev/null")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for out in (link, fifo):
        one_error(capsys, localize_out(tiny_results, query, out), f"ERROR: --out: {out} is ")
    assert link.is_symlink() and os.readlink(link) == "/dev/null"
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and tree(tmp_path) == {"stdout", "fifo"}
    for device in ("/dev/stdout", "/dev/null", "/proc/self/fd/1", "/sys/x"):
        with pytest.raises(InputError, match=r"lies in /(dev|proc|sys)"):
            files.check_target(device)


def test_the_temporary_lies_beside_the_resolved_target(tmp_path):
    """Through a link to a folder, the temporary and the file land in the real folder."""
    (tmp_path / "real").mkdir()
    (tmp_path / "via").symlink_to(tmp_path / "real", target_is_directory=True)
    with files.atomic_path(tmp_path / "via" / "x.json") as tmp:
        assert tmp.parent == tmp_path / "real"
        tmp.write_text("{}")
    assert (tmp_path / "real" / "x.json").read_text() == "{}" and (tmp_path / "via").is_symlink()


@pytest.mark.parametrize(
    "where",
    [".venv/lib/python3.11/site-packages/x.py", "workflow/flatlandia/x.py", ".snakemake/x", ".git/hooks/pre-commit"],
)
def test_python_source_and_dot_folders_are_never_written(where, tmp_path):
    """The checkout's venv, its package, its dot-folders; and this Python's own folders."""
    with pytest.raises(InputError, match="Python|source tree|hidden"):
        files.check_target(REPO / where, cwd=REPO)
    with pytest.raises(InputError, match="Python installation"):
        files.check_target(Path(os.__file__).parent / "evil.py")
    (tmp_path / "env").mkdir()
    (tmp_path / "env" / "pyvenv.cfg").write_text("")
    with pytest.raises(InputError, match="Python environment"):
        files.check_target(tmp_path / "env" / "lib" / "x.py")


# ----------------------------------------------------------------------------- 4: the command's own inputs


def test_finding_4_out_never_replaces_priors_fixes_or_the_exports_ground_truth(tmp_path, monkeypatch, capsys):
    """Only --query, --sequence and --map were guarded; --batch passed none."""
    monkeypatch.chdir(tmp_path)
    priors = tmp_path / "P.json"
    priors.write_text('{"scale": null}')
    q = tmp_path / "q.json"
    q.write_text('{"objects": []}')
    status = cli.main(["localize", "--map", "m.parquet", "--query", "q.json", "--priors", "P.json", "--out", "P.json"])
    one_error(capsys, status, "ERROR: --out: P.json is an input of this command")
    fixes = tmp_path / "F.csv"
    fixes.write_text("scene,token,lon,lat,sigma_m\n")
    export = tmp_path / "export"
    (export / "0").mkdir(parents=True)
    (export / "scenes.csv").write_text("scene,city\n0,Tiny\n")
    (export / "0" / "ground_truth.csv").write_text("token,split,x_m,y_m,theta_deg,matched_obj_idx\n")
    link = tmp_path / "exp"
    link.symlink_to(export, target_is_directory=True)
    cases = [
        (["--fixes", "F.csv", "--out", "F.csv"], "is an input of this command"),
        (["--out", "export/0/ground_truth.csv"], "a folder this command reads"),
        (["--out", "exp/0/../0/ground_truth.csv"], "a folder this command reads"),
    ]
    for extra, says in cases:
        status = cli.main(["localize", "--batch", "export", *extra])
        one_error(capsys, status, f"ERROR: --out: {extra[-1]} ", says)
    assert priors.read_text() == '{"scale": null}' and fixes.read_text() == "scene,token,lon,lat,sigma_m\n"
    assert (export / "0" / "ground_truth.csv").read_text().startswith("token,split")


# ----------------------------------------------------------------------------- 5: artifacts, external runs


def test_finding_5_score_out_never_replaces_external_eval_outputs(tiny_results, poses, tmp_path, monkeypatch, capsys):
    """`score --out results/external --name <an external entry>` replaced external_eval's outputs."""
    monkeypatch.chdir(tmp_path)
    external = tmp_path / "results" / "external" / "mine_depth_whole"
    external.mkdir(parents=True)
    (external / "errors.parquet").write_bytes(b"external_eval's")
    (tmp_path / "res").symlink_to(tmp_path / "results", target_is_directory=True)
    for out in ("results/external", "results/../results/external", "res/external", tiny_results / "external"):
        one_error(capsys, score(tiny_results, poses, out), f"ERROR: --out: {out}", "external_eval")
    assert (external / "errors.parquet").read_bytes() == b"external_eval's"
    assert not (tiny_results / "external").exists()
    assert score(tiny_results, poses, "scores") == 0  # a folder of its own
    assert (tmp_path / "scores" / "scores.md").is_file()


def test_finding_5_an_artifact_is_caught_through_dotdot_and_links(tmp_path, monkeypatch):
    """`audit --write results/../results/12/maps/reference_map.parquet` (or a link to results/)
    passed the audit's guard: unresolved relative paths were compared."""
    monkeypatch.chdir(tmp_path)
    artifact = "results/12/maps/reference_map.parquet"
    (tmp_path / artifact).parent.mkdir(parents=True)
    (tmp_path / artifact).write_bytes(b"map")
    (tmp_path / "r").symlink_to(tmp_path / "results", target_is_directory=True)
    for given in ("results/../results/12/maps/reference_map.parquet", "r/12/maps/reference_map.parquet", artifact):
        with pytest.raises(InputError, match=r"is an artifact of this run \(rule reference_map\)"):
            files.check_target(given, artifacts={artifact: "reference_map"})
        with pytest.raises(InputError, match="is an artifact of this run"):
            files.write_parquet(pd.DataFrame({"a": [1]}), given, artifacts=[artifact])
    assert (tmp_path / artifact).read_bytes() == b"map"


# ----------------------------------------------------------------------------- 6: a result set moved as one


def test_finding_6_a_failed_score_write_leaves_the_older_set_whole(tiny_results, poses, tmp_path, monkeypatch, capsys):
    """`score` wrote run by run, then scores.md: a failing write left new run folders beside a stale
    scores.md, and a traceback."""
    out = tmp_path / "scores"
    whole = pd.read_csv(poses).query("proposal == 'whole'")
    first = tmp_path / "whole.csv"
    whole.to_csv(first, index=False)
    assert score(tiny_results, first, out) == 0
    capsys.readouterr()
    before = {p: (out / p).read_bytes() for p in tree(out) if (out / p).is_file()}
    real = files.write_text

    def full(text, path, **kw):
        if Path(path).name == "scores.md":
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(text, path, **kw)

    monkeypatch.setattr(files, "write_text", full)
    one_error(capsys, score(tiny_results, poses, out), f"ERROR: --out: could not write {out}", "no space left")
    assert {p: (out / p).read_bytes() for p in tree(out) if (out / p).is_file()} == before
    assert not (out / "mine_depth_gtbb").exists() and tree(tmp_path) - {"whole.csv"} == {"scores"} | {
        f"scores/{p}" for p in tree(out)
    }


def test_a_new_score_set_appears_whole_and_a_rerun_replaces_its_own_files(tiny_results, poses, tmp_path, capsys):
    out = tmp_path / "s"
    assert score(tiny_results, poses, out) == 0
    assert {"scores.md", "mine_depth_whole/summary.json", "mine_depth_gtbb/errors.parquet"} <= tree(out)
    (out / "mine_depth_whole" / "notes.txt").write_text("mine")  # a file of the user's own stays
    assert score(tiny_results, poses, out) == 0
    assert (out / "mine_depth_whole" / "notes.txt").read_text() == "mine"
    (tmp_path / "link").symlink_to(out, target_is_directory=True)  # a link to a folder is written into
    assert score(tiny_results, poses, tmp_path / "link") == 0 and (tmp_path / "link").is_symlink()
    assert not [p for p in tree(tmp_path) if ".partial-" in p]


def test_staged_puts_back_what_was_there_when_a_move_fails(tmp_path, monkeypatch):
    top = tmp_path / "set"
    (top / "a").mkdir(parents=True)
    (top / "a" / "x").write_text("old x")
    (top / "y").write_text("old y")
    real = os.rename

    def fail_on_y(src, dst):
        if Path(dst).name == "y" and ".partial-" in str(src):
            raise OSError(errno.EIO, "Input/output error")
        return real(src, dst)

    monkeypatch.setattr(os, "rename", fail_on_y)
    with pytest.raises(OSError), files.staged(top, ["a/x", "b/z", "y"]) as tmp:
        for p in tmp.values():
            p.write_text("new")
    assert tree(top) == {"a", "a/x", "y"} and (top / "a" / "x").read_text() == "old x"
    assert (top / "y").read_text() == "old y"


# ----------------------------------------------------------------------------- 8: full disk, a folder in the way


def test_finding_8_localize_out_on_a_full_disk_is_one_error_line(tiny_results, query, tmp_path, monkeypatch, capsys):
    """`localize --out` on a full disk ended in a traceback."""
    real = Path.write_text

    def full(self, *args, **kwargs):
        if ".partial-" in self.name:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full)
    out = tmp_path / "answer.json"
    one_error(capsys, localize_out(tiny_results, query, out), f"ERROR: --out: could not write {out}", "no space")
    assert tree(tmp_path) == set()


def test_finding_8_score_out_on_a_full_disk_is_one_error_line(tiny_results, poses, tmp_path, monkeypatch, capsys):
    import pyarrow.parquet as pq

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pq, "write_table", full)
    out = tmp_path / "scores"
    one_error(capsys, score(tiny_results, poses, out), f"ERROR: --out: could not write {out}", "no space")
    assert tree(tmp_path) == set()


def test_finding_8_a_folder_in_the_way_is_one_error_line(tiny_results, query, poses, tmp_path, capsys):
    """--out naming a folder, or a path under a file: a traceback after the work."""
    (tmp_path / "a_folder").mkdir()
    (tmp_path / "a_file").write_text("mine")
    for out, says in ((tmp_path / "a_folder", "is a folder"), (tmp_path / "a_file" / "x.json", "is a file")):
        one_error(capsys, localize_out(tiny_results, query, out), f"ERROR: --out: {out}", says)
    for out, says in (
        (tmp_path / "a_file", "is a regular file, not a folder"),
        (tmp_path / "a_file" / "s", "is a file"),
    ):
        one_error(capsys, score(tiny_results, poses, out), f"ERROR: --out: {out}", says)
    (tmp_path / "s" / "scores.md").mkdir(parents=True)  # a folder where the score's file goes
    one_error(capsys, score(tiny_results, poses, tmp_path / "s"), "ERROR: --out: ", "scores.md is a folder")
    assert (tmp_path / "a_file").read_text() == "mine" and tree(tmp_path) == {"a_folder", "a_file", "s", "s/scores.md"}


def test_finding_8_nan_and_wrong_types_in_the_fetch_record_are_ignored_not_a_traceback(tmp_path):
    """NaN in resources/.flatlandia-fetches.json: a traceback after the folder was in place (the
    record could not be written back), then every rerun refused the folder."""
    archive = make_zip(tmp_path / "a.zip", {"top/imgs/1.jpg": b"1"})
    dest = tmp_path / "resources" / "images" / "s"
    state = tmp_path / fetch.FETCH_STATE
    state.parent.mkdir(parents=True)
    bad = {
        str(tmp_path / "resources" / "images" / "t"): {"device": float("nan"), "inode": 1, "files": "x"},
        "/elsewhere": [1, 2],
        "/other": {"device": "1", "inode": 2},
    }
    state.write_text(json.dumps(bad))
    fetch.fetch_images(archive.as_uri(), "imgs", dest, workdir=tmp_path)
    record = json.loads(state.read_text())  # valid JSON again: the bad entries were left out
    assert set(record) == {str(dest.resolve())} and fetch.fetched_before(dest, tmp_path)
    fetch.fetch_images(archive.as_uri(), "imgs", dest, workdir=tmp_path)  # a rerun replaces its own fetch
    for text in ("[NaN]", '"a string"', "{"):
        state.write_text(text)
        with pytest.raises(fetch.FetchError, match="a folder not written by a fetch of this run"):
            fetch.fetch_images(archive.as_uri(), "imgs", dest, workdir=tmp_path)  # unknown: never replaced
        assert (dest / "1.jpg").read_bytes() == b"1"


# ----------------------------------------------------------------------------- rule scripts' write roots


def test_a_rule_script_writes_only_in_the_runs_folders(tmp_path, monkeypatch, capsys):
    """A path built from a hostile input (a token `../../x`) outside results/, resources/, logs/ and
    the job's own output folders is one ERROR line; inside, the write goes through."""
    monkeypatch.chdir(tmp_path)
    smk = SimpleNamespace(log=[], output=[str(tmp_path / "results" / "x" / "out.json")])

    def main(smk, log):
        files.write_json({}, tmp_path / "results" / "x" / "out.json")
        files.write_json({}, tmp_path / "elsewhere" / "x.json")

    with pytest.raises(SystemExit) as stop:
        rule_log.run(main, smk)
    assert stop.value.code == 1
    one_error(capsys, 1, "elsewhere/x.json: lies outside the folders this run writes")
    assert (tmp_path / "results" / "x" / "out.json").is_file() and not (tmp_path / "elsewhere").exists()
    files.write_json({}, tmp_path / "elsewhere" / "x.json")  # no roots set: the library writes where it is told
