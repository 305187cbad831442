"""The cluster path: `snakemake --profile workflow/profiles/slurm` through sbatch on a one-node SLURM
(tests/slurm/start_slurm.sh: Debian's slurm-wlm and munge, accounting off) gives the same results
as a local run; a killed run's leftover job is found and cancelled by the command of docs/usage.md; and
every rule declares threads, mem_mb and runtime from one table (workflow/rules/resources.yaml)
that covers what its jobs were measured to need and fits a small node.

The SLURM tests need root and Debian's apt-get (the script installs the packages when missing);
elsewhere, or when a daemon does not start, they skip and say why. The cluster is stopped at the
end when this module started it (tests/slurm/stop_slurm.sh)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from conftest import REPO, smk_dry_run
from snakemake_runner import SNAKEMAKE, smk

from flatlandia.report import tables

SLURM_SCRIPTS = REPO / "tests" / "slurm"
PROFILE = REPO / "workflow" / "profiles" / "slurm"
RULES = REPO / "workflow" / "rules"
TEST_CONFIGS = REPO / "config" / "test"
#: a small cluster node: what every rule's ask must fit (cores, MB)
SMALL_NODE = (2, 20000)


# ---------------------------------------------------------------- resources, profile (fast)
def _rule_blocks() -> dict[str, str]:
    """Every rule of workflow/rules/*.smk with a job (a script, shell, run or wrapper): its text."""
    blocks = {}
    for path in sorted(RULES.glob("*.smk")):
        for m in re.finditer(r"^rule (\w+):\n((?:[ \t].*\n|\n)*)", path.read_text(), flags=re.M):
            if re.search(r"^    (script|shell|run|notebook|wrapper):", m.group(2), flags=re.M):
                blocks[m.group(1)] = m.group(2)
    return blocks


def _resource_table() -> dict:
    return yaml.safe_load((RULES / "resources.yaml").read_text())


def test_every_rule_reads_threads_memory_and_runtime_from_the_one_table():
    blocks, table = _rule_blocks(), _resource_table()
    assert len(blocks) > 40
    assert set(table) == set(blocks), (
        f"rows without a rule: {set(table) - set(blocks)}; rules without a row: {set(blocks) - set(table)}"
    )
    for name, text in blocks.items():
        assert f'    threads: rule_threads("{name}")\n' in text, name
        assert f'    resources:\n        **rule_resources("{name}"),\n' in text, name
        assert text.count("threads:") == 1 and text.count("resources:") == 1, name


def test_resource_figures_cover_the_measured_peaks_and_fit_a_small_node():
    cores, mem_mb = SMALL_NODE
    computed = {"sfm_threads", "segment_mem_mb", "coarse_train_runtime", "fine_train_runtime"}
    for name, row in _resource_table().items():
        assert set(row) - {"gpu"} == {"threads", "mem_mb", "runtime", "measured"}, name
        assert row.get("gpu", 1) == 1 or row["gpu"] in {"segment_gpus", "queries_gpus", "fine_eval_gpus"}, name
        for key in ("threads", "mem_mb", "runtime"):
            assert isinstance(row[key], int) or row[key] in computed, (name, key, row[key])
        if isinstance(row["threads"], int):
            assert 1 <= row["threads"] <= cores, name
        if isinstance(row["mem_mb"], int):
            assert 1000 <= row["mem_mb"] <= mem_mb, name
        measured = row["measured"]
        if measured is None:  # no run measured it (fetch_images, external_eval): said in the table
            continue
        if isinstance(row["mem_mb"], int):
            assert row["mem_mb"] >= 1.5 * measured["peak_mb"], name
        if isinstance(row["runtime"], int):
            assert row["runtime"] * 60 >= 5 * measured["wall_s"], name


def test_slurm_profile_needs_no_accounting_and_hard_codes_no_site():
    text = (PROFILE / "config.yaml").read_text()
    profile = yaml.safe_load(text)
    assert profile["executor"] == "slurm"
    assert profile["slurm-status-command"] == "squeue"  # sacct answers nothing without slurmdbd
    assert 1 <= profile["slurm-init-seconds-before-status-checks"] <= 100  # 3x of it under MinJobAge 300 s
    # the figures live in the rule table; a partition, an account or a per-rule figure here would be a
    # site's (the header lists them, commented out)
    assert not {"default-resources", "set-resources", "set-threads"} & set(profile)
    header = text.split("\nexecutor:")[0]
    for setting in (
        "slurm_partition",
        "slurm_account",
        "slurm-no-account",
        "set-resources",
        "gpu",
        "device: cuda",
        "resources.yaml",
    ):
        assert setting in header, setting


def test_slurm_profile_dry_run_asks_every_job_for_cores_memory_and_time(repo, tmp_path):
    res = smk_dry_run(repo, tmp_path, "--profile", str(PROFILE), "all", "--configfile", str(TEST_CONFIGS / "tiny.yaml"))
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    blocks = _rule_blocks()  # not the targets (`all`): they run nothing
    jobs = [
        job for job in re.findall(r"^\s*rule (\w+):\n((?:\s+\w+: .*\n)+)", res.stdout, flags=re.M) if job[0] in blocks
    ]
    assert len(jobs) > 40
    for name, text in jobs:
        assert re.search(r"resources: .*runtime=\d+, mem_mb=\d+", text), (name, text)
    assert "Group job scene_prep" in res.stdout  # the light per-scene steps travel as one job


@pytest.mark.slow  # the published data (flat_root)
def test_slurm_profile_dry_run_of_all_scenes_asks_what_the_table_says(repo, flat_root, tmp_path):
    """`all` on the published scenes and Lund's images (moved here from test_workflow.py): SfM,
    segment and the trainings ask for the table's figures, and no partition is imposed."""
    res = smk_dry_run(repo, tmp_path, "--profile", str(PROFILE), "all", "--config", f"flatlandia_root={flat_root}")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    out = res.stdout + res.stderr
    resources = {}
    for rule, block in re.findall(r"^\s*rule (\w+):\n(.*?)Shell command", out, flags=re.S | re.M):
        resources.setdefault(rule, re.search(r"resources: (.*)", block).group(1))
    assert "runtime=60, mem_mb=4000" in resources["sfm"]
    assert "runtime=30, mem_mb=5000" in resources["segment"]  # 1000 + 80 x images.max_megapixels 50
    assert "runtime=10, mem_mb=1000" in resources["recover"]
    assert re.search(r"runtime=\d+, mem_mb=2000", resources["coarse_train"])
    assert re.search(r"runtime=(1\d|2\d), mem_mb=2500", resources["fine_train"])  # from the epochs: 11-24 min
    assert "slurm_partition" not in out and "cpus_per_task" not in out
    assert "Group job scene_prep" in out  # light per-scene steps travel as one cluster job


#: the rules that run a torch model, and so ask for a GPU with config device: cuda
GPU_RULES = {"coarse_train", "coarse_eval", "fine_train", "fine_eval", "segment", "queries"}


class _Resources(dict):
    """A job's resources as the SLURM plugin reads them (``.get`` and attributes)."""

    __getattr__ = dict.__getitem__


def _planned_resources(output: str) -> list[tuple[str, str, dict]]:
    """(rule, wildcards, resources) of every job a dry run plans."""
    jobs = []
    for rule, block in re.findall(r"^\s*rule (\w+):\n((?:\s+\w+: .*\n)+)", output, flags=re.M):
        found = re.search(r"resources: (.*)", block)
        if found:
            pairs = (item.split("=", 1) for item in found.group(1).split(", ") if "=" in item)
            wildcards = re.search(r"wildcards: (.*)", block)
            values = {k: int(v) if v.isdigit() else v for k, v in pairs}  # Snakemake's ints stay ints
            jobs.append((rule, wildcards.group(1) if wildcards else "", values))
    return jobs


def test_with_device_cuda_the_model_rules_ask_slurm_for_a_gpu_and_the_others_do_not(repo, tmp_path):
    """The resources Snakemake computes for each job of a SLURM dry run (the host that submits
    needs no GPU of its own), turned into sbatch arguments by the plugin's own function: --gpus=1
    for the jobs that run a model (a learned fine_eval, not the solver's), nothing for the others,
    and nothing for any job with the default device."""
    from snakemake_executor_plugin_slurm.utils import set_gres_string

    tiny = ["--configfile", str(TEST_CONFIGS / "tiny.yaml")]
    res = smk_dry_run(repo, tmp_path, "--profile", str(PROFILE), "all", *tiny, "--config", "device=cuda")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    jobs = [job for job in _planned_resources(res.stdout) if job[0] in _rule_blocks()]
    asks = {}
    for rule, wildcards, resources in jobs:
        sbatch = set_gres_string(type("Job", (), {"resources": _Resources(resources)})())
        asks.setdefault(rule, set()).add(sbatch.strip())
        learned = rule != "fine_eval" or not wildcards.startswith("method=solver")
        if rule in {"coarse_train", "coarse_eval", "fine_train", "fine_eval"} and learned:
            assert resources["gpu"] == 1 and sbatch.strip() == "--gpus=1", (rule, wildcards, resources)
        else:
            assert resources.get("gpu", 0) == 0 and sbatch == "", (rule, wildcards, resources)
    assert {"coarse_train", "fine_train", "fine_eval", "coarse_eval"} <= set(asks)
    assert asks["fine_eval"] == {"--gpus=1", ""}  # the learned models' runs, and the solver's
    assert len(set(asks) - GPU_RULES) > 15  # every other rule planned, none asking
    plain = smk_dry_run(repo, tmp_path, "--profile", str(PROFILE), "all", *tiny)
    assert plain.returncode == 0 and "gpu=" not in plain.stdout


# ---------------------------------------------------------------- the one-node cluster (slow)
def _run(*cmd: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=kw.pop("timeout", 60), **kw)


def _cluster_up() -> bool:
    return bool(shutil.which("scontrol")) and "UP" in _run("scontrol", "ping").stdout


def _cannot_run_here() -> str | None:
    if os.geteuid() != 0:
        return (
            "needs root: tests/slurm/start_slurm.sh installs slurm-wlm and munge and starts munged, slurmctld, slurmd"
        )
    if not shutil.which("apt-get") or not Path("/etc/debian_version").exists():
        return "needs Debian's apt-get: tests/slurm/start_slurm.sh installs slurm-wlm and munge with it"
    return None


@pytest.fixture(scope="module")
def slurm():
    """A one-node SLURM, up (started here when it was not, stopped again at the end)."""
    reason = _cannot_run_here()
    if reason:
        pytest.skip(reason)
    was_up = _cluster_up()
    res = _run("bash", str(SLURM_SCRIPTS / "start_slurm.sh"), timeout=600)
    if res.returncode != 0:
        last = (res.stderr.strip().splitlines() or ["no message"])[-1]
        pytest.skip(f"the one-node SLURM did not start: {last}")
    yield
    if not was_up:
        _run("bash", str(SLURM_SCRIPTS / "stop_slurm.sh"), timeout=120)


def _run_id(output: str) -> str:
    m = re.search(r"SLURM run ID: ([0-9a-f-]{36})", output)
    assert m, output[-3000:]
    return m.group(1)


def _jobs_of(run_id: str, states: str = "all") -> list[tuple[str, str]]:
    """(SLURM job id, state) of the run's jobs (squeue keeps finished ones MinJobAge, 300 s)."""
    out = _run("squeue", "-h", f"--states={states}", "--name", run_id, "-o", "%i %T").stdout
    return [tuple(line.split()) for line in out.splitlines()]


def _cancel_jobs_of(output: Path) -> None:
    """Cancel the SLURM jobs of the run whose output is in ``output`` (a failed test leaves none)."""
    m = re.search(r"SLURM run ID: ([0-9a-f-]{36})", output.read_text()) if output.exists() else None
    if m:
        _run("scancel", "--name", m.group(1))


def _tensors(obj, prefix=""):
    import torch

    if isinstance(obj, torch.Tensor):
        yield prefix, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _tensors(v, f"{prefix}/{k}")
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from _tensors(v, f"{prefix}/{i}")


def differences(a: Path, b: Path) -> list[str]:
    """How results/ of run ``a`` and run ``b`` differ: the same files; every Parquet file the same
    table, exactly, but for its timing columns (flatlandia.report.tables.timing_columns says which); every
    trained model's tensors equal (single-threaded, seeded)."""
    import torch

    files = [{p.relative_to(root) for p in (root / "results").rglob("*") if p.is_file()} for root in (a, b)]
    problems = [f"only in one run: {sorted(map(str, files[0] ^ files[1]))}"] if files[0] != files[1] else []
    for rel in sorted(files[0] & files[1]):
        if rel.suffix == ".parquet":
            ta, tb = pd.read_parquet(a / rel), pd.read_parquet(b / rel)
            timing = tables.timing_columns(ta.columns)
            try:
                pd.testing.assert_frame_equal(ta.drop(columns=timing), tb.drop(columns=timing), check_exact=True)
            except AssertionError as err:
                problems.append(f"{rel}: {str(err).splitlines()[0]}")
        elif rel.suffix == ".pt":
            ta, tb = (dict(_tensors(torch.load(root / rel, map_location="cpu", weights_only=False))) for root in (a, b))
            if ta.keys() != tb.keys() or not all(torch.equal(ta[k], tb[k]) for k in ta):
                problems.append(f"{rel}: the trained weights differ")
    return problems


def local_and_slurm(repo: Path, tmp_path: Path, *args: str) -> tuple[Path, Path, str]:
    """The same targets and config run through SLURM with the cluster profile and, meanwhile, locally
    (the SLURM run mostly waits on its jobs): both folders and the SLURM run's output. Prints the
    wall time of each."""
    local, cluster = tmp_path / "local", tmp_path / "slurm"
    local.mkdir()
    cluster.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"}
    cmd = [SNAKEMAKE, "-s", str(repo / "workflow" / "Snakefile"), "-d", str(cluster), "--profile", str(PROFILE), *args]
    t0 = time.perf_counter()
    with open(tmp_path / "slurm.out", "w") as log:
        proc = subprocess.Popen(cmd, cwd=cluster, stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        res = smk(repo, local, "--cores", "2", *args)
        t_local = time.perf_counter() - t0
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        proc.wait(timeout=900)
    finally:
        if proc.poll() is None:  # the local run failed: stop the SLURM run and its jobs too
            proc.kill()
            proc.wait()
            _cancel_jobs_of(tmp_path / "slurm.out")
    t_slurm = time.perf_counter() - t0
    out = (tmp_path / "slurm.out").read_text()
    assert proc.returncode == 0, out[-6000:]
    print(f"{' '.join(args)}: SLURM {t_slurm:.0f} s, the local run beside it {t_local:.0f} s")
    return local, cluster, out


@pytest.mark.slow
def test_maps_of_the_tiny_scene_through_slurm_equal_the_local_run(slurm, repo, tmp_path):
    local, cluster, out = local_and_slurm(repo, tmp_path, "maps", "--configfile", str(TEST_CONFIGS / "tiny.yaml"))
    run_id = _run_id(out)
    # the scene's five light steps went to SLURM as one group job, through sbatch
    assert len(re.findall(r"has been submitted with SLURM jobid \d+", out)) == 1, out[-3000:]
    assert not _jobs_of(run_id, "PENDING,RUNNING")
    assert differences(local, cluster) == []
    assert (cluster / "results/0/maps/reference_map.parquet").exists()


@pytest.mark.slow
def test_benchmark_of_two_scenes_through_slurm_equals_the_local_run(slurm, repo, flat_root, tmp_path):
    """Dataset tables, a coarse and two fine models (2 epochs each: config/test/slurm_small.yaml)
    and the localization tables of scenes 9 and 12: 27 SLURM jobs, one per job of a rule (per
    scene for the grouped light steps)."""
    configs = [str(TEST_CONFIGS / name) for name in ("two_scenes.yaml", "slurm_small.yaml")]
    local, cluster, out = local_and_slurm(
        repo, tmp_path, "benchmark", "--configfile", *configs, "--config", f"flatlandia_root={flat_root}"
    )
    run_id = _run_id(out)
    assert len(re.findall(r"has been submitted with SLURM jobid \d+", out)) >= 25
    assert not _jobs_of(run_id, "PENDING,RUNNING")
    assert differences(local, cluster) == []
    for table in ("dataset_stats", "coarse_localization", "fine_localization"):
        assert (cluster / f"results/tables/{table}.parquet").exists()


def _readme_cancel_command() -> str:
    """The command of docs/usage.md ("Audit trail, report, cluster") that cancels the jobs of a killed
    run (run in its folder)."""
    usage = (REPO / "docs" / "usage.md").read_text()
    commands = [line.strip() for line in usage.splitlines() if line.strip().startswith("scancel ")]
    assert len(commands) == 1, commands
    return commands[0]


@pytest.mark.slow
def test_a_killed_runs_job_keeps_running_and_the_readme_command_cancels_it(slurm, repo, tmp_path):
    """kill -9 of Snakemake while its SLURM job runs leaves the job running (a resumed run would
    submit it again: the plugin's issue #109); docs/usage.md's command, run in the run's folder, finds
    the job by the run's ID and cancels it before it writes its last output."""
    env = {k: v for k, v in os.environ.items() if k != "FLATLANDIA_ROOT"}
    cmd = [SNAKEMAKE, "-s", str(repo / "workflow" / "Snakefile"), "-d", str(tmp_path), "--profile", str(PROFILE)]
    cmd += ["maps", "--configfile", str(TEST_CONFIGS / "tiny.yaml")]
    t0 = time.perf_counter()
    with open(tmp_path / "snakemake.out", "w") as log:
        proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        run_id, running, deadline = None, [], time.monotonic() + 300
        while not running and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            m = re.search(r"SLURM run ID: ([0-9a-f-]{36})", (tmp_path / "snakemake.out").read_text())
            run_id = m.group(1) if m else None
            running = [job for job, state in _jobs_of(run_id, "RUNNING")] if run_id else []
        assert running, (tmp_path / "snakemake.out").read_text()[-3000:]
        t_running = time.perf_counter() - t0
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        # Snakemake is gone, its job is not
        assert [state for job, state in _jobs_of(run_id) if job == running[0]] == ["RUNNING"]
        res = subprocess.run(["bash", "-c", _readme_cancel_command()], cwd=tmp_path, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        for _ in range(60):
            states = dict(_jobs_of(run_id))
            if states.get(running[0]) == "CANCELLED":
                break
            time.sleep(0.5)
        assert states == {running[0]: "CANCELLED"}, states
        print(f"job running {t_running:.0f} s after the start; killed, cancelled {time.perf_counter() - t0:.0f} s")
        assert not (tmp_path / "results/0/maps/reference_map.png").exists()  # the group's last step never ran
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
        _cancel_jobs_of(tmp_path / "snakemake.out")
