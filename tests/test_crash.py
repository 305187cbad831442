"""Crash safety: a run killed with SIGKILL (its whole process group, as a power cut or the OOM
killer of a session would) while a table is written, during a training and during SfM, then rerun
with the command of docs/usage.md (nothing else: the stale lock, the incomplete outputs and the killed
jobs' temporaries are handled by the workflow and its default profile), ends with the outputs of a
clean run. A disk that fills up mid-run ends the run with one ERROR line and nothing half-written;
the same command after freeing space completes it, again with the clean run's outputs.

One kill per moment, on the cheapest real targets: the tiny committed scene (tests/data/tiny) for
the table and the training, six of the Lund photos for SfM.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
from snakemake_runner import SNAKEMAKE, smk

REPO = Path(__file__).resolve().parents[1]
LUND_IMAGES = ["01.jpg", "02.jpg", "03.jpg", "04.jpg", "05.jpg", "06.jpg"]

CHECKPOINT = "results/fine/models/mlp_gt_gtbb/checkpoint.pt"
TABLE = "results/tables/recovery.parquet"
#: on the tiny scene, a table and a training long enough to be caught running (600 epochs, 2-3 s),
#: with what they need: its ingest, map, recovery and queries
TINY = [TABLE, CHECKPOINT]
TINY_CONFIG = ["--configfile", str(REPO / "config/test/tiny.yaml"), "--config", "fine={train: {epochs: 600}}"]
#: the temporaries of the atomic writers (flatlandia.plumbing.files)
PARTIAL = re.compile(r"^\..*\.partial-")


def timing(name: str) -> bool:
    """A column or metadata key that measures wall-clock time, different in every run."""
    return name == "seconds" or name.endswith("_seconds")


#: imported by every Python process of a run given its folder on PYTHONPATH: the job that renames
#: a temporary onto CRASH_TEST_PAUSE_AT stops just before the rename (its output fully written
#: under the temporary name, not yet under its own), says so in CRASH_TEST_PAUSED and waits there
PAUSE_SITECUSTOMIZE = """
import os, time
_target = os.environ.get("CRASH_TEST_PAUSE_AT")
if _target:
    _replace = os.replace
    def _paused_replace(src, dst, *args, **kwargs):
        if os.path.realpath(os.fspath(dst)) == os.path.realpath(_target):  # the writers rename resolved paths
            with open(os.environ["CRASH_TEST_PAUSED"], "w") as f:
                f.write(os.fspath(src))
            time.sleep(600)
        return _replace(src, dst, *args, **kwargs)
    os.replace = _paused_replace
"""


def _env(extra: dict | None = None) -> dict:
    return {k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"} | (extra or {})


def start(wd: Path, args: list[str], env: dict | None = None) -> tuple[subprocess.Popen, Path]:
    """``snakemake --cores 2 ARGS`` in ``wd``, in the background as its own process group; (the
    process, the file of what it prints)."""
    wd.mkdir(parents=True, exist_ok=True)
    out = wd.parent / f"{wd.name}.txt"
    cmd = [SNAKEMAKE, "-s", str(REPO / "workflow" / "Snakefile"), "-d", str(wd), "--cores", "2", *args]
    with open(out, "w") as f:
        proc = subprocess.Popen(cmd, cwd=wd, stdout=f, stderr=subprocess.STDOUT, env=_env(env), start_new_session=True)
    return proc, out


def finished(proc: subprocess.Popen, out: Path) -> None:
    assert proc.wait(timeout=600) == 0, out.read_text()[-3000:]


def run_and_kill(wd: Path, args: list[str], ready: Callable[[], bool], what: str, env: dict | None = None) -> str:
    """Start ``snakemake --cores 2 ARGS`` in ``wd`` as its own process group, wait until ``ready()``,
    then SIGKILL the whole group; return what the run printed."""
    proc, out = start(wd, args, env)
    try:
        deadline = time.monotonic() + 300
        while not ready():
            if proc.poll() is not None:
                pytest.fail(f"the run ended (rc {proc.returncode}) before {what}:\n{out.read_text()[-3000:]}")
            if time.monotonic() > deadline:
                pytest.fail(f"no {what} within 300 s:\n{out.read_text()[-3000:]}")
            time.sleep(0.05)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    for _ in range(200):  # the group's other processes (the jobs) die with it
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    return out.read_text()


def rerun(wd: Path, args: list[str]) -> subprocess.CompletedProcess:
    """The command of docs/usage.md, as a user reruns it after the crash: ``snakemake --cores 2 ARGS``."""
    wd.mkdir(parents=True, exist_ok=True)
    res = smk(REPO, wd, "--cores", "2", *args)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "Traceback" not in res.stderr and "LockException" not in res.stderr, res.stderr[-3000:]
    return res


def text(path: Path) -> str:
    return path.read_text(errors="replace") if path.exists() else ""


def locked(wd: Path) -> bool:
    locks = wd / ".snakemake" / "locks"
    return locks.is_dir() and any(re.match(r"^[0-9]+\.(input|output)\.lock$", p.name) for p in locks.iterdir())


def partials(wd: Path) -> list[Path]:
    return sorted(p for p in (wd / "results").rglob("*") if PARTIAL.match(p.name))


def outputs(wd: Path) -> dict[str, Path]:
    return {p.relative_to(wd).as_posix(): p for p in sorted((wd / "results").rglob("*")) if p.is_file()}


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _without_timing(meta: dict) -> dict:
    return {k: v for k, v in meta.items() if not timing(k)}


def _masked(text_: str) -> list[str]:
    """A Markdown or LaTeX table with the cells of its timing columns blanked."""
    out, masked, width = [], set(), 0
    for line in text_.splitlines():
        sep = "|" if line.startswith("|") else "&" if "&" in line else None
        if sep is None:
            out.append(line)
            continue
        cells = [c.strip().rstrip("\\").strip() for c in line.split(sep)]
        timed = {i for i, c in enumerate(cells) if timing(c.replace("\\_", "_"))}
        if timed:
            masked, width = timed, len(cells)
        elif masked and len(cells) == width:
            cells = ["<time>" if i in masked else c for i, c in enumerate(cells)]
        out.append(sep.join(cells))
    return out


def assert_same_output(clean: Path, got: Path) -> None:
    if got.suffix == ".parquet":
        from flatlandia.plumbing import files

        a, b = pd.read_parquet(clean), pd.read_parquet(got)
        a, b = (
            a.drop(columns=[c for c in a.columns if timing(c)]),
            b.drop(columns=[c for c in b.columns if timing(c)]),
        )
        pd.testing.assert_frame_equal(a, b, check_exact=True, obj=str(got))
        assert _without_timing(files.read_parquet_metadata(clean)) == _without_timing(
            files.read_parquet_metadata(got)
        ), got
    elif got.suffix == ".pt":
        import torch

        a, b = torch.load(clean, weights_only=True), torch.load(got, weights_only=True)
        assert a["state_dict"].keys() == b["state_dict"].keys(), got
        assert all(torch.equal(a["state_dict"][k], b["state_dict"][k]) for k in a["state_dict"]), got
        assert _without_timing(json.loads(a["meta"])) == _without_timing(json.loads(b["meta"])), got
    elif got.suffix in (".md", ".tex"):
        assert _masked(clean.read_text()) == _masked(got.read_text()), got
    else:
        assert sha256(clean) == sha256(got), got


def assert_same_outputs(clean_wd: Path, wd: Path, subset: bool = False) -> int:
    """Every output of ``wd`` equals the clean run's (and, unless ``subset``, the same files); no
    temporary is left. Returns the number of files compared."""
    assert partials(wd) == []
    clean, got = outputs(clean_wd), outputs(wd)
    if subset:  # a run of fewer targets: its summary lists what it built
        got.pop("results/summary.md", None)
        assert got.keys() <= clean.keys(), sorted(got.keys() - clean.keys())
    else:
        assert got.keys() == clean.keys(), (sorted(got.keys() - clean.keys()), sorted(clean.keys() - got.keys()))
    for rel, path in got.items():
        assert_same_output(clean[rel], path)
    return len(got)


@pytest.fixture(scope="module")
def tiny_clean(tmp_path_factory):
    """A clean run of the tiny targets, started in the background (10-20 s) as the tests begin:
    ``tiny_clean()`` waits for it and returns its folder."""
    wd = tmp_path_factory.mktemp("tiny_clean")
    proc, out = start(wd, [*TINY, *TINY_CONFIG])

    def folder() -> Path:
        finished(proc, out)
        return wd

    yield folder
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _assert_killed_then_rerun(wd: Path, args: list[str]) -> subprocess.CompletedProcess:
    """After the kill: Snakemake's lock is left; docs/usage.md's command removes it (one line) and
    completes the run."""
    assert locked(wd)
    res = rerun(wd, args)
    notes = [ln for ln in res.stderr.splitlines() if "removed the lock" in ln]
    assert len(notes) == 1 and notes[0].startswith("flatlandia: removed the lock of a run killed here"), res.stderr
    assert not locked(wd)
    return res


@pytest.mark.slow
def test_killed_while_a_table_is_written(tiny_clean, tmp_path):
    """Killed with the table written under its temporary name, not yet renamed: the rerun redoes
    the job and removes the temporary."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(PAUSE_SITECUSTOMIZE)
    paused = tmp_path / "paused"
    wd = tmp_path / "run"
    env = {"PYTHONPATH": str(hook), "CRASH_TEST_PAUSE_AT": TABLE, "CRASH_TEST_PAUSED": str(paused)}
    run_and_kill(wd, [TABLE, *TINY_CONFIG], paused.exists, f"the rename onto {TABLE}", env=env)
    tmp = wd / paused.read_text()
    assert tmp.exists() and PARTIAL.match(tmp.name) and not (wd / TABLE).exists()
    res = _assert_killed_then_rerun(wd, [TABLE, *TINY_CONFIG])
    assert f"removed {tmp.relative_to(wd)}, the leftover of an interrupted run" in res.stderr
    assert (wd / TABLE).exists() and assert_same_outputs(tiny_clean(), wd, subset=True) == 5


@pytest.mark.slow
def test_killed_during_a_training(tiny_clean, tmp_path):
    """Killed at epoch 100 of 600: the rerun trains again from the start, to the same weights."""
    wd = tmp_path / "run"
    log = wd / "logs/fine_train/mlp_gt_gtbb.log"
    run_and_kill(wd, [CHECKPOINT, *TINY_CONFIG], lambda: "epoch 100:" in text(log), "epoch 100 of the training")
    assert not (wd / CHECKPOINT).exists()
    _assert_killed_then_rerun(wd, [CHECKPOINT, *TINY_CONFIG])
    assert (wd / CHECKPOINT).exists() and assert_same_outputs(tiny_clean(), wd, subset=True) == 7


@pytest.mark.slow
def test_killed_during_sfm(lund, tmp_path):
    """SfM on six Lund photos (single-threaded COLMAP: the same model run to run), killed during
    its feature extraction: the rerun removes its scratch folder and redoes SfM only."""
    if not all((lund / n).exists() for n in LUND_IMAGES):
        pytest.fail(f"the Lund images are needed at {lund}")
    photos = tmp_path / "lund6"
    photos.mkdir()
    for n in LUND_IMAGES:
        shutil.copy(lund / n, photos / n)
    sheet = tmp_path / "scenes.tsv"
    header = (REPO / "config" / "scenes.tsv").read_text().splitlines()[0]
    sheet.write_text(f"{header}\nlund\timages\tLund\tlund_six\t{photos}\t\t\n")
    args = [
        "results/lund/sfm/model",
        "--configfile",
        str(REPO / "config/test/images_lund.yaml"),
        "--config",
        f"scenes={sheet}",
    ]
    clean = tmp_path / "clean"
    clean_run = start(clean, args)  # alongside the killed run and its rerun: COLMAP runs on one thread
    try:
        wd = tmp_path / "run"
        log = wd / "logs/sfm/lund.log"
        run_and_kill(wd, args, lambda: "Processed file [3/6]" in text(log), "SfM's feature extraction")
        scratch = [p for p in partials(wd) if p.parent == wd / "results/lund/sfm"]
        assert len(scratch) == 1 and scratch[0].is_dir() and not (wd / "results/lund/sfm/model").exists()
        res = _assert_killed_then_rerun(wd, args)
    finally:
        finished(*clean_run)
    assert f"removed {scratch[0].relative_to(wd)}, the leftover of an interrupted run" in res.stderr
    assert [ln for ln in (res.stdout + res.stderr).splitlines() if ln.startswith("localrule ")] == ["localrule sfm:"]
    assert assert_same_outputs(clean, wd) >= 7  # the model's files, the stats, the cameras, ...


def _mount_tmpfs(path: Path, size: str) -> None:
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.decode(errors='replace').strip()}")


@pytest.mark.slow
@pytest.mark.skipif(os.name != "posix" or os.geteuid() != 0, reason="mounts a small tmpfs: needs root")
def test_a_disk_that_fills_up(tiny_clean, tmp_path):
    """results/ on a 128 KiB tmpfs: the map and queries fit, the checkpoint (150 KB) does not. The
    run ends with one ERROR line naming it; nothing half-written is left. With room made (the
    tmpfs grown), the same command completes with the clean run's outputs."""
    wd = tmp_path / "run"
    results = wd / "results"
    results.mkdir(parents=True)
    _mount_tmpfs(results, "128k")
    try:
        args = [CHECKPOINT, *TINY_CONFIG]
        res = smk(REPO, wd, "--cores", "2", *args)
        said = res.stdout + res.stderr
        assert res.returncode != 0
        errors = [ln for ln in said.splitlines() if ln.startswith("ERROR:")]
        expected = f"ERROR: {CHECKPOINT}: no space left on device; "
        assert len(errors) == 1 and errors[0].startswith(expected), said[-3000:]
        assert "Traceback" not in said
        assert not (wd / CHECKPOINT).exists() and partials(wd) == []
        for rel, path in outputs(wd).items():  # what is there is whole
            assert_same_output(tiny_clean() / rel, path)
        subprocess.run(["mount", "-o", "remount,size=4m", str(results)], check=True)
        rerun(wd, args)
        assert (wd / CHECKPOINT).exists() and assert_same_outputs(tiny_clean(), wd, subset=True) == 7
    finally:
        if subprocess.run(["umount", str(results)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(results)], capture_output=True)  # busy: detach it now


# ---------------------------------------------------------------- the parts, without a run


def test_a_writer_cut_short_by_a_full_disk_leaves_nothing(tmp_path, monkeypatch):
    """COLMAP's write_binary returns as if it had written a whole model on a full disk, torch's
    save raises a bare RuntimeError: with the disk full at that moment, the atomic writers raise
    ENOSPC naming the output, and neither leaves a file under its name nor a temporary."""
    import errno

    from flatlandia.plumbing import files

    monkeypatch.setattr(files, "disk_full", lambda path: True)
    out = tmp_path / "model"
    with pytest.raises(OSError) as err, files.atomic_dir(out) as tmp:
        (tmp / "points3D.bin").write_bytes(b"cut short")  # "succeeds"
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(out)
    target = tmp_path / "checkpoint.pt"
    with pytest.raises(OSError) as err, files.atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("basic_ios::clear: iostream error")
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(target)
    assert isinstance(err.value.__cause__, RuntimeError)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_error_on_a_disk_with_room_is_left_alone(tmp_path):
    from flatlandia.plumbing import files

    with pytest.raises(RuntimeError, match="a bug"), files.atomic_path(tmp_path / "x.pt"):
        raise RuntimeError("a bug")
    assert list(tmp_path.iterdir()) == []


def test_a_rule_out_of_room_ends_with_one_error_line(tmp_path, capsys):
    """rule_log.run: an ENOSPC (named by a writer or not) ends the script with one ERROR line and
    exit status 1, the writer's own error in the log, no traceback anywhere."""
    import errno
    from types import SimpleNamespace

    from flatlandia.plumbing import rule_log

    log = tmp_path / "rule.log"
    smk_ = SimpleNamespace(log=[str(log)], output=["results/x/out.parquet"], rule="x", wildcards={}, params={})
    for raised, named in (
        (OSError(errno.ENOSPC, "No space left on device", "results/x/table.md"), "results/x/table.md"),
        (OSError(errno.ENOSPC, "Error writing bytes to file"), "results/x/out.parquet"),
        (OSError(errno.EDQUOT, "Disk quota exceeded", "results/x/table.md"), "results/x/table.md"),
    ):

        def main(smk, logger, raised=raised):
            logger.info("working")
            raise raised

        with pytest.raises(SystemExit) as ended:
            rule_log.run(main, smk_)
        assert ended.value.code == 1
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.startswith("ERROR:")]
        problem = "disk quota exceeded" if raised.errno == errno.EDQUOT else "no space left on device"
        assert len(lines) == 1 and lines[0].startswith(f"ERROR: {named}: {problem}; "), err
        assert "rerun the same command" in lines[0] and "Traceback" not in err
        assert "Traceback" not in log.read_text() and "the writer's error: OSError" in log.read_text()


def _dead_pid() -> int:
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def _lock_with_note(locks: Path, name: str, **change) -> Path:
    from flatlandia.plumbing import stale_locks

    locks.mkdir(parents=True, exist_ok=True)
    lock = locks / name
    lock.write_text("results/x\n")
    stale_locks.claim(lock, local=True)
    note = stale_locks.owner_note(lock)
    note.write_text(json.dumps(json.loads(note.read_text()) | change))
    return lock


def test_a_stale_lock_is_removed_only_when_its_run_is_provably_gone(tmp_path):
    """The owner note decides: a dead run of this user, host, boot and pid namespace with the local
    executor loses its lock; a live run, another machine's, another user's, a cluster run's, one
    without a note or with a note of another lock file keeps it, and says whose it is."""
    from flatlandia.plumbing import stale_locks

    if stale_locks._identity()["boot"] is None or stale_locks._proc_stat(os.getpid()) is None:
        pytest.skip("no /proc here: every lock is kept (Snakemake's --unlock by hand)")
    locks = tmp_path / ".snakemake" / "locks"
    dead = _dead_pid()
    stale = _lock_with_note(locks, "0.input.lock", pid=dead, pgid=None)
    kept = {
        "1.input.lock": ({}, "a run still going"),  # this very process
        "2.input.lock": ({"pid": dead, "host": "elsewhere"}, "a run on another machine"),
        "3.input.lock": ({"pid": dead, "uid": os.getuid() + 1}, "another user's run"),
        "4.input.lock": ({"pid": dead, "local": False}, "a run with a cluster executor"),
        "5.input.lock": ({"pid": dead, "lock_size": 1}, "a run of unknown owner"),
    }
    for name, (change, _) in kept.items():
        _lock_with_note(locks, name, **change)
    (locks / "6.output.lock").write_text("results/y\n")  # no note: an earlier version's, or killed as it locked
    assert stale_locks.judge(stale) == (True, stale_locks.judge(stale)[1])
    said: list[str] = []
    removed, why = stale_locks.clear_stale(locks, say=said.append)
    assert removed == [stale] and not stale.exists() and not stale_locks.owner_note(stale).exists()
    assert len(said) == 1 and said[0].startswith(
        f"flatlandia: removed the lock of a run killed here (Snakemake pid {dead} "
    )
    assert len(why) == 6 and all((locks / name).exists() for name in kept)
    for (_, expected), got in zip(kept.values(), why, strict=False):
        assert got.startswith(expected), (expected, got)
    assert why[-1].startswith("a run of unknown owner (its lock has no owner note")
    assert "--unlock" in stale_locks.refusal_line(why)
    assert "--unlock" not in stale_locks.refusal_line(why[:1]) and "wait for it" in stale_locks.refusal_line(why[:1])
    # a power cut: the lock of a run of an earlier boot of this machine (its pid now anyone's)
    restarted = _lock_with_note(locks, "7.input.lock", boot="an-earlier-boot")
    if stale_locks._identity()["machine"]:
        assert stale_locks.judge(restarted)[1].startswith("a run from before this machine restarted")
        assert stale_locks.clear_stale(locks)[0] == [restarted]
    else:  # no machine id: an earlier boot of this machine looks like another machine
        assert not stale_locks.judge(restarted)[0]


def test_a_lock_whose_run_left_a_job_running_is_kept(tmp_path):
    """Snakemake killed alone: the job scripts it started may still be writing; its lock stays."""
    from flatlandia.plumbing import stale_locks

    scripts = tmp_path / ".snakemake" / "scripts"
    scripts.mkdir(parents=True)
    script = scripts / "tmpabcdefgh.train.py"
    script.write_text("import time\ntime.sleep(60)\n")
    job = subprocess.Popen([sys.executable, str(script)])
    try:
        lock = _lock_with_note(tmp_path / ".snakemake" / "locks", "0.input.lock", pid=_dead_pid(), pgid=None)
        stale, why = stale_locks.judge(lock)
        assert not stale and f"job scripts of this folder still run (pid [{job.pid}])" in why
    finally:
        job.kill()
        job.wait()
    assert stale_locks.judge(lock)[0]
