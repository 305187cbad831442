"""The paper's learned fine-localization baselines: MLP, MLP+ATT, GAT, GAT+ATT (torch-geometric).

Each sample is one query: its local map (GT in metres, or depth, unscaled) with the classes of its
objects, and a region proposal (reference objects, metric frame). The model regresses the camera
pose (x, y, theta) in the region's frame.

Normalisation ("scene scaled into a unit square"): region coordinates are centred on the
proposal's centroid and divided by ``scale_m``; GT query maps are divided by ``scale_m`` too, depth
query maps (median object range 1) are multiplied by ``depth_unit_m / scale_m``, a fixed typical
range, so both map types live in the same units. The loss is ``Δo + w Δθ``: Euclidean position
error in those units plus the absolute wrapped angle (radians). Augmentation: a random rigid
roto-translation of the region together with the target pose (the query stays in its camera
frame), and for depth maps an optional random scale of the query.

Models (``hidden`` = 64 in the paper):
- ``MLP``: Psi_Q = maxpool(Π(query nodes)); Psi = maxpool_j σ3([Psi_Q, Π(region node j)]); ρ -> pose.
- ``MLP+ATT``: a multi-head self-attention layer over the σ3 features before the last max-pool.
- ``GAT``: one graph of query + region nodes; intra-map edges (query fully connected, region
  kNN-``knn``) and inter-map edges between same-class query/region nodes. Edge embedding: length and
  orientation of the segment, inter-map edges computed with the query placed at the region centre
  facing north. ``rounds`` x (2 edge-aware GATv2 layers on intra-map edges, then 1 EGAT-style layer
  on inter-map edges updating nodes and edges); Psi = maxpool(inter-map edge embeddings).
- ``GAT+ATT``: self-attention over the inter-map edge embeddings before the pool.

Batches are torch-geometric batches (one ``Data`` per query); everything is seeded and runs
deterministically on CPU. Checkpoints hold ``{'state_dict', 'config', ...}``.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd
import torch
from torch import nn
from torch_geometric.data import Batch, Data
from torch_geometric.nn import GATv2Conv
from torch_geometric.utils import scatter, to_dense_batch

from flatlandia.data import localmaps

N_CLASSES = 42
MODELS = ("MLP", "MLP+ATT", "GAT", "GAT+ATT")


@dataclass
class FineConfig:
    model: str = "MLP"
    map_type: str = "depth"  # gt | depth
    hidden: int = 64
    heads: int = 4
    rounds: int = 3  # GAT: rounds of (2 intra-map layers + 1 inter-map layer)
    knn: int = 3  # GAT: region kNN for intra-map edges
    epochs: int = 20
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 0.0
    lr_schedule: str = "none"  # none | cosine (to 1% of lr over the epochs)
    scale_m: float = 15.0  # metres per normalised unit (tuned on val: 100 -> 15 m, MLP 5.7 -> 3.6 m)
    depth_unit_m: float = 25.0  # metres assumed per depth-map unit (typical median object range)
    angle_weight: float = 1.0
    augment: bool = True
    aug_rotate_deg: float = 180.0  # max |rotation| of the augmentation (180: any rotation)
    aug_translate: float = 0.25  # max translation (normalised units) of the augmentation
    aug_depth_scale: float = 0.2  # std of log scale jitter of depth query maps (0: none)
    seed: int = 0
    eval_every: int = 1
    extra: dict = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: dict | None) -> FineConfig:
        d = dict(d or {})
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})

    def to_dict(self) -> dict:
        return asdict(self)


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
    q_local: np.ndarray, q_cls, r_xy: np.ndarray, r_cls, cfg: FineConfig, cam_xy=None, theta: float | None = None
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
    ref: pd.DataFrame, queries: pd.DataFrame, proposals: pd.DataFrame, cfg: FineConfig
) -> tuple[list[Data], pd.DataFrame]:
    """Samples of one scene's queries with their proposals; also the kept query rows (same order)."""
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    props = dict(zip(proposals["token"].astype(str), proposals["proposal"]))
    out = []
    for r in queries.itertuples(index=False):
        idx = np.array([pos[int(o)] for o in props.get(str(r.token), []) if int(o) in pos], int)
        q = localmaps.xy(r.gt_local_xy_m if cfg.map_type == "gt" else r.depth_local_xy)
        out.append(make_sample(q, r.classes, ref_xy[idx], ref_cls[idx], cfg, (r.x_m, r.y_m), math.radians(r.theta_deg)))
    return out, queries.reset_index(drop=True)


# ----------------------------------------------------------------------------- dense batches (MLP models)


@dataclass
class DenseMaps:
    """Padded per-query tensors (query objects, region objects, target) for the MLP models.

    Why: collating torch-geometric batches at every step costs about as much as the MLP step; the
    whole split is padded once and a batch is a row selection, trimmed to its longest map.
    """

    q_cls: torch.Tensor  # (N, Lq) class ids (0 on padding)
    q_xy: torch.Tensor  # (N, Lq, 2) query objects, normalised camera frame
    q_mask: torch.Tensor  # (N, Lq) True on real objects
    r_cls: torch.Tensor  # (N, Lr)
    r_xy: torch.Tensor  # (N, Lr, 2) region objects, normalised region frame
    r_mask: torch.Tensor  # (N, Lr)
    y: torch.Tensor  # (N, 3) target pose

    @property
    def num_graphs(self) -> int:
        return int(self.y.shape[0])

    def __len__(self) -> int:
        return self.num_graphs

    def __getitem__(self, idx) -> DenseMaps:
        idx = torch.as_tensor(idx, dtype=torch.long)
        lq = max(int(self.q_mask[idx].sum(1).max()), 1) if len(idx) else 1
        lr = max(int(self.r_mask[idx].sum(1).max()), 1) if len(idx) else 1
        return DenseMaps(
            self.q_cls[idx, :lq],
            self.q_xy[idx, :lq],
            self.q_mask[idx, :lq],
            self.r_cls[idx, :lr],
            self.r_xy[idx, :lr],
            self.r_mask[idx, :lr],
            self.y[idx],
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
    return DenseMaps(*parts, y=b.y)


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
        return torch.zeros(n_graphs, h.shape[1], dtype=h.dtype)
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
    def __init__(self, cfg: FineConfig):
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
    def __init__(self, cfg: FineConfig, attention: bool = False):
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
    def __init__(self, cfg: FineConfig, attention: bool = False):
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


def build_model(cfg: FineConfig) -> nn.Module:
    if cfg.model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {cfg.model!r}")
    att = cfg.model.endswith("+ATT")
    return MLPModel(cfg, att) if cfg.model.startswith("MLP") else GATModel(cfg, att)


def n_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


# ----------------------------------------------------------------------------- loss, augmentation


def angle_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Absolute wrapped angle difference in radians, in [0, pi]."""
    d = a - b
    return torch.atan2(torch.sin(d), torch.cos(d)).abs()


def pose_loss(pred: torch.Tensor, target: torch.Tensor, angle_weight: float = 1.0) -> torch.Tensor:
    """Mean of Δo (Euclidean position error, normalised units) + w Δθ (radians)."""
    d_o = (pred[:, :2] - target[:, :2]).norm(dim=1)
    return (d_o + angle_weight * angle_distance(pred[:, 2], target[:, 2])).mean()


def augment(batch, cfg: FineConfig, gen: torch.Generator):
    """Random rigid roto-translation of every region (and its target pose); query maps unchanged
    but for an optional random scale of depth maps. Takes a graph batch or :class:`DenseMaps`
    (same random draws for the same samples); returns a new one."""
    n_graphs = int(batch.num_graphs)
    phi = (torch.rand(n_graphs, generator=gen) * 2 - 1) * math.radians(cfg.aug_rotate_deg)
    tr = (torch.rand(n_graphs, 2, generator=gen) * 2 - 1) * cfg.aug_translate
    c, s = torch.cos(phi), torch.sin(phi)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)  # (B, 2, 2)
    scale = (
        torch.exp(torch.randn(n_graphs, generator=gen) * cfg.aug_depth_scale)
        if cfg.map_type == "depth" and cfg.aug_depth_scale > 0
        else None
    )
    y = batch.y.clone()
    y[:, :2] = torch.einsum("bij,bj->bi", rot, y[:, :2]) + tr
    y[:, 2] = torch.atan2(torch.sin(y[:, 2] + phi), torch.cos(y[:, 2] + phi))
    if isinstance(batch, DenseMaps):
        r_xy = torch.einsum("bij,blj->bli", rot, batch.r_xy) + tr[:, None]
        q_xy = batch.q_xy * scale[:, None, None] if scale is not None else batch.q_xy
        return DenseMaps(batch.q_cls, q_xy, batch.q_mask, batch.r_cls, r_xy, batch.r_mask, y)
    b = copy.copy(batch)
    g = batch.batch
    loc = batch.local
    moved = torch.einsum("nij,nj->ni", rot[g], loc) + tr[g]
    qloc = loc * scale[g][:, None] if scale is not None else loc
    b.local = torch.where(batch.is_q[:, None], qloc, moved)
    b.y = y
    return b


# ----------------------------------------------------------------------------- training


def set_determinism(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)


def _is_dense(model: nn.Module) -> bool:
    return isinstance(model, MLPModel)


def _batches(samples, batch_size: int, order: np.ndarray | None = None):
    """Batches of a sample list (torch-geometric) or row selections of :class:`DenseMaps`."""
    idx = np.arange(len(samples)) if order is None else order
    for k in range(0, len(idx), batch_size):
        if isinstance(samples, DenseMaps):
            yield samples[idx[k : k + batch_size]]
        else:
            yield Batch.from_data_list([samples[i] for i in idx[k : k + batch_size]])


@torch.no_grad()
def predict(model: nn.Module, samples, batch_size: int = 256) -> np.ndarray:
    """(N, 3) predictions in the normalised region frame (x, y, theta); samples: a list or DenseMaps."""
    model.eval()
    if _is_dense(model) and not isinstance(samples, DenseMaps) and len(samples):
        samples = dense_maps(samples)
    out = [model(b) for b in _batches(samples, batch_size)]
    return torch.cat(out).numpy() if out else np.zeros((0, 3))


def errors_metres(pred: np.ndarray, samples: list[Data], cfg: FineConfig) -> tuple[np.ndarray, np.ndarray]:
    """Position error (m) and heading error (deg) of normalised predictions."""
    y = torch.cat([s.y for s in samples]).numpy()
    e_m = np.hypot(*(pred[:, :2] - y[:, :2]).T) * cfg.scale_m
    d = pred[:, 2] - y[:, 2]
    e_deg = np.degrees(np.abs(np.arctan2(np.sin(d), np.cos(d))))
    return e_m, e_deg


def to_world(pred: np.ndarray, samples: list[Data], cfg: FineConfig) -> np.ndarray:
    centre = torch.cat([s.centre for s in samples]).numpy()
    return np.column_stack([pred[:, :2] * cfg.scale_m + centre, pred[:, 2]])


def train(train_samples: list[Data], val_samples: list[Data], cfg: FineConfig, log=None, progress=None) -> dict:
    """Adam on batches; the best-on-validation (median position error) weights are kept.

    Returns {'model', 'state_dict', 'config', 'history', 'best_epoch', 'best_val_median_m', 'seconds'}.
    """
    set_determinism(cfg.seed)
    model = build_model(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, fused=True)
    sched = (
        torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.epochs, 1), eta_min=0.01 * cfg.lr)
        if cfg.lr_schedule == "cosine"
        else None
    )
    gen = torch.Generator().manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    history, best, best_state, best_epoch = [], float("inf"), None, -1
    t0 = time.perf_counter()
    data, val_data = train_samples, val_samples
    if _is_dense(model):  # padded once; a batch is a row selection
        data = dense_maps(train_samples)
        val_data = dense_maps(val_samples) if val_samples else val_samples
    epochs = range(cfg.epochs)
    for ep in progress(epochs) if progress else epochs:
        model.train()
        tot, n = 0.0, 0
        for batch in _batches(data, cfg.batch_size, rng.permutation(len(train_samples))):
            if cfg.augment:
                batch = augment(batch, cfg, gen)
            opt.zero_grad()
            loss = pose_loss(model(batch), batch.y, cfg.angle_weight)
            loss.backward()
            opt.step()
            tot += float(loss.detach()) * int(batch.num_graphs)
            n += int(batch.num_graphs)
        if sched is not None:
            sched.step()
        rec = {"epoch": ep, "train_loss": tot / max(n, 1)}
        if val_samples and (ep % cfg.eval_every == 0 or ep == cfg.epochs - 1):
            e_m, e_deg = errors_metres(predict(model, val_data), val_samples, cfg)
            rec.update(val_median_m=float(np.median(e_m)), val_median_deg=float(np.median(e_deg)))
            if rec["val_median_m"] < best:
                best, best_epoch = rec["val_median_m"], ep
                best_state = copy.deepcopy(model.state_dict())
        history.append(rec)
        if log is not None:
            log.info("epoch %d: %s", ep, {k: round(v, 4) for k, v in rec.items() if k != "epoch"})
    if best_state is None:
        best_state = copy.deepcopy(model.state_dict())
    model.load_state_dict(best_state)
    return {
        "model": model,
        "state_dict": best_state,
        "config": cfg.to_dict(),
        "history": history,
        "best_epoch": best_epoch,
        "best_val_median_m": best,
        "seconds": time.perf_counter() - t0,
    }


def save_checkpoint(result: dict, path) -> None:
    """torch.save({'state_dict', 'config', 'history', 'best_epoch', 'best_val_median_m'}) atomically."""
    from flatlandia.io import atomic_path

    with atomic_path(path) as tmp:
        torch.save(
            {
                k: result[k]
                for k in ("state_dict", "config", "history", "best_epoch", "best_val_median_m", "seconds")
                if k in result
            },
            tmp,
        )


def load_checkpoint(path) -> tuple[nn.Module, FineConfig]:
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = FineConfig.from_dict(ck["config"])
    model = build_model(cfg)
    model.load_state_dict(ck["state_dict"])
    model.eval()
    return model, cfg


def checkpoint_info(path) -> dict:
    """The bookkeeping of a checkpoint: config, best epoch and validation median, training seconds."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    return {k: ck.get(k) for k in ("config", "best_epoch", "best_val_median_m", "seconds")}


def evaluate_model(
    model: nn.Module,
    cfg: FineConfig,
    ref: pd.DataFrame,
    queries: pd.DataFrame,
    proposals: pd.DataFrame,
    method: str | None = None,
) -> pd.DataFrame:
    """Per-query error rows (same columns as the solver's) for one scene; query time is the
    single-query inference time (batch of one, after building the sample)."""
    from flatlandia.fine import evaluation

    samples, kept = samples_from_queries(ref, queries, proposals, cfg)
    ref_cls = ref["class_id"].to_numpy()
    pos = {int(o): k for k, o in enumerate(ref["obj_idx"].to_numpy())}
    props = dict(zip(proposals["token"].astype(str), proposals["proposal"]))
    strat = dict(zip(proposals["token"].astype(str), proposals["strategy"]))
    lat = float(ref["lat"].mean())
    rows = []
    model.eval()
    for s, r in zip(samples, kept.itertuples(index=False)):
        t0, c0 = time.perf_counter(), time.process_time()
        with torch.no_grad():
            p = model(Batch.from_data_list([s])).numpy()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        x, y, th = to_world(p, [s], cfg)[0]
        e_m, e_deg = evaluation.pose_errors(x, y, th, r.x_m, r.y_m, math.radians(r.theta_deg))
        idx = np.array([pos[int(o)] for o in props.get(str(r.token), []) if int(o) in pos], int)
        rows.append(
            {
                "scene": str(r.scene),
                "token": str(r.token),
                "method": method or cfg.model,
                "map_type": cfg.map_type,
                "strategy": strat.get(str(r.token), "none"),
                "n_objects": int(r.n_objects),
                "proposal_size": int(len(idx)),
                "solvable": bool(evaluation.solvable(r.classes, ref_cls[idx])) if len(idx) else False,
                "x": float(x),
                "y": float(y),
                "theta_deg": float(math.degrees(th)),
                "error_m": float(e_m),
                "error_deg": float(e_deg),
                "error_paper_m": float(evaluation.paper_metres(e_m, lat)),
                "confidence": float("nan"),
                "n_inliers": 0,
                "n_correct_inliers": 0,
                "seconds": float(dt),
                "cpu_seconds": float(dc),
            }
        )
    return pd.DataFrame(rows)
