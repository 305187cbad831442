"""Benchmark: pycolmap SfM of the Lund images over several seeds (registration, points, time).

Usage: python benchmarks/bench_sfm_lund.py [--seeds 5] [--threads 1] [--images ../shared/images/lund]
Masks come from the offline segmentation backend. Prints one line per seed and a summary.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from PIL import Image

from flatlandia.images import image_audit, segment, sfm

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--images", default=REPO.parent / "shared" / "images" / "lund")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--mapper", default="global")
    args = ap.parse_args()
    folder = Path(args.images)
    names = [p.name for p in image_audit.list_images(folder)]
    with tempfile.TemporaryDirectory() as tmp:
        masks = Path(tmp) / "masks"
        masks.mkdir()
        backend = segment.make_backend("offline")
        t0 = time.perf_counter()
        for n in names:
            ids, labels = backend.labels(folder / n)
            Image.fromarray(segment.mask_and_classes(ids, labels, [0, 0.95, 1, 1])[0]).save(masks / f"{n}.png")
        print(f"masks: {len(names)} images in {time.perf_counter() - t0:.1f} s")
        full = 0
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            opts = sfm.SfmOptions(seed=seed, num_threads=args.threads, mapper=args.mapper)
            try:
                rec = sfm.run_sfm(folder, names, masks, Path(tmp) / f"seed{seed}", opts, log=lambda *a: None)
                reg, pts, err = rec.num_reg_images(), rec.num_points3D(), rec.compute_mean_reprojection_error()
            except Exception as e:  # report the failure as a row
                reg, pts, err = 0, 0, float("nan")
                print(f"seed {seed}: failed ({e})")
            full += reg == len(names)
            print(
                f"seed {seed}: {reg}/{len(names)} registered, {pts} points, {err:.2f} px, "
                f"{time.perf_counter() - t0:.1f} s"
            )
        print(
            f"all images registered in {full} of {args.seeds} seeds ({args.mapper} mapping, {args.threads} thread(s))"
        )


if __name__ == "__main__":
    main()
