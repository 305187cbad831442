"""Coarse map localization (PAPER.md, "Coarse map localization", Table 3).

A graph attention network (GATv2 layers with the ``exp(-d)`` edge feature) embeds the query
graph and the scene's reference graph with shared weights; a reference node ``i`` scores
``s_i = || psi_i - mean_j psi_j(query) ||`` (smaller = more similar). Losses:

* **Trip**: ``mean relu(s_pos - s_neg + margin)`` over the query's matched reference objects
  (positives) paired with as many unmatched objects (negatives, redrawn every step). The paper
  draws them at random; by default half of them (``hard_negatives: 0.5``) are instead the
  unmatched nodes the model currently ranks best, the confusions N_LM / R_30 punish (at 20
  epochs: validation criterion +0.03, test R_30 success +0.04 over seeds 100 and 7;
  ``hard_negatives: 0`` is the paper's loss);
* **Sim**: weighted least squares of ``s_i`` to ``1 - S_i`` (``S`` from
  :mod:`flatlandia.coarse.target`), weights ``S_i / max_i S_i + sim_weight_floor`` (the paper's
  "weighted by normalised S"; the floor keeps dissimilar nodes in the loss), normalised per query;
* **Sim+Trip**: their sum (``trip_weight`` scales the triplet term).

Training: Adam over batches of ``batch_size`` (query graph, reference graph) pairs, learning
rate ``lr`` with a per-step cosine decay (``lr_schedule``) so that short runs (the default 20
epochs) converge. With ``batching: scene`` (default) a batch holds queries of one scene, so a
step embeds that scene's reference graph and the batch's query graphs in one forward pass over
their disjoint union (:func:`fused_scores`; about 4x faster per epoch than ``mixed`` batches,
which embed every scene the batch touches); each query is then compared with the nodes of its
own scene. One model per loss, trained on GT and depth local maps (each epoch draws the map
type of every training query at random from ``train_maps``). Seeded and deterministic on CPU;
the best-on-validation weights are kept (criterion: mean of the 2N_LM recall and the R_30
success over GT and depth maps, every ``eval_every`` epochs).

Region proposals (:func:`propose`): ``N_LM`` (the N best nodes, N = query objects), ``2N_LM``,
``R_30`` (every node within 30 m, true metres, of the best node) and the oracle ``GT-BB``.
Metrics per query: precision ``|S n S_gt| / |S|``, recall ``|S n S_gt| / |S_gt|``, success
``|S n S_gt| >= 3``.
"""

from __future__ import annotations

import copy
import time
from dataclasses import asdict, dataclass, field, fields

import numpy as np
import pandas as pd
import torch
from torch import nn
from torch_geometric.data import Batch
from torch_geometric.nn import GATConv, GATv2Conv, global_mean_pool
from torch_geometric.utils import add_self_loops

from flatlandia import tables
from flatlandia.coarse import graphs

LOSSES = {"sim": "Sim", "trip": "Trip", "simtrip": "Sim+Trip"}
STRATEGIES = ["N_LM", "2N_LM", "R_30", "GT-BB"]
MAP_TYPES = ["gt", "depth"]

#: The paper's Table 3: (loss, strategy, map type) -> (precision, recall, success).
PAPER_TABLE3: dict[tuple[str, str, str], tuple[float, float, float]] = {
    ("-", "GT-BB", "gt"): (0.258, 1.0, 1.0),
    ("-", "GT-BB", "depth"): (0.258, 1.0, 1.0),
    ("Sim", "N_LM", "gt"): (0.146, 0.146, 0.168),
    ("Sim", "N_LM", "depth"): (0.176, 0.176, 0.179),
    ("Sim", "2N_LM", "gt"): (0.133, 0.266, 0.328),
    ("Sim", "2N_LM", "depth"): (0.149, 0.299, 0.326),
    ("Sim", "R_30", "gt"): (0.105, 0.439, 0.533),
    ("Sim", "R_30", "depth"): (0.134, 0.531, 0.533),
    ("Trip", "N_LM", "gt"): (0.222, 0.222, 0.211),
    ("Trip", "N_LM", "depth"): (0.214, 0.214, 0.211),
    ("Trip", "2N_LM", "gt"): (0.188, 0.376, 0.403),
    ("Trip", "2N_LM", "depth"): (0.173, 0.345, 0.372),
    ("Trip", "R_30", "gt"): (0.142, 0.471, 0.522),
    ("Trip", "R_30", "depth"): (0.137, 0.458, 0.496),
    ("Sim+Trip", "N_LM", "gt"): (0.236, 0.236, 0.269),
    ("Sim+Trip", "N_LM", "depth"): (0.219, 0.219, 0.247),
    ("Sim+Trip", "2N_LM", "gt"): (0.198, 0.396, 0.473),
    ("Sim+Trip", "2N_LM", "depth"): (0.193, 0.385, 0.452),
    ("Sim+Trip", "R_30", "gt"): (0.148, 0.543, 0.600),
    ("Sim+Trip", "R_30", "depth"): (0.139, 0.506, 0.590),
}

#: Columns of results/tables/coarse_localization.parquet: (name, unit, meaning), from its schema.
TABLE_COLUMNS = [(c.name, c.unit, c.meaning) for c in tables.SCHEMAS["coarse_localization"]]


@dataclass
class CoarseConfig:
    loss: str = "simtrip"  # sim | trip | simtrip
    epochs: int = 20
    batch_size: int = 20
    lr: float = 1e-2  # peak learning rate
    weight_decay: float = 0.0
    margin: float = 0.5  # triplet margin (score units)
    trip_weight: float = 1.0  # Sim+Trip: weight of the triplet term
    hard_negatives: float = 0.5  # Trip: share of negatives that are the best-ranked unmatched nodes (paper 0)
    sim_weight_floor: float = 0.1  # Sim: weight S/max(S) + floor
    grad_clip: float = 1.0  # max gradient norm (0: off); damps the Sim loss spikes
    lr_schedule: str = "cosine"  # constant | cosine (per step, from lr down to lr * lr_min_factor)
    lr_min_factor: float = 0.01
    hidden: int = 32
    heads: int = 2
    layers: int = 3
    out_dim: int = 32
    dropout: float = 0.0
    normalize: bool = True  # L2-normalise embeddings: scores in [0, 2], no blow-ups of the Sim loss
    conv: str = "gatv2"  # gatv2 | gat
    train_maps: list = field(default_factory=lambda: ["gt", "depth"])
    batching: str = "scene"  # scene: each batch holds queries of one scene | mixed: any scenes
    eval_every: int = 1
    seed: int = 0
    # graph normalisation (graphs.GraphConfig); depth_unit_m null = median range of training GT maps
    scale_m: float = 50.0
    depth_unit_m: float | None = None
    knn: int = graphs.REF_KNN
    radius_m: float = 30.0  # R_30
    bb_enlarge: float = 0.10  # GT-BB

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

    @classmethod
    def from_dict(cls, d: dict) -> CoarseConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown coarse config keys {unknown}; known: {sorted(known)}")
        return cls(**{k: (list(v) if isinstance(v, (list, tuple)) else v) for k, v in d.items()})

    def to_dict(self) -> dict:
        return asdict(self)

    def graph_config(self) -> graphs.GraphConfig:
        return graphs.GraphConfig(
            scale_m=self.scale_m,
            depth_unit_m=float(self.depth_unit_m if self.depth_unit_m is not None else 27.0),
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
    cfg: CoarseConfig,
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


# ----------------------------------------------------------------------------- model


class CoarseGAT(nn.Module):
    """Shared node encoder: linear lift, ``layers`` GAT layers with edge features, linear head."""

    def __init__(self, cfg: CoarseConfig, in_dim: int = graphs.N_CLASSES + 2):
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
    message-passing machinery; about 1.5x faster per training step on small CPU graphs and equal
    to the layer up to float rounding (tested)."""
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


def n_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


def _embed(model, b: Batch) -> torch.Tensor:
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
        return _embed(model, ds.ref_batch), ds.offsets
    uniq = sorted(set(int(k) for k in scene_pos))
    if len(uniq) == 1:
        return _embed(model, ds.ref_graphs[uniq[0]]), {uniq[0]: 0}
    sizes = np.cumsum([0] + [len(ds.refs[k]) for k in uniq])
    return _embed(model, graphs.batch([ds.ref_graphs[k] for k in uniq])), dict(zip(uniq, sizes[:-1].tolist()))


def scores(model, ref_emb: torch.Tensor, q_batch: Batch, node: np.ndarray, qpos: np.ndarray) -> torch.Tensor:
    """``s = ||psi_node - mean psi_query||`` for every pair."""
    q_mean = global_mean_pool(_embed(model, q_batch), q_batch.batch, size=q_batch.num_graphs)
    return torch.linalg.vector_norm(ref_emb[torch.from_numpy(node)] - q_mean[torch.from_numpy(qpos)], dim=1)


# ----------------------------------------------------------------------------- losses


def sim_loss(s: torch.Tensor, S: torch.Tensor, qpos: torch.Tensor, n_queries: int, floor: float = 0.1) -> torch.Tensor:
    """Weighted regression of ``s`` to ``1 - S``; weights ``S / max_query S + floor``, mean over queries."""
    smax = torch.zeros(n_queries, dtype=S.dtype).scatter_reduce(0, qpos, S, reduce="amax", include_self=True)
    w = S / smax.clamp_min(1e-6)[qpos] + floor
    err = w * (s - (1.0 - S)) ** 2
    num = torch.zeros(n_queries, dtype=s.dtype).index_add(0, qpos, err)
    den = torch.zeros(n_queries, dtype=s.dtype).index_add(0, qpos, w)
    return (num / den.clamp_min(1e-12)).mean()


def triplet_loss(s_pos: torch.Tensor, s_neg: torch.Tensor, margin: float) -> torch.Tensor:
    """``mean relu(s_pos - s_neg + margin)`` over (positive, negative) pairs."""
    if s_pos.numel() == 0:
        return s_pos.sum()
    return torch.relu(s_pos - s_neg + margin).mean()


def draw_triplets(
    batch_samples: list[Sample],
    sizes: list[int],
    rng: np.random.Generator,
    scores: np.ndarray | None = None,
    hard_fraction: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Pair positions (into the concatenated pair list) of positives and as many negatives: random
    unmatched nodes (the paper), of which ``hard_fraction`` (rounded, per query) are instead the
    unmatched nodes the model currently ranks best (smallest ``scores``, one per pair position)."""
    pos_all, neg_all = [], []
    start = 0
    for s, n in zip(batch_samples, sizes):
        neg_pool = s.negatives if s.negatives is not None else np.setdiff1d(np.arange(n), s.positives)
        n_pos = len(s.positives)
        if n_pos and len(neg_pool):
            n_hard = min(int(round(hard_fraction * n_pos)), len(neg_pool)) if scores is not None else 0
            hard = np.zeros(0, np.int64)
            pool = neg_pool
            if n_hard:
                order = np.argsort(scores[start + neg_pool], kind="stable")
                hard, pool = neg_pool[order[:n_hard]], neg_pool[np.sort(order[n_hard:])]
            n_rand = n_pos - n_hard
            if len(pool) >= n_rand:  # without replacement
                rand = pool[rng.permutation(len(pool))[:n_rand]]
            else:
                rand = neg_pool[rng.integers(0, len(neg_pool), n_rand)]
            neg = np.concatenate([hard, rand]).astype(np.int64)
            pos_all.append(start + s.positives)
            neg_all.append(start + neg)
        start += n
    if not pos_all:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(pos_all), np.concatenate(neg_all)


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
    sizes_t = torch.tensor(sizes)
    qb = torch.repeat_interleave(torch.arange(len(sizes)), sizes_t)
    q_mean = emb.new_zeros(len(sizes), emb.shape[1]).index_add(0, qb, emb) / sizes_t[:, None].to(emb.dtype)
    return torch.linalg.vector_norm(ref_emb[None] - q_mean[:, None], dim=-1)


def batch_loss(
    model, ds: Dataset, batch_samples: list[Sample], map_types: list[str], cfg: CoarseConfig, rng: np.random.Generator
) -> tuple[torch.Tensor, dict]:
    """The configured loss of one batch (map type per sample given); only the reference graphs of
    the batch's scenes are embedded (one fused forward pass when the batch holds one scene)."""
    scenes = {b.scene for b in batch_samples}
    qpos = np.repeat(np.arange(len(batch_samples)), [len(ds.refs[b.scene]) for b in batch_samples])
    if len(scenes) == 1:
        k = batch_samples[0].scene
        s = fused_scores(model, ds.ref_graphs[k], [b.graphs[mt] for b, mt in zip(batch_samples, map_types)]).reshape(-1)
    else:
        ref_emb, offsets = reference_embeddings(model, ds, [b.scene for b in batch_samples])
        qb = graphs.batch([s.graphs[mt] for s, mt in zip(batch_samples, map_types)])
        node, qpos, row = pair_index(ds, batch_samples, offsets)
        s = scores(model, ref_emb, qb, node, qpos)
    parts = {}
    total = s.new_zeros(())
    if cfg.loss in ("sim", "simtrip"):
        if any(b.S is None for b in batch_samples):
            raise ValueError("the Sim loss needs the similarity table of every training query")
        S = torch.from_numpy(np.concatenate([b.S for b in batch_samples]).astype(np.float32))
        ls = sim_loss(s, S, torch.from_numpy(qpos), len(batch_samples), cfg.sim_weight_floor)
        parts["loss_sim"] = float(ls.detach())
        total = total + ls
    if cfg.loss in ("trip", "simtrip"):
        sizes = [len(ds.refs[b.scene]) for b in batch_samples]
        ip, ineg = draw_triplets(
            batch_samples, sizes, rng, s.detach().numpy() if cfg.hard_negatives else None, cfg.hard_negatives
        )
        lt = triplet_loss(s[torch.from_numpy(ip)], s[torch.from_numpy(ineg)], cfg.margin)
        parts["loss_trip"] = float(lt.detach())
        total = total + cfg.trip_weight * lt
    return total, parts


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
        s = scores(model, ref_emb, qb, node, qpos).numpy()
        bounds = np.cumsum([len(ds.refs[c.scene]) for c in chunk])[:-1]
        out += np.split(s, bounds)
    return out


def random_scores(ds: Dataset, samples: list[Sample], seed: int = 0) -> list[np.ndarray]:
    """The random-scoring baseline: i.i.d. uniform scores per node, seeded."""
    rng = np.random.default_rng(seed)
    return [rng.random(len(ds.refs[s.scene])) for s in samples]


def similarity_scores(samples: list[Sample]) -> list[np.ndarray]:
    """Oracle baseline: rank by the target itself (``1 - S``; needs the true GT local map)."""
    return [1.0 - s.S for s in samples]


# ----------------------------------------------------------------------------- proposals and metrics


def propose(
    score: np.ndarray,
    ref_xy: np.ndarray,
    n_query: int,
    strategy: str,
    radius_m: float = 30.0,
    matched_rows=None,
    cam_xy=None,
    enlarge: float = 0.10,
) -> np.ndarray:
    """Rows of the reference table proposed by a strategy (scores: smaller is better).

    Ties in the score are broken by row (stable sort), so proposals are deterministic.
    """
    score = np.asarray(score, float)
    order = np.argsort(score, kind="stable")
    if strategy == "N_LM":
        return np.sort(order[:n_query])
    if strategy == "2N_LM":
        return np.sort(order[: 2 * n_query])
    if strategy == "R_30":
        best = order[0]
        d = np.linalg.norm(np.asarray(ref_xy, float) - np.asarray(ref_xy, float)[best], axis=1)
        return np.flatnonzero(d <= radius_m)
    if strategy == "GT-BB":
        from flatlandia.fine.evaluation import gtbb_indices

        if matched_rows is None or cam_xy is None:
            raise ValueError("GT-BB needs the matched rows and the true camera")
        return gtbb_indices(ref_xy, matched_rows, cam_xy, enlarge)
    raise ValueError(f"unknown strategy {strategy!r}; known: {STRATEGIES}")


def proposal_metrics(proposal, truth) -> dict:
    """Precision, recall, success (>= 3 correct) of one proposal against the matched objects."""
    p, t = set(int(i) for i in proposal), set(int(i) for i in truth)
    hit = len(p & t)
    return {
        "n_proposed": len(p),
        "n_correct": hit,
        "precision": hit / len(p) if p else 0.0,
        "recall": hit / len(t) if t else float("nan"),
        "success": hit >= 3,
    }


def evaluate_scores(
    ds: Dataset,
    samples: list[Sample],
    score_list: list[np.ndarray],
    loss_label: str,
    map_type: str,
    strategies=("N_LM", "2N_LM", "R_30"),
    radius_m: float = 30.0,
    enlarge: float = 0.10,
) -> pd.DataFrame:
    """One row per (query, strategy): the proposal (reference ``obj_idx``) and its metrics."""
    rows = []
    for s, sc in zip(samples, score_list):
        ref = ds.refs[s.scene]
        xy = ref[["x_m", "y_m"]].to_numpy(float)
        obj = ref["obj_idx"].to_numpy()
        for strat in strategies:
            prop = propose(sc, xy, s.n_objects, strat, radius_m, s.positives, s.cam_xy, enlarge)
            rows.append(
                {
                    "scene": ds.scene_ids[s.scene],
                    "token": s.token,
                    "loss": loss_label,
                    "map_type": map_type,
                    "strategy": strat,
                    "proposal": [int(o) for o in obj[prop]],
                    **proposal_metrics(prop, s.positives),
                }
            )
    return pd.DataFrame(rows)


def summarise(per_query: pd.DataFrame) -> pd.DataFrame:
    """Mean precision / recall / success per (loss, strategy, map type), the paper's beside."""
    g = per_query.groupby(["loss", "strategy", "map_type"], sort=False)
    out = g.agg(
        queries=("token", "size"),
        precision=("precision", "mean"),
        recall=("recall", "mean"),
        success=("success", "mean"),
        proposal_size=("n_proposed", "mean"),
    ).reset_index()
    out["queries"] = out["queries"].astype(np.int64)
    paper = [PAPER_TABLE3.get((r.loss, r.strategy, r.map_type), (np.nan,) * 3) for r in out.itertuples()]
    out["paper_precision"], out["paper_recall"], out["paper_success"] = (
        np.array(paper, float).T if paper else ([], [], [])
    )
    return out[[c for c, _, _ in TABLE_COLUMNS]]


def validation_metric(model, ds: Dataset, samples: list[Sample], cfg: CoarseConfig) -> float:
    """Mean of the 2N_LM recall and the R_30 success over GT and depth maps (higher is better)."""
    vals = []
    xy = [r[["x_m", "y_m"]].to_numpy(float) for r in ds.refs]
    for mt in MAP_TYPES:
        recall, success = [], []
        for s, sc in zip(samples, score_samples(model, ds, samples, mt)):
            order = np.argsort(sc, kind="stable")  # = propose() + proposal_metrics(), without DataFrames
            pos = np.zeros(len(sc), bool)
            pos[s.positives] = True
            recall.append(pos[order[: 2 * s.n_objects]].sum() / max(pos.sum(), 1))
            near = np.linalg.norm(xy[s.scene] - xy[s.scene][order[0]], axis=1) <= cfg.radius_m
            success.append((near & pos).sum() >= 3)
        vals += [float(np.mean(recall)), float(np.mean(success))]
    return float(np.mean(vals))


# ----------------------------------------------------------------------------- training


def set_determinism(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)


def build_model(cfg: CoarseConfig) -> CoarseGAT:
    return CoarseGAT(cfg)


def epoch_batches(train_s: list[Sample], cfg: CoarseConfig, rng: np.random.Generator) -> list[np.ndarray]:
    """Index batches of one epoch. ``scene``: each scene's queries shuffled and cut into batches
    of at most ``batch_size``, then the batches shuffled (one reference graph per step);
    ``mixed``: one global permutation cut into batches."""
    if cfg.batching == "mixed":
        order = rng.permutation(len(train_s))
        return [order[k : k + cfg.batch_size] for k in range(0, len(order), cfg.batch_size)]
    by_scene: dict[int, list[int]] = {}
    for i, s in enumerate(train_s):
        by_scene.setdefault(s.scene, []).append(i)
    out = []
    for k in sorted(by_scene):
        idx = rng.permutation(np.asarray(by_scene[k]))
        out += [idx[j : j + cfg.batch_size] for j in range(0, len(idx), cfg.batch_size)]
    return [out[i] for i in rng.permutation(len(out))]


def train(ds: Dataset, cfg: CoarseConfig, log=None, progress=None) -> dict:
    """Adam over batches of (query, reference) pairs; keeps the best-on-validation weights.

    Returns {'model', 'state_dict', 'config', 'history', 'best_epoch', 'best_val', 'seconds',
    'seconds_per_epoch'}.
    """
    set_determinism(cfg.seed)
    model = build_model(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, foreach=True)
    rng = np.random.default_rng(cfg.seed)
    train_s, val_s = ds.split("train"), ds.split("val")
    if not train_s:
        raise ValueError("no training queries")
    sched = None
    if cfg.lr_schedule == "cosine":
        total = max(cfg.epochs * len(epoch_batches(train_s, cfg, np.random.default_rng(0))), 1)
        lo = cfg.lr_min_factor
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda step: lo + (1 - lo) * 0.5 * (1 + np.cos(np.pi * min(step, total) / total))
        )
    history, best, best_state, best_epoch = [], -np.inf, None, -1
    t0 = time.perf_counter()
    train_time = 0.0
    epochs = range(cfg.epochs)
    for ep in progress(epochs) if progress else epochs:
        te = time.perf_counter()
        model.train()
        mts = rng.choice(len(cfg.train_maps), size=len(train_s))
        tot, parts_sum, n = 0.0, {}, 0
        for idx in epoch_batches(train_s, cfg, rng):
            opt.zero_grad()
            loss, parts = batch_loss(
                model, ds, [train_s[i] for i in idx], [cfg.train_maps[mts[i]] for i in idx], cfg, rng
            )
            loss.backward()
            if cfg.grad_clip > 0:
                nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            opt.step()
            if sched is not None:
                sched.step()
            tot += float(loss.detach()) * len(idx)
            for key, v in parts.items():
                parts_sum[key] = parts_sum.get(key, 0.0) + v * len(idx)
            n += len(idx)
        train_time += time.perf_counter() - te
        rec = {
            "epoch": ep,
            "train_loss": tot / n,
            **{k: v / n for k, v in parts_sum.items()},
            "epoch_seconds": time.perf_counter() - te,
        }
        if val_s and (ep % cfg.eval_every == 0 or ep == cfg.epochs - 1):
            rec["val_metric"] = validation_metric(model, ds, val_s, cfg)
            if rec["val_metric"] > best:
                best, best_epoch = rec["val_metric"], ep
                best_state = copy.deepcopy(model.state_dict())
        history.append(rec)
        if log is not None:
            log.info("epoch %d: %s", ep, {k: round(v, 4) for k, v in rec.items() if k != "epoch"})
    if best_state is None:
        best_state, best_epoch = copy.deepcopy(model.state_dict()), cfg.epochs - 1
    model.load_state_dict(best_state)
    model.eval()
    return {
        "model": model,
        "state_dict": best_state,
        "config": cfg.to_dict(),
        "history": history,
        "best_epoch": best_epoch,
        "best_val": float(best),
        "seconds": time.perf_counter() - t0,
        "seconds_per_epoch": train_time / max(cfg.epochs, 1),
    }


def save_checkpoint(result: dict, path) -> None:
    """torch.save({'state_dict', 'config', 'history', 'best_epoch', 'best_val', ...}) atomically."""
    from flatlandia.io import atomic_path

    with atomic_path(path) as tmp:
        torch.save(
            {
                k: result[k]
                for k in ("state_dict", "config", "history", "best_epoch", "best_val", "seconds", "seconds_per_epoch")
                if k in result
            },
            tmp,
        )


def load_checkpoint(path) -> tuple[CoarseGAT, CoarseConfig]:
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = CoarseConfig.from_dict(ck["config"])
    model = build_model(cfg)
    model.load_state_dict(ck["state_dict"])
    model.eval()
    return model, cfg


# ----------------------------------------------------------------------------- evaluation


def evaluate(
    models: dict[str, tuple[CoarseGAT, CoarseConfig]],
    ds: Dataset,
    split: str = "test",
    baselines: bool = True,
    seed: int = 0,
) -> pd.DataFrame:
    """Per-query proposals and metrics of every model x map type x strategy, plus GT-BB and baselines.

    ``models`` maps the loss label (Sim, Trip, Sim+Trip) to (model, config). Baselines: 'random'
    (uniform scores) and 'S oracle' (ranking by the target S, computed from the GT map).
    """
    samples = ds.split(split)
    parts = []
    radius = next(iter(models.values()))[1].radius_m if models else 30.0
    enlarge = next(iter(models.values()))[1].bb_enlarge if models else 0.10
    for label, (model, cfg) in models.items():
        for mt in MAP_TYPES:
            parts.append(
                evaluate_scores(ds, samples, score_samples(model, ds, samples, mt), label, mt, radius_m=cfg.radius_m)
            )
    for mt in MAP_TYPES:
        parts.append(
            evaluate_scores(ds, samples, random_scores(ds, samples, seed), "-", mt, ("GT-BB",), radius, enlarge)
        )
        if baselines:
            parts.append(evaluate_scores(ds, samples, random_scores(ds, samples, seed), "random", mt, radius_m=radius))
            if all(s.S is not None for s in samples):
                parts.append(evaluate_scores(ds, samples, similarity_scores(samples), "S oracle", mt, radius_m=radius))
    return pd.concat(parts, ignore_index=True)


def _fmt(p, r, s) -> str:
    return " / ".join("-" if not np.isfinite(v) else f"{v:.3f}" for v in (p, r, s))


def render_markdown(table: pd.DataFrame, title: str = "Coarse map localization (Table 3)", note: str = "") -> str:
    """Rows loss x strategy; columns GT maps and depth maps, ours beside the paper's (P / R / S)."""
    order_loss = ["-", "Sim", "Trip", "Sim+Trip", "random", "S oracle"]
    order_strat = {s: i for i, s in enumerate(STRATEGIES)}
    t = table.copy()
    t["_l"] = t["loss"].map(lambda v: order_loss.index(v) if v in order_loss else len(order_loss))
    t["_s"] = t["strategy"].map(lambda v: order_strat.get(v, 99))
    lines = [f"# {title}", ""]
    if note:
        lines += [note, ""]
    lines += [
        "P / R / S = precision / recall / success (>= 3 correct nodes), test split.",
        "",
        "| loss | NS | GT maps (ours) | GT maps (paper) | depth maps (ours) | depth maps (paper) | queries |",
        "|---|---|---|---|---|---|---|",
    ]
    for (loss, strat), g in t.sort_values(["_l", "_s"]).groupby(["loss", "strategy"], sort=False):
        cells = []
        for mt in MAP_TYPES:
            r = g[g["map_type"] == mt]
            if len(r):
                r = r.iloc[0]
                cells += [
                    _fmt(r.precision, r.recall, r.success),
                    _fmt(r.paper_precision, r.paper_recall, r.paper_success),
                ]
            else:
                cells += ["", ""]
        lines.append(f"| {loss} | {strat} | " + " | ".join(cells) + f" | {int(g['queries'].iloc[0])} |")
    return "\n".join(lines) + "\n"


@torch.no_grad()
def time_one_query(model, ds: Dataset, sample: Sample, map_type: str = "gt", repeats: int = 50) -> dict:
    """Seconds to score one query against its scene (:func:`fused_scores`, the scene's reference
    embeddings cached, and without the cache: reference graph embedded in the same pass); median
    of ``repeats`` calls."""
    model.eval()
    k = sample.scene
    ref_emb = _embed(model, ds.ref_graphs[k])
    g = sample.graphs[map_type]
    times = {"score_cached_ref_s": [], "score_with_ref_s": []}
    for _ in range(repeats):
        t0 = time.perf_counter()
        fused_scores(model, None, [g], ref_emb=ref_emb)
        t1 = time.perf_counter()
        fused_scores(model, ds.ref_graphs[k], [g])
        t2 = time.perf_counter()
        times["score_cached_ref_s"].append(t1 - t0)
        times["score_with_ref_s"].append(t2 - t1)
    return {key: float(np.median(v)) for key, v in times.items()}
