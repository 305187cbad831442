"""The parts of torch-geometric the learned models use, imported without its dataset zoo.

Why: ``import torch_geometric`` (2.8) imports every subpackage, among them ``datasets``, which
pulls in its LLM toolkit and, with it, ``transformers`` (installed here for the segmentation and
depth backends): CPU in each of the jobs that train or evaluate a learned model, for code none of
them runs (docs/measurements.md, "Start-up costs"). Those two subpackages are marked as loaded (empty modules) before
torch-geometric is imported, unless something imported it already; every model module imports
torch-geometric through this one (tests/test_fine.py checks the classes are the real ones).
"""

from __future__ import annotations

import sys
import types

#: torch-geometric subpackages never used here whose import costs the most
SKIPPED = ("torch_geometric.datasets", "torch_geometric.llm")

if "torch_geometric" not in sys.modules:
    for _name in SKIPPED:
        sys.modules.setdefault(_name, types.ModuleType(_name, "not imported by flatlandia.plumbing.pyg"))

from torch_geometric.data import Batch, Data  # noqa: E402
from torch_geometric.nn import GATConv, GATv2Conv, global_mean_pool  # noqa: E402
from torch_geometric.utils import add_self_loops, scatter, to_dense_batch  # noqa: E402

__all__ = ["Batch", "Data", "GATConv", "GATv2Conv", "add_self_loops", "global_mean_pool", "scatter", "to_dense_batch"]
