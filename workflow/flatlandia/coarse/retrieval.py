"""Coarse map localization: the retrieval model (the paper's Table 3; its figures in
:mod:`flatlandia.paper`).

A graph attention network (GATv2 layers with the ``exp(-d)`` edge feature) embeds the query
graph and the scene's reference graph with shared weights; a reference node ``i`` scores
``s_i = || psi_i - mean_j psi_j(query) ||`` (smaller = more similar). With all of a batch's
queries from one scene, the scene's reference graph and the query graphs go through the encoder
as one disjoint union (:func:`fused_scores`). Graphs and targets of every query:
:func:`build_dataset`. Training: :mod:`flatlandia.coarse.training`; proposals and metrics:
:mod:`flatlandia.coarse.evaluation`.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch
from torch import nn

from flatlandia import config, vocabulary
from flatlandia.classes import N_CLASSES
from flatlandia.coarse import graphs
from flatlandia.plumbing.pyg import Batch, GATConv, GATv2Conv, add_self_loops, global_mean_pool

LOSSES = vocabulary.COARSE_LOSSES
MAP_TYPES = ["gt", "depth"]


@config.settings("coarse.train")
class CoarseTrainConfig:
    """How one coarse retrieval model is trained: the config section ``coarse.train`` (each key is
    described in config/README.md, ``coarse.train.*``), plus what the rule fixes per model: the
    loss (its wildcard) and the seed (``seed`` + ``coarse.seed_offset``). Stored in the checkpoint
    (``to_dict``) and read back with ``from_dict``. ``scale_m``, ``depth_unit_m`` and ``knn`` are
    the graphs' normalisation (:meth:`graph_config`)."""

    loss: str = "simtrip"  # sim | trip | simtrip
    seed: int = 0

    def __post_init__(self):
        if self.loss not in LOSSES:
            raise ValueError(f"coarse loss must be one of {list(LOSSES)}, got {self.loss!r}")
        if self.lr_schedule not in ("constant", "cosine"):
            raise ValueError(f"lr_schedule must be 'constant' or 'cosine', got {self.lr_schedule!r}")
        if self.batching not in ("scene", "mixed"):
            raise ValueError(f"batching must be 'scene' or 'mixed', got {self.batching!r}")
        bad = [m for m in self.train_maps if m not in MAP_TYPES]
        if bad or not self.train_maps:
            raise ValueError(f"train_maps must be a non-empty subset of {MAP_TYPES}, got {self.train_maps}")

    def graph_config(self) -> graphs.GraphConfig:
        return graphs.GraphConfig(
            scale_m=self.scale_m,
            depth_unit_m=float(self.depth_unit_m if self.depth_unit_m is not None else graphs.DEPTH_UNIT_M),
            knn=self.knn,
        )


# ----------------------------------------------------------------------------- data


@dataclass
class Sample:
    scene: int  # position in the scene list
    token: str
    split: str
    graphs: dict  # map type -> query graph (Data)
    positives: np.ndarray  # rows of the reference table matched by the query (unique)
    n_objects: int
    cam_xy: np.ndarray  # true camera (metres), for the GT-BB oracle only
    S: np.ndarray | None = None  # similarity target per reference row
    negatives: np.ndarray | None = None  # rows not matched by the query (triplet negatives)
    S_t: torch.Tensor | None = None  # S on the training device (:func:`to_device`)


@dataclass
class Dataset:
    scene_ids: list  # scene id per position
    refs: list  # reference tables (rows in obj_idx order as read)
    ref_graphs: list  # reference graph per scene
    ref_batch: Batch  # every scene's reference graph, batched
    offsets: np.ndarray  # first node of each scene in ref_batch
    samples: list

    def split(self, name: str) -> list:
        return [s for s in self.samples if s.split == name]


def build_dataset(
    scenes: list[tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame | None]],
    cfg: CoarseTrainConfig,
    splits: tuple[str, ...] = ("train", "val", "test"),
) -> Dataset:
    """Graphs and targets from (reference map, queries, similarity table or None) per scene.

    With ``cfg.depth_unit_m`` unset, it is resolved here (and written into ``cfg``, so the saved
    config holds it) as the median object range of the training queries' GT maps.
    """
    if cfg.depth_unit_m is None:
        train_q = pd.concat([q[q["split"] == "train"] for _, q, _ in scenes])
        if not len(train_q):
            raise ValueError("depth_unit_m is unset and there are no training queries to fit it on")
        cfg.depth_unit_m = round(graphs.median_range_m(train_q), 3)
    gcfg = cfg.graph_config()
    refs, ref_graphs, scene_ids, samples = [], [], [], []
    for k, (ref, queries, sim) in enumerate(scenes):
        ref = ref.reset_index(drop=True)
        refs.append(ref)
        scene_ids.append(str(ref["scene"].iloc[0]))
        ref_graphs.append(graphs.reference_graph(ref, gcfg))
        row_of = {int(o): i for i, o in enumerate(ref["obj_idx"].to_numpy())}
        S_by_token = {}
        if sim is not None and len(sim):
            piv = sim.pivot(index="token", columns="obj_idx", values="S")
            piv = piv.reindex(columns=ref["obj_idx"].to_numpy())
            S_by_token = {str(t): v.to_numpy(np.float32) for t, v in piv.iterrows()}
        for r in queries[queries["split"].isin(splits)].itertuples(index=False):
            row = r._asdict()
            g = {mt: graphs.query_graph(graphs.local_map_metres(row, mt, gcfg), r.classes, gcfg) for mt in MAP_TYPES}
            pos = np.unique([row_of[int(i)] for i in r.ref_idx])
            S = S_by_token.get(str(r.token))
            if S is not None and np.isnan(S).any():
                raise ValueError(f"scene {scene_ids[-1]} query {r.token}: similarity table misses objects")
            samples.append(
                Sample(
                    k,
                    str(r.token),
                    str(r.split),
                    g,
                    pos,
                    int(r.n_objects),
                    np.array([r.x_m, r.y_m], float),
                    S,
                    np.setdiff1d(np.arange(len(ref)), pos),
                )
            )
    sizes = np.array([len(r) for r in refs])
    offsets = np.r_[0, np.cumsum(sizes)[:-1]].astype(np.int64)
    return Dataset(scene_ids, refs, ref_graphs, graphs.batch(ref_graphs), offsets, samples)


def to_device(ds: Dataset, device) -> Dataset:
    """The dataset with every graph (and similarity target, ``Sample.S_t``) on ``device``, moved
    once before the loops (a new dataset: the caller's keeps its tensors where they were)."""
    dev = torch.device(device)

    def move(g):
        return copy.copy(g).to(dev)

    samples = [
        dataclasses.replace(
            s,
            graphs={mt: move(g) for mt, g in s.graphs.items()},
            S_t=None if s.S is None else torch.from_numpy(np.array(s.S, np.float32)).to(dev),
        )
        for s in ds.samples
    ]
    return Dataset(ds.scene_ids, ds.refs, [move(g) for g in ds.ref_graphs], move(ds.ref_batch), ds.offsets, samples)


# ----------------------------------------------------------------------------- model


class CoarseGAT(nn.Module):
    """Shared node encoder: linear lift, ``layers`` GAT layers with edge features, linear head."""

    def __init__(self, cfg: CoarseTrainConfig, in_dim: int = N_CLASSES + 2):
        super().__init__()
        conv = {"gatv2": GATv2Conv, "gat": GATConv}[cfg.conv]
        self.lift = nn.Linear(in_dim, cfg.hidden)
        self.convs = nn.ModuleList(
            [
                conv(
                    cfg.hidden,
                    cfg.hidden,
                    heads=cfg.heads,
                    concat=False,
                    edge_dim=1,
                    dropout=cfg.dropout,
                    add_self_loops=False,
                )
                for _ in range(cfg.layers)
            ]
        )
        self.head = nn.Linear(cfg.hidden, cfg.out_dim)
        self.act = nn.ELU()
        self.normalize = cfg.normalize
        self.fast = cfg.conv == "gatv2"  # gatv2_forward: same layer, fewer ops (see there)

    def forward(self, x, edge_index, edge_attr):
        # self loops once for all layers, edge feature exp(-0) = 1
        edge_index, edge_attr = add_self_loops(edge_index, edge_attr, fill_value=1.0, num_nodes=x.size(0))
        h = self.act(self.lift(x))
        for conv in self.convs:
            out = gatv2_forward(conv, h, edge_index, edge_attr) if self.fast else conv(h, edge_index, edge_attr)
            h = h + self.act(out)  # residual: keeps the class identity
        out = self.head(h)
        return nn.functional.normalize(out, dim=-1) if self.normalize else out


def gatv2_forward(conv: GATv2Conv, x: torch.Tensor, edge_index: torch.Tensor, edge_attr: torch.Tensor) -> torch.Tensor:
    """``conv(x, edge_index, edge_attr)`` of a torch-geometric ``GATv2Conv`` (``concat=False``,
    ``edge_dim=1``, self loops already in ``edge_index``) with its own parameters, in plain torch:
    the one-column edge projection as a broadcast product instead of a matmul and no
    message-passing machinery; faster per training step on small CPU graphs (docs/measurements.md, "Code paths")
    and equal to the layer up to float rounding (tested)."""
    H, C = conv.heads, conv.out_channels
    n = x.shape[0]
    src, dst = edge_index[0], edge_index[1]
    xl = conv.lin_l(x).view(n, H, C)
    xr = conv.lin_r(x).view(n, H, C)
    xj = xl.index_select(0, src)
    z = xj + xr.index_select(0, dst) + edge_attr.view(-1, 1, 1) * conv.lin_edge.weight.view(1, H, C)
    logit = (nn.functional.leaky_relu(z, conv.negative_slope) * conv.att).sum(-1)  # (E, H)
    gmax = logit.new_full((n, H), -torch.inf).scatter_reduce(0, dst[:, None].expand(-1, H), logit, "amax")
    w = torch.exp(logit - gmax.index_select(0, dst))
    den = w.new_zeros(n, H).index_add(0, dst, w)
    alpha = nn.functional.dropout(w / den.index_select(0, dst), p=conv.dropout, training=conv.training)
    out = xj.new_zeros(n, H, C).index_add(0, dst, xj * alpha[..., None])
    return out.mean(1) + conv.bias


def build_model(cfg: CoarseTrainConfig) -> CoarseGAT:
    """The encoder of a config (the signature :func:`flatlandia.checkpoints.load_checkpoint` wants)."""
    return CoarseGAT(cfg)


def embed(model, b: Batch) -> torch.Tensor:
    """Node embeddings of a (batched) graph."""
    return model(b.x, b.edge_index, b.edge_attr)


def pair_index(ds: Dataset, batch_samples: list[Sample], offsets=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every (query, node of its scene) pair: node index in the reference embeddings, query
    position, node row in its scene. ``offsets`` maps scene position -> first node (default: all
    scenes batched as in ``ds.ref_batch``)."""
    offsets = ds.offsets if offsets is None else offsets
    sizes = [len(ds.refs[s.scene]) for s in batch_samples]
    node = np.concatenate([offsets[s.scene] + np.arange(n) for s, n in zip(batch_samples, sizes)])
    qpos = np.repeat(np.arange(len(batch_samples)), sizes)
    row = np.concatenate([np.arange(n) for n in sizes])
    return node, qpos, row


def reference_embeddings(model, ds: Dataset, scene_pos=None) -> tuple[torch.Tensor, dict | np.ndarray]:
    """Embeddings of the reference graphs of ``scene_pos`` (default every scene) and their offsets."""
    if scene_pos is None:
        return embed(model, ds.ref_batch), ds.offsets
    uniq = sorted(set(int(k) for k in scene_pos))
    if len(uniq) == 1:
        return embed(model, ds.ref_graphs[uniq[0]]), {uniq[0]: 0}
    sizes = np.cumsum([0] + [len(ds.refs[k]) for k in uniq])
    return embed(model, graphs.batch([ds.ref_graphs[k] for k in uniq])), dict(zip(uniq, sizes[:-1].tolist()))


def scores(model, ref_emb: torch.Tensor, q_batch: Batch, node: np.ndarray, qpos: np.ndarray) -> torch.Tensor:
    """``s = ||psi_node - mean psi_query||`` for every pair."""
    q_mean = global_mean_pool(embed(model, q_batch), q_batch.batch, size=q_batch.num_graphs)
    node_t, qpos_t = (torch.from_numpy(a).to(ref_emb.device, non_blocking=True) for a in (node, qpos))
    return torch.linalg.vector_norm(ref_emb[node_t] - q_mean[qpos_t], dim=1)


def fused_scores(model, ref_graph, query_graphs: list, ref_emb: torch.Tensor | None = None) -> torch.Tensor:
    """(queries, reference nodes) scores of query graphs against one reference graph.

    The reference graph and the query graphs go through the encoder as one disjoint union (one
    forward pass, no torch-geometric collation): the same numbers as :func:`scores` on separately
    embedded graphs with less per-call overhead. ``ref_emb`` (cached reference embeddings) skips
    the reference graph.
    """
    graphs_in = ([] if ref_emb is not None else [ref_graph]) + list(query_graphs)
    sizes = [int(g.x.shape[0]) for g in graphs_in]
    offs = np.r_[0, np.cumsum(sizes)[:-1]]
    emb = model(
        torch.cat([g.x for g in graphs_in]),
        torch.cat([g.edge_index + int(o) for g, o in zip(graphs_in, offs)], 1),
        torch.cat([g.edge_attr for g in graphs_in]),
    )
    if ref_emb is None:
        n_ref = sizes[0]
        ref_emb, emb, sizes = emb[:n_ref], emb[n_ref:], sizes[1:]
    sizes_t = torch.tensor(sizes).to(emb.device, non_blocking=True)  # sizes known here: nothing read back
    qb = torch.repeat_interleave(torch.arange(len(sizes), device=emb.device), sizes_t, output_size=sum(sizes))
    q_mean = emb.new_zeros(len(sizes), emb.shape[1]).index_add(0, qb, emb) / sizes_t[:, None].to(emb.dtype)
    return torch.linalg.vector_norm(ref_emb[None] - q_mean[:, None], dim=-1)


# ----------------------------------------------------------------------------- scoring


@torch.no_grad()
def score_samples(model, ds: Dataset, samples: list[Sample], map_type: str, batch_size: int = 512) -> list[np.ndarray]:
    """Scores of every reference node (rows of its scene's table) for each sample."""
    model.eval()
    ref_emb, _ = reference_embeddings(model, ds)
    out = []
    for k in range(0, len(samples), batch_size):
        chunk = samples[k : k + batch_size]
        qb = graphs.batch([s.graphs[map_type] for s in chunk])
        node, qpos, _ = pair_index(ds, chunk)
        s = scores(model, ref_emb, qb, node, qpos).cpu().numpy()
        bounds = np.cumsum([len(ds.refs[c.scene]) for c in chunk])[:-1]
        out += np.split(s, bounds)
    return out
