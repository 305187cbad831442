"""The paper's learned fine-localization baselines: MLP, MLP+ATT, GAT, GAT+ATT (torch-geometric).

Each sample is one query: its local map (GT in metres, or depth, unscaled) with the classes of its
objects, and a region proposal (reference objects, metric frame). The model regresses the camera
pose (x, y, theta) in the region's frame.

Normalisation ("scene scaled into a unit square"): region coordinates are centred on the
proposal's centroid and divided by ``scale_m``; GT query maps are divided by ``scale_m`` too, depth
query maps (median object range 1) are multiplied by ``depth_unit_m / scale_m``, a fixed typical
range, so both map types live in the same units.

Models (``hidden`` = 64 in the paper):
- ``MLP``: Psi_Q = maxpool(Π(query nodes)); Psi = maxpool_j σ3([Psi_Q, Π(region node j)]); ρ -> pose.
- ``MLP+ATT``: a multi-head self-attention layer over the σ3 features before the last max-pool.
- ``GAT``: one graph of query + region nodes; intra-map edges (query fully connected, region
  kNN-``knn``) and inter-map edges between same-class query/region nodes. Edge embedding: length and
  orientation of the segment, inter-map edges computed with the query placed at the region centre
  facing north. ``rounds`` x (2 edge-aware GATv2 layers on intra-map edges, then 1 EGAT-style layer
  on inter-map edges updating nodes and edges); Psi = maxpool(inter-map edge embeddings).
- ``GAT+ATT``: self-attention over the inter-map edge embeddings before the pool.

Batches are torch-geometric batches (one ``Data`` per query), or padded :class:`DenseMaps` for
the MLP models. Training, loss and augmentation: :mod:`flatlandia.fine.training`.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch
from torch import nn

from flatlandia import config, vocabulary
from flatlandia import device as device_module
from flatlandia.classes import N_CLASSES
from flatlandia.data import localmaps
from flatlandia.plumbing.pyg import Batch, Data, GATv2Conv, scatter, to_dense_batch

MODELS = tuple(vocabulary.LEARNED_METHODS.values())


@config.settings("fine.train")
class FineTrainConfig:
    """How one fine model is trained: the config section ``fine.train`` (each key is described in
    config/README.md, ``fine.train.*``), plus what the rule fixes per run: the model (one of
    :data:`MODELS`), the local maps it reads (``gt`` | ``depth``) and ``extra``, free-form
    bookkeeping. Stored in the checkpoint (``to_dict``) and read back with ``from_dict``."""

    model: str = "MLP"
    map_type: str = "depth"  # gt | depth
    extra: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- samples


def _knn_edges(pos: np.ndarray, k: int) -> np.ndarray:
    n = len(pos)
    if n < 2 or k < 1:
        return np.zeros((2, 0), int)
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    nb = np.argsort(d, axis=1, kind="stable")[:, : min(k, n - 1)]
    src = np.repeat(np.arange(n), nb.shape[1])
    e = np.stack([src, nb.ravel()])
    e = np.concatenate([e, e[::-1]], axis=1)  # symmetric
    return np.unique(e, axis=1)


def make_sample(
    q_local: np.ndarray, q_cls, r_xy: np.ndarray, r_cls, cfg: FineTrainConfig, cam_xy=None, theta: float | None = None
) -> Data:
    """One query as a graph: nodes = query objects then region objects (positions normalised).

    ``q_pos`` is the query in its camera frame (normalised); ``pos`` holds the node positions used
    by the graph (query placed at the region centre facing north, region centred). The target ``y``
    is (x, y, theta) of the camera in the region's normalised frame.
    """
    q_local = np.asarray(q_local, float).reshape(-1, 2)
    r_xy = np.asarray(r_xy, float).reshape(-1, 2)
    m, n = len(q_local), len(r_xy)
    centre = r_xy.mean(0) if n else np.zeros(2)
    unit = (cfg.depth_unit_m if cfg.map_type == "depth" else 1.0) / cfg.scale_m
    q_pos = q_local * unit
    r_pos = (r_xy - centre) / cfg.scale_m
    cls = np.concatenate([np.asarray(q_cls, int), np.asarray(r_cls, int)])
    # intra-map edges: query fully connected, region kNN
    qi, qj = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    keep = qi != qj
    intra_q = np.stack([qi[keep], qj[keep]])
    intra_r = _knn_edges(r_pos, cfg.knn) + m
    intra = np.concatenate([intra_q, intra_r], axis=1)
    # inter-map edges: same-class query -> region (and back)
    a, b = np.nonzero(np.asarray(q_cls, int)[:, None] == np.asarray(r_cls, int)[None, :])
    inter = np.stack([a, b + m]) if len(a) else np.zeros((2, 0), int)
    y = np.zeros((1, 3))
    if cam_xy is not None:
        y[0, :2] = (np.asarray(cam_xy, float) - centre) / cfg.scale_m
        y[0, 2] = float(theta)
    return Data(
        cls=torch.as_tensor(cls, dtype=torch.long),
        local=torch.as_tensor(np.concatenate([q_pos, r_pos]), dtype=torch.float32),
        is_q=torch.as_tensor(np.r_[np.ones(m, bool), np.zeros(n, bool)]),
        intra_edge_index=torch.as_tensor(intra, dtype=torch.long),
        inter_edge_index=torch.as_tensor(inter, dtype=torch.long),
        y=torch.as_tensor(y, dtype=torch.float32),
        centre=torch.as_tensor(centre[None], dtype=torch.float32),
        num_nodes=m + n,
    )


def samples_from_queries(
    ref: pd.DataFrame, queries: pd.DataFrame, proposals: pd.DataFrame, cfg: FineTrainConfig
) -> tuple[list[Data], pd.DataFrame]:
    """Samples of one scene's queries with their proposals; also the kept query rows (same order)."""
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    props = dict(zip(proposals["token"].astype(str), proposals["proposal"]))
    out = []
    for r in queries.itertuples(index=False):
        idx = np.array([pos[int(o)] for o in props.get(str(r.token), []) if int(o) in pos], int)
        q = localmaps.local_map(r, cfg.map_type)
        out.append(make_sample(q, r.classes, ref_xy[idx], ref_cls[idx], cfg, (r.x_m, r.y_m), math.radians(r.theta_deg)))
    return out, queries.reset_index(drop=True)


# ----------------------------------------------------------------------------- dense batches (MLP models)


@dataclass
class DenseMaps:
    """Padded per-query tensors (query objects, region objects, target) for the MLP models.

    Why: collating torch-geometric batches at every step costs about as much as the MLP step; the
    whole split is padded once (and moved to the device once, :meth:`to`) and a batch is a row
    selection, trimmed to its longest map. The maps' lengths are kept on the host (``q_len``,
    ``r_len``), so trimming a batch on a GPU reads nothing back from it.
    """

    q_cls: torch.Tensor  # (N, Lq) class ids (0 on padding)
    q_xy: torch.Tensor  # (N, Lq, 2) query objects, normalised camera frame
    q_mask: torch.Tensor  # (N, Lq) True on real objects
    r_cls: torch.Tensor  # (N, Lr)
    r_xy: torch.Tensor  # (N, Lr, 2) region objects, normalised region frame
    r_mask: torch.Tensor  # (N, Lr)
    y: torch.Tensor  # (N, 3) target pose
    q_len: np.ndarray | None = None  # (N,) query objects per row, on the host (None: from q_mask)
    r_len: np.ndarray | None = None  # (N,) region objects per row, on the host

    @property
    def num_graphs(self) -> int:
        return int(self.y.shape[0])

    def __len__(self) -> int:
        return self.num_graphs

    def to(self, device) -> DenseMaps:
        """The same maps on ``device`` (the host lengths stay on the host); itself when there already."""
        if same_device(self.y.device, device):
            return self
        moved = [getattr(self, f).to(device) for f in ("q_cls", "q_xy", "q_mask", "r_cls", "r_xy", "r_mask", "y")]
        return DenseMaps(*moved, q_len=self._lengths("q"), r_len=self._lengths("r"))

    def _lengths(self, kind: str) -> np.ndarray:
        kept = getattr(self, f"{kind}_len")
        return kept if kept is not None else getattr(self, f"{kind}_mask").sum(1).cpu().numpy()

    def __getitem__(self, idx) -> DenseMaps:
        rows = np.asarray(idx, dtype=np.int64).reshape(-1)
        q_len, r_len = self._lengths("q")[rows], self._lengths("r")[rows]
        lq = max(int(q_len.max()), 1) if len(rows) else 1
        lr = max(int(r_len.max()), 1) if len(rows) else 1
        idx = torch.from_numpy(rows).to(self.y.device, non_blocking=True)  # the step's one copy to the device
        return DenseMaps(
            self.q_cls[idx, :lq],
            self.q_xy[idx, :lq],
            self.q_mask[idx, :lq],
            self.r_cls[idx, :lr],
            self.r_xy[idx, :lr],
            self.r_mask[idx, :lr],
            self.y[idx],
            q_len,
            r_len,
        )


def dense_maps(samples) -> DenseMaps:
    """Pad a list of samples (or a torch-geometric batch of them) into :class:`DenseMaps`."""
    b = samples if isinstance(samples, Batch) else Batch.from_data_list(list(samples))
    n = int(b.num_graphs)
    qm = b.is_q
    parts = []
    for m in (qm, ~qm):
        xy, mask = to_dense_batch(b.local[m], b.batch[m], batch_size=n)
        cls, _ = to_dense_batch(b.cls[m], b.batch[m], batch_size=n)
        if xy.shape[1] == 0:  # no object of this kind in any sample: one padded column
            xy, mask, cls = xy.new_zeros(n, 1, 2), mask.new_zeros(n, 1), cls.new_zeros(n, 1)
        parts += [cls, xy, mask]
    q_len, r_len = (m.sum(1).cpu().numpy() for m in (parts[2], parts[5]))
    return DenseMaps(*parts, y=b.y, q_len=q_len, r_len=r_len)


# ----------------------------------------------------------------------------- graph batches (GAT models)

#: the per-node, per-graph and edge-index attributes of a sample (:func:`make_sample`)
NODE_KEYS = ("cls", "local", "is_q")
GRAPH_KEYS = ("y", "centre")
EDGE_KEYS = ("intra_edge_index", "inter_edge_index")


@dataclass
class GraphBatch:
    """Sample graphs batched as ``Batch.from_data_list`` batches them (nodes and edges in sample
    order, edge indices shifted by the nodes before, ``batch`` the graph of each node): what the
    GAT models and :func:`flatlandia.fine.training.augment` read."""

    cls: torch.Tensor
    local: torch.Tensor
    is_q: torch.Tensor
    intra_edge_index: torch.Tensor
    inter_edge_index: torch.Tensor
    y: torch.Tensor
    centre: torch.Tensor
    batch: torch.Tensor
    num_graphs: int

    def to(self, device) -> GraphBatch:
        if same_device(self.y.device, device):
            return self
        moved = {k: getattr(self, k).to(device) for k in (*NODE_KEYS, *EDGE_KEYS, *GRAPH_KEYS, "batch")}
        return GraphBatch(**moved, num_graphs=self.num_graphs)


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``concatenate([arange(s, s + c) for s, c in zip(starts, counts)])``, without the loop."""
    total = int(counts.sum())
    before = np.cumsum(counts) - counts
    return np.repeat(starts - before, counts) + np.arange(total, dtype=np.int64)


class GraphSplit:
    """Every sample graph of a split collated once (and moved to the device once, :meth:`to`); a
    batch is a selection of graphs (:meth:`__getitem__`), equal to ``Batch.from_data_list`` of those
    samples. Why: collating on every step costs CPU time, and collating graphs that live on a GPU
    copies a number to it per graph and attribute (torch-geometric's collate), each a wait; here
    the node and edge positions of a batch are computed on the host and go over in one copy."""

    def __init__(self, samples: list[Data]):
        b = Batch.from_data_list(list(samples))
        self.tensors = {k: b[k] for k in (*NODE_KEYS, *GRAPH_KEYS, *EDGE_KEYS)}
        self.node_ptr = np.r_[0, np.cumsum([int(s.num_nodes) for s in samples])].astype(np.int64)
        self.edge_ptr = {
            k: np.r_[0, np.cumsum([int(s[k].shape[1]) for s in samples])].astype(np.int64) for k in EDGE_KEYS
        }

    def __len__(self) -> int:
        return len(self.node_ptr) - 1

    @property
    def device(self) -> torch.device:
        return self.tensors["y"].device

    def to(self, device) -> GraphSplit:
        """The same split on ``device`` (positions stay on the host); itself when there already."""
        if same_device(self.device, device):
            return self
        out = copy.copy(self)
        out.tensors = {k: v.to(device) for k, v in self.tensors.items()}
        return out

    def __getitem__(self, idx) -> GraphBatch:
        rows = np.asarray(idx, dtype=np.int64).reshape(-1)
        n_nodes = self.node_ptr[rows + 1] - self.node_ptr[rows]
        new_start = np.cumsum(n_nodes) - n_nodes  # first node of each graph in the batch
        parts = [rows, _ranges(self.node_ptr[rows], n_nodes), np.repeat(np.arange(len(rows)), n_nodes)]
        for k in EDGE_KEYS:
            ptr = self.edge_ptr[k]
            n_edges = ptr[rows + 1] - ptr[rows]
            parts += [_ranges(ptr[rows], n_edges), np.repeat(new_start - self.node_ptr[rows], n_edges)]
        sizes = [len(p) for p in parts]
        packed = torch.from_numpy(np.concatenate(parts)).to(self.device, non_blocking=True)
        graph, node, batch, *edges = torch.split(packed, sizes)
        t = self.tensors
        out = {k: t[k][node] for k in NODE_KEYS} | {k: t[k][graph] for k in GRAPH_KEYS}
        for k, (edge, shift) in zip(EDGE_KEYS, zip(edges[::2], edges[1::2])):
            out[k] = t[k][:, edge] + shift
        return GraphBatch(**out, batch=batch, num_graphs=len(rows))


def _masked_max(h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Max over dim 1 of (B, L, d) where mask (B, L) is True; 0 for rows without any."""
    z = h.masked_fill(~mask[..., None], float("-inf")).max(dim=1).values
    return torch.where(torch.isfinite(z), z, torch.zeros_like(z))


# ----------------------------------------------------------------------------- models


def _mlp(sizes: list[int], last_relu: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for k in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[k], sizes[k + 1]))
        if k < len(sizes) - 2 or last_relu:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def _masked_attention_pool(att: nn.MultiheadAttention, h: torch.Tensor, index: torch.Tensor, n_graphs: int):
    """Self-attention over the rows of each graph (padding + mask), residual, then masked max-pool."""
    dense, mask = to_dense_batch(h, index, batch_size=n_graphs)  # (B, L, d), (B, L)
    if dense.shape[1] == 0:
        return torch.zeros(n_graphs, h.shape[1], dtype=h.dtype, device=h.device)
    pad = ~mask
    empty = pad.all(dim=1)
    pad = pad.clone()
    pad[empty, 0] = False  # graphs without rows attend to one zero row (result masked below)
    a, _ = att(dense, dense, dense, key_padding_mask=pad, need_weights=False)
    return _masked_max(dense + a, mask)


def _edge_geom(pos: torch.Tensor, ei: torch.Tensor) -> torch.Tensor:
    d = pos[ei[1]] - pos[ei[0]]
    length = d.norm(dim=1, keepdim=True)
    ang = torch.atan2(d[:, 1], d[:, 0])
    return torch.cat([length, torch.cos(ang)[:, None], torch.sin(ang)[:, None]], dim=1)


class _Base(nn.Module):
    def __init__(self, cfg: FineTrainConfig):
        super().__init__()
        self.cfg = cfg
        h = cfg.hidden
        self.rho = _mlp([h, h, h, 4], last_relu=False)

    @staticmethod
    def node_features(batch) -> torch.Tensor:
        return torch.cat([nn.functional.one_hot(batch.cls, N_CLASSES).float(), batch.local], dim=1)

    def head(self, psi: torch.Tensor) -> torch.Tensor:
        out = self.rho(psi)
        return torch.cat([out[:, :2], torch.atan2(out[:, 3], out[:, 2])[:, None]], dim=1)


class MLPModel(_Base):
    def __init__(self, cfg: FineTrainConfig, attention: bool = False):
        super().__init__(cfg)
        h = cfg.hidden
        self.pi_q = _mlp([N_CLASSES + 2, h, h])
        self.pi_r = _mlp([N_CLASSES + 2, h, h])
        self.sigma3 = _mlp([2 * h, h, h])
        self.att = nn.MultiheadAttention(h, cfg.heads, batch_first=True) if attention else None

    def forward(self, batch) -> torch.Tensor:
        d = batch if isinstance(batch, DenseMaps) else dense_maps(batch)
        n_graphs, n_r = d.r_mask.shape
        xq = torch.cat([nn.functional.one_hot(d.q_cls, N_CLASSES).float(), d.q_xy], dim=2)
        psi_q = _masked_max(self.pi_q(xq), d.q_mask)
        g, col = d.r_mask.nonzero(as_tuple=True)  # region objects, packed (no work on padding)
        xr = torch.cat([nn.functional.one_hot(d.r_cls[g, col], N_CLASSES).float(), d.r_xy[g, col]], dim=1)
        z = self.sigma3(torch.cat([psi_q[g], self.pi_r(xr)], dim=1))
        if self.att is not None:
            psi = _masked_attention_pool(self.att, z, g, n_graphs)
        else:
            psi = scatter(z, g, dim=0, dim_size=n_graphs, reduce="max")
        return self.head(psi)


class _EdgeLayer(nn.Module):
    """EGAT-style layer on inter-map edges: attention update of nodes, then of edge embeddings."""

    def __init__(self, h: int, heads: int):
        super().__init__()
        self.node = GATv2Conv(h, h, heads=heads, concat=False, edge_dim=h, add_self_loops=False)
        self.edge = _mlp([3 * h, h, h])

    def forward(self, x, ei, e):
        both = torch.cat([ei, ei.flip(0)], dim=1)
        x = x + torch.relu(self.node(x, both, torch.cat([e, e], dim=0)))
        e = e + self.edge(torch.cat([x[ei[0]], x[ei[1]], e], dim=1))
        return x, e


class GATModel(_Base):
    def __init__(self, cfg: FineTrainConfig, attention: bool = False):
        super().__init__(cfg)
        h = cfg.hidden
        self.pi_n = _mlp([N_CLASSES + 2, h, h])
        self.pi_e = _mlp([3, h, h])
        self.pi_x = _mlp([3, h, h])
        self.intra = nn.ModuleList(
            [GATv2Conv(h, h, heads=cfg.heads, concat=False, edge_dim=h) for _ in range(2 * cfg.rounds)]
        )
        self.inter = nn.ModuleList([_EdgeLayer(h, cfg.heads) for _ in range(cfg.rounds)])
        self.att = nn.MultiheadAttention(h, cfg.heads, batch_first=True) if attention else None

    def forward(self, batch) -> torch.Tensor:
        n_graphs = int(batch.num_graphs)
        # graph positions: region centred, query placed at the centre facing north (+y)
        loc = batch.local
        placed = torch.stack([-loc[:, 1], loc[:, 0]], dim=1)
        pos = torch.where(batch.is_q[:, None], placed, loc)
        x = self.pi_n(self.node_features(batch))
        ea = self.pi_e(_edge_geom(pos, batch.intra_edge_index))
        ex = self.pi_x(_edge_geom(pos, batch.inter_edge_index))
        for r in range(self.cfg.rounds):
            for layer in self.intra[2 * r : 2 * r + 2]:
                x = x + torch.relu(layer(x, batch.intra_edge_index, ea))
            x, ex = self.inter[r](x, batch.inter_edge_index, ex)
        eb = batch.batch[batch.inter_edge_index[0]]
        if self.att is not None:
            psi = _masked_attention_pool(self.att, ex, eb, n_graphs)
        else:
            psi = scatter(ex, eb, dim=0, dim_size=n_graphs, reduce="max")
        return self.head(psi)


def build_model(cfg: FineTrainConfig) -> nn.Module:
    """The model a config names (the signature :func:`flatlandia.checkpoints.load_checkpoint` wants)."""
    if cfg.model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {cfg.model!r}")
    att = cfg.model.endswith("+ATT")
    return MLPModel(cfg, att) if cfg.model.startswith("MLP") else GATModel(cfg, att)


# ----------------------------------------------------------------------------- inference


def is_dense(model: nn.Module) -> bool:
    """Does the model take padded :class:`DenseMaps` (the MLP models) rather than graph batches."""
    return isinstance(model, MLPModel)


def batches(samples, batch_size: int, order: np.ndarray | None = None):
    """Batches of a sample list (torch-geometric) or selections of :class:`DenseMaps` or :class:`GraphSplit`."""
    idx = np.arange(len(samples)) if order is None else order
    for k in range(0, len(idx), batch_size):
        if isinstance(samples, (DenseMaps, GraphSplit)):
            yield samples[idx[k : k + batch_size]]
        else:
            yield Batch.from_data_list([samples[i] for i in idx[k : k + batch_size]])


def to_device(samples, device) -> list[Data] | DenseMaps:
    """Samples (a list of graphs or :class:`DenseMaps`) on ``device``, moved once before the loops;
    on the device they are on already they come back as they are (no copy)."""
    if isinstance(samples, DenseMaps):
        return samples.to(device)
    return [s if same_device(s.y.device, device) else copy.copy(s).to(device) for s in samples]


def same_device(a, b) -> bool:
    """Whether two devices are the same (``cuda`` is the current GPU, ``cuda:0`` one named)."""
    a, b = torch.device(a), torch.device(b)
    if a.type != b.type:
        return False
    if a.type != "cuda" or a.index == b.index:
        return True
    current = torch.cuda.current_device()
    return (current if a.index is None else a.index) == (current if b.index is None else b.index)


@torch.no_grad()
def predict(model: nn.Module, samples, batch_size: int = 256) -> np.ndarray:
    """(N, 3) predictions in the normalised region frame (x, y, theta); samples: a list or DenseMaps,
    on any device (batches go to the model's; samples already there are not copied)."""
    model.eval()
    if is_dense(model) and not isinstance(samples, DenseMaps) and len(samples):
        samples = dense_maps(samples)
    device = device_module.model_device(model)
    out = [model(b.to(device)) for b in batches(samples, batch_size)]
    return torch.cat(out).cpu().numpy() if out else np.zeros((0, 3))


def errors_metres(pred: np.ndarray, samples: list[Data], cfg: FineTrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Position error (m) and heading error (deg) of normalised predictions."""
    y = torch.cat([s.y for s in samples]).cpu().numpy()
    e_m = np.hypot(*(pred[:, :2] - y[:, :2]).T) * cfg.scale_m
    d = pred[:, 2] - y[:, 2]
    e_deg = np.degrees(np.abs(np.arctan2(np.sin(d), np.cos(d))))
    return e_m, e_deg


def to_world(pred: np.ndarray, samples: list[Data], cfg: FineTrainConfig) -> np.ndarray:
    """Normalised predictions back to the scene's metric frame: (N, 3) as x, y (metres), theta."""
    centre = torch.cat([s.centre for s in samples]).cpu().numpy()
    return np.column_stack([pred[:, :2] * cfg.scale_m + centre, pred[:, 2]])
