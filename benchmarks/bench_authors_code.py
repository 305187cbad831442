"""The authors' fine-localization baselines, run by their own code on the workflow's export in their
form (rule export_original, results/export/original/), and their predictions scored as the built-in
methods are (`flatlandia score`).

The authors' repository (IIT-PAVIS/Flatlandia) ships the training script of its four fine models,
scripts/demo_fine_localization.py, but not the data/flatlandia.json and data/region_proposal.json it
reads; `snakemake --cores 2 export` regenerates both (docs/usage.md, "The benchmark in the authors'
form"). This script runs their script unchanged on them, in a virtual environment of its own, and
turns their test predictions into a poses file of the scene frames:

    git clone <the authors' repository> /tmp/authors           # a clone with a work tree
    python benchmarks/bench_authors_code.py --authors-repo /tmp/authors --model MLP --map-type GT --epochs 2
    python benchmarks/bench_authors_code.py --authors-repo /tmp/authors --model MLP GAT+MLP MLP+ATT+MLP GAT+ATT+MLP --epochs 1 --fix-gat
    python benchmarks/bench_authors_code.py --authors-repo /tmp/authors --rp mix_2nq --map-type depth   # a coarse proposal

Nothing of their code is copied into this repository, and their files are never changed: the
script runs theirs with ``runpy`` in a child process of their environment (``--venv``, built on first
use: torch 2.13.0 from this machine's wheel when there is one, dgl 1.1.3, setuptools<70 for dgl's
pkg_resources, wandb with WANDB_MODE=disabled, mapillary, requests, pillow, packaging, which their
imports need), one thread (OMP_NUM_THREADS=1), with these run-time patches:

1. *Their package name*: scripts/utils/dataloader.py imports ``Flatlandia.scripts.utils.common``,
   which resolves only where the clone's folder is named ``Flatlandia`` and its parent is on the
   path; a module ``Flatlandia`` whose path is the clone stands in for it.
2. *Where the data is*: scripts/utils/common.py points at the clone's data/ and models/; the loader's
   three paths point at the export and the models go to the run folder instead (the clone is never written).
3. *``os`` is not imported* by the demo, which calls ``os.makedirs``: it runs with ``os`` in its globals.
4. *The best model's file*: the demo saves ``model_best`` but loads ``model_best.pth`` (after the
   last epoch, FileNotFoundError); ``torch.load`` of a missing ``.pth`` loads the file without it.
   (The names carry a backslash, ``save_path + '\\model_best'``: on Linux the files land beside the
   run's folder, named ``<run>\\model_best``: left as is.)
5. *Validation and test crash without augmentation*: the local map reaches ``nodes_to_graph`` as the
   JSON list, and ``xy[j] - xy[i]`` subtracts lists (TypeError); the patch makes it an array first
   (the augmented training path already passes one).
6. *Both JSON files re-read per sample*: ``get_region_proposal`` and ``assemble_graphs`` parse
   region_proposal.json and local_maps.json for every query of every epoch (36 ms a query here, a
   minute more per MLP epoch of 4 s); ``json.load`` of the loader caches each file's parse (their
   code never changes the values).
7. *Coarse proposals on the training queries* (only with a coarse ``--rp``): their script reads the
   chosen proposal for every split, the workflow's coarse stage makes them for the test split only;
   a training or validation query without one gets its ``CoarseBB`` box (the workflow's own training
   regime for coarse runs); a test query without one stops the run.
8. *The GAT models' inputs* (opt-in, ``--fix-gat``; without it GAT+MLP and GAT+ATT+MLP stop at their
   first query): ``solve_regression`` builds both graphs from ``r_xor_q`` (intra-map edges) and
   passes the edge features of ``r_and_q`` (inter-map edges only), while the GAT forward reads the
   first graph's edge count of intra-map features, then the inter-map ones for its second graph:
   the sizes differ and dgl's EGATConv raises. The patch gives the forward the ``r_xor_q`` graph, the
   ``r_and_q`` graph and the ``r_or_q`` edge features (intra, then inter: the layout it slices),
   from the graphs ``assemble_graphs`` made for that query. It is our reading of what their code
   meant, not their code: rows of patched runs say so (``fix_gat`` in runs.json).

Their predictions are recorded by a forward hook of the model during the final test pass (after
``model_best`` is loaded), per test query: x, y in their frame (units of ``tf / 2`` degrees around
the map's centre) and theta (radians, counter-clockwise from +x of that frame), with the time from
reading the query to its pose. They are turned into the scene's metric frame with the centre and
frame the export records (``flatlandia.data.original.scene_pose``), written as
``OUT/poses.csv`` and scored with ``flatlandia score`` against ``--results`` (a finished run; the
export must be of that run; a coarse key is scored as the workflow's proposal of its source, e.g.
``mix_2nq`` as ``coarse-simtrip``, whose proposal sizes and F% follow the run's config
``fine.coarse_strategy``). The table (printed, and ``OUT/table.md``) has per run the seconds
per epoch (training and validation passes apart, from the lines their script prints), the test
pass, and the scores (true metres and degrees; ``median pu``: their unit errors x 215, the paper's
"metres").
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: their script's choices of model (--model_type)
MODELS = ("MLP", "GAT+MLP", "MLP+ATT+MLP", "GAT+ATT+MLP")
GAT_MODELS = ("GAT+MLP", "GAT+ATT+MLP")
MAP_TYPES = {"GT": "gt", "depth": "depth"}
#: their proposal key -> the workflow's proposal slug (flatlandia score's `proposal`)
PROPOSAL_OF_KEY = {"CoarseBB": "gtbb", "simil": "coarse-sim", "triplet": "coarse-trip", "mix": "coarse-simtrip"}
DEMO = "scripts/demo_fine_localization.py"
TORCH = "torch==2.13.0"
TORCH_WHEELS = Path("/opt/wheels")
#: the environment of their code, beside torch (installed without its dependencies: torch 2.13 asks
#: for setuptools>=77, dgl 1.1.3's pkg_resources for an older one)
PACKAGES = [
    "dgl==1.1.3",
    "setuptools<70",
    "packaging",
    "filelock",
    "typing-extensions>=4.10.0",
    "sympy>=1.13.3",
    "networkx>=2.5.1",
    "jinja2",
    "fsspec>=0.8.5",
    "wandb",
    "mapillary",
    "requests",
    "pillow",
]
THREADS_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


# ----------------------------------------------------------------------------- inside their environment
def run_inner(cfg: dict) -> None:
    """Their demo script under the patches of the module's docstring; writes predictions.json and
    timings.json into the current folder. Runs in their environment: standard library, numpy,
    torch and their code only."""
    import builtins
    import runpy
    import types

    repo = Path(cfg["repo"]).resolve()
    data = Path(cfg["export"]).resolve() / "data"
    out = Path.cwd()
    sys.path.insert(0, str(repo))
    package = types.ModuleType("Flatlandia")  # patch 1
    package.__path__ = [str(repo)]
    sys.modules["Flatlandia"] = package

    import numpy as np
    import torch

    torch.set_num_threads(int(cfg["threads"]))
    from scripts.utils import common, dataloader, models

    dataloader.dataset_path = str(data / "flatlandia.json")  # patch 2
    dataloader.local_maps_path = str(data / "local_maps.json")
    dataloader.region_proposals_path = str(data / "region_proposal.json")
    common.out_path = str(out / "models") + "/"

    torch_load = torch.load

    def load_best(f, *args, **kwargs):  # patch 4
        if isinstance(f, str) and f.endswith(".pth") and not os.path.exists(f) and os.path.exists(f[:-4]):
            f = f[:-4]
        return torch_load(f, *args, **kwargs)

    torch.load = load_best

    nodes_to_graph = dataloader.nodes_to_graph

    def nodes_to_graph_array(xy, classes, knn):  # patch 5
        return nodes_to_graph(np.asarray(xy, dtype=float), classes, knn)

    dataloader.nodes_to_graph = nodes_to_graph_array

    parsed: dict[str, object] = {}

    def load_once(f, *args, **kwargs):  # patch 6
        key = os.path.realpath(f.name)
        if key not in parsed:
            parsed[key] = json.load(f, *args, **kwargs)
        return parsed[key]

    dataloader.json = types.SimpleNamespace(load=load_once)

    state: dict = {"mode": None, "token": None, "t0": 0.0}
    predictions: list[dict] = []
    fallback: set[str] = set()
    loader = dataloader.FlatlandiaLoader
    loader_init, loader_item, loader_rp = loader.__init__, loader.__getitem__, loader.get_region_proposal

    def init(self, data_mode="training", data_subset=False):
        loader_init(self, data_mode, data_subset)
        self.bench_mode = data_mode

    def item(self, idx):
        state.update(mode=self.bench_mode, token=self.tokens[idx], t0=time.perf_counter())
        return loader_item(self, idx)

    def region(self, token, mode="GT", select="CoarseBB"):  # patch 7
        try:
            return loader_rp(self, token, mode, select)
        except KeyError:
            if select == "CoarseBB" or self.bench_mode == "testing":
                raise
            fallback.add(token)
            return loader_rp(self, token, mode, "CoarseBB")

    loader.__init__, loader.__getitem__, loader.get_region_proposal = init, item, region

    if cfg["fix_gat"]:  # patch 8 (opt-in): the graphs of the last query, for the GAT models' inputs
        assemble_graphs = dataloader.assemble_graphs

        def assemble_recorded(*args, **kwargs):
            state["graphs"] = assemble_graphs(*args, **kwargs)
            return state["graphs"]

        dataloader.assemble_graphs = assemble_recorded

    select_module = models.select_module

    def select(mode, *args, **kwargs):  # the predictions: a forward hook on the test pass
        model = select_module(mode, *args, **kwargs)
        if cfg["fix_gat"] and mode in GAT_MODELS:
            model.forward = gat_inputs(model, model.forward, state)

        def hook(module, inputs, output):
            if state["mode"] == "testing":
                pose = output[2].detach().cpu().numpy().reshape(-1)
                predictions.append(
                    {
                        "token": state["token"],
                        "x": float(pose[0]),
                        "y": float(pose[1]),
                        "theta_rad": float(pose[2]),
                        "seconds": time.perf_counter() - state["t0"],
                    }
                )

        model.register_forward_hook(hook)
        return model

    models.select_module = select

    lines: list[tuple[float, str]] = []

    def timed_print(*args, **kwargs):
        lines.append((time.perf_counter(), " ".join(str(a) for a in args)))
        builtins.print(*args, **kwargs, flush=True)

    sys.argv = [DEMO, *cfg["argv"]]
    start = time.perf_counter()
    runpy.run_path(str(repo / DEMO), init_globals={"os": os, "print": timed_print}, run_name="__main__")  # patch 3
    (out / "predictions.json").write_text(json.dumps(predictions))
    timings = {
        "lines": [(t - start, text) for t, text in lines],
        "wall_s": time.perf_counter() - start,
        "fallback_tokens": len(fallback),
    }
    (out / "timings.json").write_text(json.dumps(timings))


def gat_inputs(model, forward, state: dict):
    """Patch 8: the GAT models' forward given what it reads (module docstring): the intra-map graph,
    the inter-map graph, the intra-map edges' features then the inter-map ones, from the graphs
    assemble_graphs made for this query."""
    import dgl
    import torch

    def forward_fixed(g_all, node_data, edge_data, n_r):
        p, n = state["graphs"], int(node_data.shape[0])
        intra, cross = p["r_xor_q"]["idx"].T, p["r_and_q"]["idx"].T
        graphs = [dgl.graph((g[0], g[1]), num_nodes=n).to(model.device) for g in (intra, cross)]
        edges = torch.from_numpy(p["r_or_q"]["e_e"]).to(model.device).type(torch.float32)
        return forward(graphs, node_data, edges, n_r)

    return forward_fixed


# ----------------------------------------------------------------------------- their environment
def torch_requirement() -> str:
    """torch 2.13.0: this machine's CPU wheel when there is one, else the index's."""
    wheels = sorted(TORCH_WHEELS.glob("torch-2.13.0*-cp3*.whl")) if TORCH_WHEELS.is_dir() else []
    tag = f"cp{sys.version_info.major}{sys.version_info.minor}"
    wheels = [w for w in wheels if f"-{tag}-" in w.name]
    return str(wheels[0]) if wheels else TORCH


def ensure_venv(venv: Path) -> Path:
    """Their environment at ``venv`` (built when it has no marker of a finished build): its python."""
    python = venv / "bin" / "python"
    marker = venv / "flatlandia-authors-env.json"
    if python.exists() and marker.exists():
        return python
    log = venv.parent / f"{venv.name}-build.log"
    print(f"building their environment in {venv} (once; pip's output: {log}) ...", flush=True)
    venv.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", "--clear", str(venv)], check=True)
    pip = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    torch = torch_requirement()
    with open(log, "w") as f:
        for step in (PACKAGES, ["--no-deps", torch]):
            if subprocess.run([*pip, *step], stdout=f, stderr=subprocess.STDOUT).returncode != 0:
                raise RuntimeError(f"pip install {' '.join(step)} failed: see {log}")
    check = "import dgl, torch, wandb, mapillary.interface, PIL, requests; print(torch.__version__, dgl.__version__)"
    versions = subprocess.run([str(python), "-c", check], check=True, capture_output=True, text=True).stdout.strip()
    marker.write_text(json.dumps({"torch": torch, "packages": PACKAGES, "versions": versions}) + "\n")
    return python


# ----------------------------------------------------------------------------- one run, its poses, the table
def proposal_slug(key: str) -> str:
    """The workflow's proposal of their key: ``CoarseBB`` -> gtbb, ``mix_2nq`` -> coarse-simtrip."""
    return PROPOSAL_OF_KEY[key.split("_", 1)[0] if key != "CoarseBB" else key]


def run_name(model: str) -> str:
    """flatlandia score's --name of a model: ``GAT+ATT+MLP`` -> authors_gat_att_mlp."""
    return "authors_" + model.lower().replace("+", "_")


def run_theirs(python: Path, args, model: str, map_type: str, folder: Path) -> dict:
    """Their script for one model and map type in ``folder``; returns timings.json with the log's path."""
    folder.mkdir(parents=True, exist_ok=True)
    cfg = {
        "repo": str(args.authors_repo),
        "export": str(args.export),
        "threads": args.threads,
        "fix_gat": args.fix_gat,
        "argv": [
            "--epochs",
            str(args.epochs),
            "--model_type",
            model,
            "--data_type",
            map_type,
            "--rp",
            args.rp,
            "--seed",
            str(args.seed),
            "--experiment_name",
            "bench",
            *args.extra,
        ],
    }
    env = {**os.environ, "WANDB_MODE": "disabled", "WANDB_SILENT": "true", "PYTHONUNBUFFERED": "1"}
    env.update(dict.fromkeys(THREADS_ENV, str(args.threads)))
    env.pop("PYTHONPATH", None)
    log = folder / "their_script.log"
    print(f"{model} on {map_type} maps, {args.rp}, {args.epochs} epoch(s): {log}", flush=True)
    with open(log, "w") as f:
        res = subprocess.run(
            [str(python), str(Path(__file__).resolve()), "--inner", json.dumps(cfg)],
            cwd=folder,
            env=env,
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    if res.returncode != 0:
        tail = log.read_text()[-3000:]
        hint = (
            " (their GAT models crash on their own inputs: --fix-gat)"
            if model in GAT_MODELS and not args.fix_gat
            else ""
        )
        raise RuntimeError(f"their script failed ({model}, {map_type}), exit {res.returncode}{hint}: ...\n{tail}")
    timings = json.loads((folder / "timings.json").read_text())
    return {**timings, "log": str(log)}


def epoch_seconds(lines: list[tuple[float, str]]) -> dict:
    """Seconds of each epoch's training and validation passes and of the test pass, from the lines
    their script prints ('Epoch k', then a '(n/N)::' line after each pass; 'Evaluating ...' before
    the test pass), and the test pass's line (their mean errors: units, radians)."""
    train, val, test, test_line = [], [], float("nan"), ""
    phase, mark = None, 0.0
    for t, text in lines:
        if text.startswith("Epoch "):
            phase, mark = "train", t
        elif text.startswith("Evaluating"):
            phase, mark = "test", t
        elif text.startswith("(") and "::" in text:
            if phase == "train":
                train.append(t - mark)
                phase = "val"
            elif phase == "val":
                val.append(t - mark)
                phase = None
            elif phase == "test":
                test, test_line, phase = t - mark, text, None
            mark = t
    return {"train_s": train, "val_s": val, "test_s": test, "test_line": test_line}


def poses_table(predictions: list[dict], data: dict, map_type: str, rp: str):
    """Their test predictions as a poses file of the scene frames (flatlandia score's columns)."""
    import numpy as np
    import pandas as pd

    from flatlandia import geo
    from flatlandia.data import original

    to_scene = data["miscellanea"]["split"]["img_to_scene"]
    notes = data["miscellanea"]["flatlandia_workflow"]["maps"]
    pred = pd.DataFrame(predictions, columns=["token", "x", "y", "theta_rad", "seconds"])
    pred = pred[np.isfinite(pred[["x", "y", "theta_rad"]]).all(axis=1)]
    pred = pred.assign(scene=[str(to_scene[t]) for t in pred["token"]])
    parts = []
    for scene, p in pred.groupby("scene", sort=False):
        m = notes[scene]
        x, y, theta = original.scene_pose(
            p[["x", "y"]].to_numpy(),
            np.degrees(p["theta_rad"].to_numpy()),
            m["centre_lonlat"],
            geo.MetricFrame(m["lon0"], m["lat0"]),
        )
        parts.append(
            pd.DataFrame(
                {
                    "scene": scene,
                    "token": p["token"].astype(str).to_numpy(),
                    "x_m": x,
                    "y_m": y,
                    "theta_deg": theta,
                    "map_type": MAP_TYPES[map_type],
                    "proposal": proposal_slug(rp),
                    "seconds": p["seconds"].to_numpy(),
                }
            )
        )
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def mean_unit_error(predictions: list[dict], data: dict) -> float:
    """The mean position error of the recorded predictions in their frame (units), against the
    export's cameras: what their test line prints as distance_error (a check that the hook recorded
    each pose under its query)."""
    import math

    to_scene = data["miscellanea"]["split"]["img_to_scene"]
    errs = []
    for p in predictions:
        gx, gy = data["maps"][str(to_scene[p["token"]])]["queries"][p["token"]]["xy"]
        errs.append(math.hypot(p["x"] - gx, p["y"] - gy))
    return sum(errs) / len(errs) if errs else float("nan")


def score(poses: Path, name: str, out: Path, results: Path) -> dict:
    """``flatlandia score`` of a poses file; its one summary."""
    cli = Path(sys.executable).parent / "flatlandia"
    cmd = [str(cli) if cli.exists() else "flatlandia", "score", str(poses), "--name", name, "--out", str(out)]
    res = subprocess.run([*cmd, "--results", str(results)], capture_output=True, text=True)
    print(res.stdout.strip() or res.stderr.strip(), flush=True)
    if res.returncode != 0:
        raise RuntimeError(f"flatlandia score failed: {res.stderr.strip()[-2000:]}")
    summary = sorted(out.glob(f"{name}_*/summary.json"))
    return json.loads(summary[0].read_text()) if summary else {}


def table_markdown(rows: list[dict]) -> str:
    """The runs as a Markdown table."""
    cols = [
        ("model", "model"),
        ("map", "map_type"),
        ("proposal", "rp"),
        ("epochs", "epochs"),
        ("train s/epoch", "train_s"),
        ("val s/epoch", "val_s"),
        ("test s", "test_s"),
        ("test queries", "queries"),
        ("median m", "median_m"),
        ("median °", "median_deg"),
        ("0.5 m & 2°", "pct_0.5m_2deg"),
        ("1 m & 5°", "pct_1m_5deg"),
        ("5 m & 10°", "pct_5m_10deg"),
        ("10 m & 20°", "pct_10m_20deg"),
        ("median pu", "median_pu"),
    ]

    def cell(v):
        if isinstance(v, float):
            return "" if v != v else f"{v:.2f}" if abs(v) < 100 else f"{v:.0f}"
        return str(v)

    lines = ["| " + " | ".join(c for c, _ in cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(cell(r.get(k, "")) for _, k in cols) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--authors-repo", type=Path, required=True, help="a clone of the authors' repository (a work tree)")
    ap.add_argument("--export", type=Path, default=REPO / "results/export/original", help="the export in their form")
    ap.add_argument(
        "--results", type=Path, default=REPO / "results", help="the finished run the export is of (scoring)"
    )
    ap.add_argument(
        "--venv", type=Path, default=Path.home() / ".cache/flatlandia/authors-venv", help="their environment"
    )
    ap.add_argument("--out", type=Path, default=None, help="where the runs go (default: a new temporary folder)")
    ap.add_argument("--model", nargs="+", choices=MODELS, default=["MLP"])
    ap.add_argument("--map-type", nargs="+", choices=list(MAP_TYPES), default=["GT"])
    ap.add_argument("--rp", default="CoarseBB", help="their region proposal key (CoarseBB, simil_2nq, mix_nq, ...)")
    ap.add_argument("--epochs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=2, help="their script's seed (theirs by default)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-score", action="store_true", help="time their script only")
    ap.add_argument(
        "--fix-gat", action="store_true", help="patch 8: give the GAT models the inputs their forward reads (see above)"
    )
    ap.add_argument("extra", nargs="*", help="after --: more arguments for their script (e.g. -- --lr 3)")
    args = ap.parse_args(argv)

    from flatlandia.data import original  # reads the export as their loader would, and checks it

    if not (args.authors_repo / DEMO).is_file():
        ap.error(f"--authors-repo {args.authors_repo}: no {DEMO} there (a clone with a work tree)")
    args.authors_repo = args.authors_repo.resolve()
    args.export = args.export.resolve()
    data = original.read(args.export)["flatlandia"]
    out = args.out or Path(tempfile.mkdtemp(prefix="authors_code_"))
    out.mkdir(parents=True, exist_ok=True)
    python = ensure_venv(args.venv)
    rows = []
    for model in args.model:
        for map_type in args.map_type:
            folder = out / f"{run_name(model)}_{MAP_TYPES[map_type]}_{args.rp}_e{args.epochs}"
            timings = run_theirs(python, args, model, map_type, folder)
            secs = epoch_seconds(timings["lines"])
            predictions = json.loads((folder / "predictions.json").read_text())
            poses = poses_table(predictions, data, map_type, args.rp)
            poses.to_csv(folder / "poses.csv", index=False)
            scores = {}
            if not args.no_score:
                if folder.joinpath("scores").exists():
                    shutil.rmtree(folder / "scores")
                scores = score(folder / "poses.csv", run_name(model), folder / "scores", args.results)
            units = mean_unit_error(predictions, data)
            print(
                f"  their test pass: {secs['test_line']}; recorded: {len(poses)} test poses, mean distance "
                f"error {units:.3f} units",
                flush=True,
            )
            rows.append(
                {
                    **scores,  # flatlandia score's summary (its own train_s, epochs are 0: not ours)
                    "model": model,
                    "map_type": map_type,
                    "rp": args.rp,
                    "epochs": args.epochs,
                    "train_s": sum(secs["train_s"]) / max(len(secs["train_s"]), 1),
                    "val_s": sum(secs["val_s"]) / max(len(secs["val_s"]), 1),
                    "test_s": secs["test_s"],
                    "their_test_line": secs["test_line"],
                    "fallback_tokens": timings["fallback_tokens"],
                    "predicted": len(poses),
                    "mean_units": units,
                    "wall_s": timings["wall_s"],
                    "fix_gat": bool(args.fix_gat and model in GAT_MODELS),
                }
            )
    text = table_markdown(rows)
    (out / "table.md").write_text(text)
    (out / "runs.json").write_text(json.dumps(rows, indent=1, default=str) + "\n")
    print("\n" + text + f"\nwritten: {out}/table.md, runs.json and per run poses.csv, their_script.log", flush=True)
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--inner":
        run_inner(json.loads(sys.argv[2]))
    else:
        sys.exit(main())
