"""Benchmark: our offline masks against the published Berlin masks (IoU of ignored pixels).

Usage: python benchmarks/bench_masks_berlin.py [--images ../shared/images/berlin]
Prints per image the ignored share (theirs, ours), the IoU and the time per image.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from PIL import Image

from flatlandia.images import segment

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--images", default=REPO.parent / "shared" / "images" / "berlin")
    ap.add_argument("--backend", default="offline")
    args = ap.parse_args()
    folder = Path(args.images)
    backend = segment.make_backend(args.backend)
    ious = []
    for img in sorted((folder / "images").glob("*.jpg")):
        ref = np.asarray(Image.open(folder / "masks" / f"{img.name}.png").convert("L"))
        t0 = time.perf_counter()
        ids, names = backend.labels(img)
        ours, _, shares = segment.mask_and_classes(ids, names, None)
        dt = time.perf_counter() - t0
        iou = segment.ignore_iou(ours, ref)
        if np.any(ref == 0):
            ious.append(iou)
        print(
            f"{img.name}: ignored theirs {np.mean(ref == 0):.3f} ours {np.mean(ours == 0):.3f} "
            f"(people {shares['human']:.3f}, vegetation {shares['nature--vegetation']:.3f}) "
            f"IoU {iou:.3f}  {dt:.1f} s"
        )
    print(f"mean IoU over images whose masks ignore something: {np.mean(ious):.3f}")


if __name__ == "__main__":
    main()
