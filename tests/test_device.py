"""The config's ``device`` (flatlandia.device): ``auto`` without a GPU is the CPU, ``cuda`` without
one is one ERROR line naming the setting (from the library, the rule scripts and the workflow's
parse, before any job), and a training step keeps every parameter and batch on the resolved device.

No GPU is needed: the placement is checked on the CPU through the same code path (hooks record the
device of every tensor a step hands the model and the losses), and the coarse stage's whole step
runs on torch's ``meta`` device, where any tensor left on the CPU stops it as it would on a GPU. The
device-side pieces that replace host code (graph batches selected from a collated split, hard
negatives ranked on the device) give exactly what the host code gave.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import smk_dry_run
from snakemake_runner import job_stats, smk

from flatlandia import config, device, geo
from flatlandia.coarse import graphs, retrieval
from flatlandia.coarse import training as coarse_training
from flatlandia.fine import models
from flatlandia.fine import training as fine_training
from flatlandia.plumbing.errors import InputError

HAS_CUDA = torch.cuda.is_available()
META = torch.device("meta")


@pytest.fixture
def no_gpu(monkeypatch):
    """A machine whose torch is built with CUDA but sees no GPU."""
    monkeypatch.setattr(torch.version, "cuda", "13.0")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


# ----------------------------------------------------------------------------- resolution


def test_auto_without_a_gpu_is_the_cpu(no_gpu):
    assert device.resolve("auto") == torch.device("cpu")
    assert device.resolve("cpu") == torch.device("cpu")
    assert device.torch_device("auto") == torch.device("cpu")
    assert device.workflow_check("auto") is None and device.workflow_check("cpu") is None


@pytest.mark.skipif(HAS_CUDA, reason="this machine has a GPU: auto is CUDA here")
def test_auto_on_this_machine_without_a_gpu_is_the_cpu():
    assert device.resolve("auto") == torch.device("cpu")
    assert device.resolve(config.resolve({})["device"]) == torch.device("cpu")  # the default: auto


def test_cuda_without_a_gpu_is_one_error_naming_the_setting(no_gpu):
    with pytest.raises(InputError) as err:
        device.resolve("cuda")
    text = str(err.value)
    assert text.startswith("config: 'device': cuda asked for, but torch") and "sees no GPU" in text
    assert "\n" not in text and "use device: auto" in text
    line = device.workflow_check("cuda")
    assert line == text
    # a cluster run's submitting host needs no GPU: its jobs check on their nodes
    assert device.workflow_check("cuda", jobs_run_here=False) is None


def test_cuda_with_a_torch_built_without_it_says_so(monkeypatch):
    monkeypatch.setattr(torch.version, "cuda", None)
    with pytest.raises(InputError, match=r"config: 'device': cuda asked for, but this torch .* built without CUDA"):
        device.resolve("cuda")


def test_a_device_the_setting_does_not_know_is_refused():
    with pytest.raises(InputError, match="config: 'device': 'gpu' is not one of auto, cpu, cuda"):
        device.resolve("gpu")
    with pytest.raises(config.ConfigError, match="'device'"):
        config.resolve({"device": "gpu"})
    assert config.resolve({"device": "cpu"})["device"] == "cpu"


@pytest.mark.skipif(HAS_CUDA, reason="this machine has a GPU: cuda is honoured")
def test_a_dry_run_with_cuda_without_a_gpu_warns_and_plans_the_jobs(repo, tmp_path):
    """A plan for a GPU machine can be previewed anywhere: one WARNING line naming the setting, and
    the same jobs as on the CPU."""
    tiny = ["--configfile", str(repo / "config" / "test" / "tiny.yaml")]
    res = smk_dry_run(repo, tmp_path, "all", *tiny, "--config", "device=cuda")
    assert res.returncode == 0, res.stderr[-2000:]
    said = [ln for ln in (res.stdout + res.stderr).splitlines() if "WARNING" in ln or "ERROR" in ln]
    assert len(said) == 1 and said[0].startswith("WARNING: config: 'device': cuda asked for"), said
    assert said[0].endswith("this dry run plans the jobs anyway, a run here stops with it as an ERROR")
    assert "Traceback" not in res.stderr
    cpu = smk_dry_run(repo, tmp_path, "all", *tiny, "--config", "device=cpu")
    assert cpu.returncode == 0, cpu.stderr[-2000:]
    assert job_stats(res.stdout) == job_stats(cpu.stdout) and job_stats(res.stdout)["total"] > 20


@pytest.mark.slow  # the Snakemake runner (a run, though it stops at its parse)
@pytest.mark.skipif(HAS_CUDA, reason="this machine has a GPU: cuda is honoured")
def test_a_run_with_cuda_without_a_gpu_stops_at_its_parse(repo, tmp_path):
    tiny = ["--configfile", str(repo / "config" / "test" / "tiny.yaml")]
    res = smk(repo, tmp_path, "--cores", "1", "maps", *tiny, "--config", "device=cuda")
    assert res.returncode == 1
    errors = [ln for ln in (res.stdout + res.stderr).splitlines() if "ERROR" in ln or "WARNING" in ln]
    assert len(errors) == 1 and errors[0].startswith("ERROR: config: 'device': cuda asked for"), errors
    assert "Traceback" not in res.stderr and "Job stats" not in res.stdout  # before any job is planned
    assert not (tmp_path / "results").exists()


@pytest.mark.skipif(HAS_CUDA, reason="this machine has a GPU: cuda is honoured")
def test_flatlandia_debug_of_a_training_stops_with_the_same_line(repo, tmp_path):
    """The command line's way into a rule (`flatlandia debug`) parses the workflow: the same one line."""
    from flatlandia import cli

    tiny = ["--configfile", str(repo / "config" / "test" / "tiny.yaml"), "--config", "device=cuda"]
    with pytest.raises(SystemExit) as stop:
        cli.main(["debug", "coarse_train", "loss=sim", "-d", str(tmp_path), *tiny, "--show"])
    line = str(stop.value.code)
    assert line.startswith("ERROR: config: 'device': cuda asked for") and "\n" not in line


class _Named(dict):
    """A Snakemake namedlist as a rule script reads it: by attribute or ``.get``."""

    __getattr__ = dict.__getitem__


@pytest.mark.parametrize("rule", ["coarse_train", "coarse_eval", "fine_train", "fine_eval"])
def test_a_rule_script_on_a_node_without_a_gpu_stops_with_one_line_before_its_work(rule, repo, no_gpu, capsys):
    """On a cluster the parse of the submitting host does not check (it needs no GPU); the job's
    script does, first: one ERROR line naming the setting, exit 1, nothing read or written."""
    import runpy

    job = type("Job", (), {})()
    job.config, job.threads, job.log = {"device": "cuda"}, 1, []
    job.input, job.output = _Named(reference_maps=[], queries=[]), _Named()
    job.wildcards = _Named(map_type="gt", method="mlp", proposal="gtbb", loss="sim")
    job.params = _Named(solver={})  # a learned model on GT-BB proposals reads no config key
    with pytest.raises(SystemExit) as stop:
        runpy.run_path(str(repo / "workflow" / "scripts" / f"{rule}.py"), init_globals={"snakemake": job})
    assert stop.value.code == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("ERROR")]
    assert len(err) == 1 and err[0].startswith("ERROR: config: 'device': cuda asked for, but torch"), err


# ----------------------------------------------------------------------------- fine: placement


def _toy_samples(n, cfg, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        ref = rng.uniform(-50, 50, (int(rng.integers(6, 14)), 2))
        cls = rng.integers(0, 5, len(ref))
        cam, th = rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi)
        m = int(rng.integers(3, 6))
        local = geo.world_to_local(ref[:m], cam, th)
        q = local / np.median(np.linalg.norm(local, axis=1)) if cfg.map_type == "depth" else local
        out.append(models.make_sample(q, cls[:m], ref, cls, cfg, cam, th))
    return out


def _tensors(obj) -> list[torch.Tensor]:
    if isinstance(obj, torch.Tensor):
        return [obj]
    if isinstance(obj, (list, tuple)):
        return [t for o in obj for t in _tensors(o)]
    if hasattr(obj, "__dict__"):
        return [t for o in vars(obj).values() for t in _tensors(o)]
    return []


@pytest.mark.parametrize("name", models.MODELS)
def test_a_fine_training_step_keeps_every_parameter_and_batch_on_the_resolved_device(name, monkeypatch):
    """Every forward of the training (steps and validation) gets its batch and runs its weights on
    the device ``auto`` resolves to; the loss sees its tensors there; the result's model is there
    and its saved weights on the CPU."""
    dev = device.resolve("auto")
    cfg = models.FineTrainConfig(
        model=name, map_type="depth", hidden=16, heads=2, rounds=1, epochs=2, batch_size=4, eval_every=1
    )
    seen: list[tuple[str, torch.device]] = []

    def record(module, args):
        seen.extend(("batch", t.device) for t in _tensors(args[0]))
        seen.extend(("parameter", p.device) for p in module.parameters())

    original_loss = fine_training.pose_loss

    def loss(pred, target, w):
        seen.extend(("loss", t.device) for t in (pred, target))
        return original_loss(pred, target, w)

    monkeypatch.setattr(fine_training, "pose_loss", loss)
    monkeypatch.setattr(models.MLPModel, "__call__", _hooked(models.MLPModel.__call__, record))
    monkeypatch.setattr(models.GATModel, "__call__", _hooked(models.GATModel.__call__, record))
    res = fine_training.train(_toy_samples(10, cfg), _toy_samples(5, cfg, seed=1), cfg, device="auto")
    kinds = {k for k, _ in seen}
    assert kinds == {"batch", "parameter", "loss"}
    assert {d for _, d in seen} == {dev}, sorted(set(seen), key=str)
    assert sum(k == "batch" for k, _ in seen) > 10
    assert {p.device for p in res["model"].parameters()} == {dev}
    assert {t.device.type for t in res["state_dict"].values()} == {"cpu"}


def _hooked(call, record):
    def wrapped(self, *args, **kw):
        record(self, args)
        return call(self, *args, **kw)

    return wrapped


def test_graph_batches_selected_from_the_collated_split_equal_torch_geometric_batches():
    cfg = models.FineTrainConfig(model="GAT", map_type="gt")
    samples = _toy_samples(9, cfg, seed=3)
    samples[4] = models.make_sample(
        np.zeros((1, 2)), [7], np.ones((4, 2)), [1, 2, 3, 4], cfg, (0, 0), 0.0
    )  # no inter edge
    split = models.GraphSplit(samples)
    for pick in ([0], [8, 2, 5], [4], [4, 1, 4], list(range(9))[::-1]):
        got, want = split[np.array(pick)], models.Batch.from_data_list([samples[i] for i in pick])
        assert got.num_graphs == want.num_graphs
        for key in (*models.NODE_KEYS, *models.EDGE_KEYS, *models.GRAPH_KEYS, "batch"):
            a, b = getattr(got, key), getattr(want, key)
            assert a.dtype == b.dtype and torch.equal(a, b), (pick, key)


def test_the_fine_data_path_runs_on_a_device_without_touching_the_host():
    """On ``meta`` (no data, every CPU tensor mixed in is an error): selections of the padded maps
    and of the collated graphs, and the augmentation, stay on the device."""
    for name in ("MLP", "GAT"):
        cfg = models.FineTrainConfig(model=name, map_type="depth", aug_depth_scale=0.2)
        samples = _toy_samples(6, cfg)
        split = (models.dense_maps if name == "MLP" else models.GraphSplit)(samples).to(META)
        batch = fine_training.augment(split[np.array([5, 0, 3])], cfg, torch.Generator().manual_seed(0))
        tensors = _tensors(batch)
        assert len(tensors) >= 7 and {t.device for t in tensors} == {META}


# ----------------------------------------------------------------------------- coarse: placement


def _coarse_dataset(n_queries=8, seed=0) -> retrieval.Dataset:
    rng = np.random.default_rng(seed)
    refs, ref_graphs, samples = [], [], []
    for k in range(2):
        n = 24 + 6 * k
        ref = pd.DataFrame(
            {
                "scene": str(k),
                "obj_idx": np.arange(n),
                "x_m": rng.uniform(-60, 60, n),
                "y_m": rng.uniform(-60, 60, n),
                "class_id": rng.integers(0, 6, n),
            }
        )
        refs.append(ref)
        ref_graphs.append(graphs.reference_graph(ref))
        for j in range(n_queries):
            rows = np.sort(rng.choice(n, int(rng.integers(3, 7)), replace=False))
            q = {
                mt: graphs.query_graph(rng.uniform(0, 40, (len(rows), 2)), ref["class_id"].to_numpy()[rows])
                for mt in retrieval.MAP_TYPES
            }
            split = "val" if j % 4 == 0 else "train"
            S = rng.random(n).astype(np.float32)
            S[rng.integers(0, n)] = S.max()  # a tie at the top
            samples.append(
                retrieval.Sample(
                    k, f"{k}-{j}", split, q, rows, len(rows), np.zeros(2), S, np.setdiff1d(np.arange(n), rows)
                )
            )
    offsets = np.r_[0, np.cumsum([len(r) for r in refs])[:-1]]
    return retrieval.Dataset(["0", "1"], refs, ref_graphs, graphs.batch(ref_graphs), offsets, samples)


@pytest.mark.parametrize("loss", ["sim", "trip", "simtrip"])
def test_a_coarse_training_step_keeps_every_parameter_and_batch_on_the_resolved_device(loss, monkeypatch):
    dev = device.resolve("auto")
    cfg = retrieval.CoarseTrainConfig(loss=loss, epochs=2, batch_size=3, eval_every=1, hard_negatives=0.5)
    seen: list[tuple[str, torch.device]] = []

    def record(module, args):
        seen.extend(("batch", t.device) for t in args)
        seen.extend(("parameter", p.device) for p in module.parameters())

    for fn in ("sim_loss", "triplet_loss"):
        original = getattr(coarse_training, fn)

        def wrapped(*args, _original=original, **kw):
            seen.extend(("loss", t.device) for t in args if isinstance(t, torch.Tensor))
            return _original(*args, **kw)

        monkeypatch.setattr(coarse_training, fn, wrapped)
    monkeypatch.setattr(retrieval.CoarseGAT, "__call__", _hooked(retrieval.CoarseGAT.__call__, record))
    ds = _coarse_dataset()
    res = coarse_training.train(ds, cfg, device="auto")
    assert {k for k, _ in seen} == {"batch", "parameter", "loss"}
    assert {d for _, d in seen} == {dev}
    assert {p.device for p in res["model"].parameters()} == {dev}
    assert {t.device.type for t in res["state_dict"].values()} == {"cpu"}
    assert {g.x.device for s in ds.samples for g in s.graphs.values()} == {torch.device("cpu")}  # the caller's stay


@pytest.mark.parametrize("loss", ["sim", "trip", "simtrip"])
def test_a_coarse_step_runs_wholly_on_a_device_without_touching_the_host(loss):
    """The step of a GPU run, on ``meta``: the embedding, the scores, the hard negatives' ranking
    and the losses run there with the moved dataset; a CPU tensor anywhere in it would stop it."""
    cfg = retrieval.CoarseTrainConfig(loss=loss, hard_negatives=0.5)
    torch.manual_seed(0)
    model = retrieval.build_model(cfg).to(META)
    ds = retrieval.to_device(_coarse_dataset(), META)
    batch = [s for s in ds.samples if s.scene == 1][:4]
    total, parts = coarse_training.batch_loss(
        model, ds, batch, ["gt", "depth", "gt", "depth"], cfg, np.random.default_rng(0)
    )
    total.backward()
    assert total.device == META and {v.device for v in parts.values()} == {META}
    assert {p.grad.device for p in model.parameters() if p.grad is not None} == {META}


@pytest.mark.parametrize("fraction", [0.0, 0.5, 1.0])
def test_hard_negatives_ranked_on_the_device_are_the_host_ranking_s(fraction):
    """device_triplet_pairs (scores left on the device, a GPU's path, run here on the CPU) =
    draw_triplets (scores on the host, the CPU's path): the same pairs in the same order from the
    same draws, over ties, unequal scenes and short pools."""
    ds = _coarse_dataset(n_queries=12, seed=5)
    rng_data = np.random.default_rng(1)
    for trial in range(25):
        batch = [ds.samples[i] for i in rng_data.choice(len(ds.samples), int(rng_data.integers(1, 9)), replace=False)]
        if trial % 5 == 0:  # a query with more positives than negatives: draws with replacement
            s = batch[0]
            n = len(ds.refs[s.scene])
            batch[0] = retrieval.Sample(
                s.scene, s.token, s.split, s.graphs, np.arange(n - 2), n - 2, s.cam_xy, s.S, np.array([n - 2, n - 1])
            )
        sizes = [len(ds.refs[s.scene]) for s in batch]
        scores = rng_data.integers(0, 4, sum(sizes)).astype(np.float32)  # many ties
        seed = int(rng_data.integers(1 << 30))
        rng_host, rng_dev = np.random.default_rng(seed), np.random.default_rng(seed)
        want = coarse_training.draw_triplets(batch, sizes, rng_host, scores if fraction else None, fraction)
        got = coarse_training.device_triplet_pairs(
            batch, sizes, rng_dev, torch.device("cpu"), torch.from_numpy(scores) if fraction else None, fraction
        )
        assert [g.tolist() for g in got] == [w.tolist() for w in want], trial
        assert rng_host.random() == rng_dev.random()  # the generator advanced alike
    # the training's call: the host's drawing where the scores are on the CPU, the device's elsewhere
    on_cpu = coarse_training.triplet_pairs(batch, sizes, np.random.default_rng(3), "cpu", torch.from_numpy(scores), 1.0)
    want = coarse_training.draw_triplets(batch, sizes, np.random.default_rng(3), scores, 1.0)
    assert [t.tolist() for t in on_cpu] == [w.tolist() for w in want]
    on_meta = coarse_training.triplet_pairs(batch, sizes, rng_dev, META, torch.from_numpy(scores).to(META), 1.0)
    assert {t.device for t in on_meta} == {META}


# ----------------------------------------------------------------------------- the GPU benchmark

#: what a GPU image lacks: every package the workflow uses but torch, torch-geometric, numpy, pandas
NOT_ON_A_GPU_IMAGE = [
    "snakemake",
    "pycolmap",
    "open3d",
    "kornia",
    "pyproj",
    "yaml",
    "jsonschema",
    "pyarrow",
    "fastparquet",
    "scipy",
    "numba",
    "sklearn",
    "cv2",
    "transformers",
    "matplotlib",
    "PIL",
]

#: runs a script with those packages shadowed by ones whose import fails
BARE_RUNNER = """
import pathlib, runpy, sys
stubs = pathlib.Path(sys.argv[1])
for name in {names!r}:
    (stubs / name).mkdir(parents=True, exist_ok=True)
    (stubs / name / "__init__.py").write_text(f"raise ImportError('{{name}} is not installed here')")
sys.path.insert(0, str(stubs))
sys.argv = sys.argv[2:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def _tiny_results(folder):
    """The tiny committed scene's reference map, queries and coarse target, as rules write them."""
    from conftest import TINY_SCENE
    from tiny_results import tiny_scene

    from flatlandia.coarse import target
    from flatlandia.plumbing import files

    tiny = tiny_scene()
    ref, q = tiny.ref, tiny.queries
    for name, table in (
        ("maps/reference_map", ref),
        ("queries/queries", q),
        ("coarse/target", target.scene_similarity(ref, q)),
    ):
        (folder / TINY_SCENE / name).parent.mkdir(parents=True, exist_ok=True)
        files.write_parquet(table, folder / TINY_SCENE / f"{name}.parquet")


@pytest.mark.slow  # trains on the CPU in three processes: about 45 s
def test_the_gpu_benchmark_runs_where_only_torch_torch_geometric_numpy_and_pandas_are(repo, tmp_path):
    """bench_paper_config.py packs its inputs here, then runs from the pack with the workflow's other
    packages unimportable (a bare GPU image), on the CPU here: the losses of the CPU reference
    workers equal the run's, and a cuda it cannot have is one ERROR line."""
    import subprocess
    import sys

    bench = repo / "benchmarks" / "bench_paper_config.py"
    env = {"PYTHONPATH": str(repo / "workflow"), "PATH": "/usr/bin:/bin"}
    _tiny_results(tmp_path / "results")
    packed = tmp_path / "inputs.json.gz"
    run = subprocess.run(
        [sys.executable, bench, "--results", tmp_path / "results", "--pack", packed],
        capture_output=True,
        text=True,
        env=env,
    )
    assert run.returncode == 0 and packed.exists(), run.stderr[-2000:]
    runner = tmp_path / "bare.py"
    runner.write_text(BARE_RUNNER.format(names=NOT_ON_A_GPU_IMAGE))
    args = [sys.executable, runner, tmp_path / "stubs", bench, "--inputs", packed, "--epochs", "2"]
    jobs = ["--only", "coarse_simtrip", "fine_gat_att_depth_coarse", "--out", tmp_path / "table.csv"]
    run = subprocess.run([*args, *jobs, "--compare-cpu"], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    assert "largest relative difference 0.00e+00, within the tolerance" in run.stdout
    table = pd.read_csv(tmp_path / "table.csv")
    assert table["job"].tolist() == ["simtrip", "gat_att_depth_coarse"] and (table["loss_rel_diff"] == 0).all()
    assert (table["s_per_epoch"] > 0).all() and table["epochs"].tolist() == [800, 1000]  # the paper's lengths
    if not HAS_CUDA:
        run = subprocess.run([*args, *jobs, "--device", "cuda"], capture_output=True, text=True, env=env)
        assert run.returncode == 2 and run.stderr.strip().startswith("ERROR: config: 'device': cuda asked for")
        assert len(run.stderr.strip().splitlines()) == 1


# ----------------------------------------------------------------------------- learned image backends


def test_the_learned_image_backends_run_their_model_and_inputs_on_the_resolved_device(tmp_path):
    """Mask2Former (segment) and Depth-Anything (depth), tiny and random, with device auto: the model
    and every image's tensors on the resolved device, the label and depth maps back as arrays."""
    from PIL import Image
    from test_learned_backends import VISTAS_V12, save_depth_anything, save_mask2former

    from flatlandia.images import depth, segment

    dev = device.resolve("auto")
    photo = tmp_path / "photo.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(photo)
    seen = []

    def record(module, args, kwargs):
        seen.extend(t.device for t in (*args, *kwargs.values()) if isinstance(t, torch.Tensor))

    seg = segment.make_backend(
        "transformers", weights=str(save_mask2former(tmp_path / "m2f", VISTAS_V12)), device="auto"
    )
    seg.model.register_forward_pre_hook(record, with_kwargs=True)
    ids, _ = seg.labels(photo)
    assert ids.shape == (48, 64) and ids.dtype == np.int32
    mono = depth.MonocularDepth(str(save_depth_anything(tmp_path / "da")), device="auto")
    mono.model.register_forward_pre_hook(record, with_kwargs=True)
    pred = mono.predict(photo, (48, 64))
    assert pred.shape == (48, 64) and pred.dtype == np.float64
    assert len(seen) >= 2 and set(seen) == {dev}
    assert {p.device for m in (seg.model, mono.model) for p in m.parameters()} == {dev}
