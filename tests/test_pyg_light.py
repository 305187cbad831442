"""The learned models import torch-geometric through flatlandia.plumbing.pyg: the real classes, without its
dataset zoo (and the transformers import it pulls in)."""

import subprocess
import sys


def test_the_model_modules_get_torch_geometric_without_its_datasets():
    code = (
        "import sys\n"
        "from flatlandia.fine import models, training\n"
        "from flatlandia.coarse import retrieval\n"
        "from flatlandia.plumbing import pyg\n"
        "assert pyg.GATv2Conv.__module__.startswith('torch_geometric.nn'), pyg.GATv2Conv.__module__\n"
        "assert pyg.Batch.__module__.startswith('torch_geometric.data')\n"
        "assert 'transformers' not in sys.modules, 'torch-geometric imported its LLM toolkit'\n"
        "print('ok')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]
