"""Benchmark: rule sfm on the Lund images over several seeds (registration, points, time).

Usage: python benchmarks/bench_sfm_lund.py [--seeds 5] [--threads 1] [--images ../shared/images/lund]
Runs the images audit (flatlandia.images.image_audit.audit_table), masks from the configured
segmentation backend (default: offline) and, per seed, rule sfm's entry function
(flatlandia.images.sfm.reconstruct: SfM, camera cleaning, final bundle adjustment) with the
default config's sfm section (``--mapper`` and ``--threads`` over it). Prints one line per seed
(registered by the mapper, kept after cleaning, points, reprojection error, time) and a summary.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from PIL import Image

from flatlandia import config
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
    images, seg = config.section_defaults("images"), config.section_defaults("segment")
    table = image_audit.audit_table(
        folder,
        images["dedup_threshold"],
        images["missing_gps"],
        min_side_px=images["min_side_px"],
        max_megapixels=images["max_megapixels"],
    )
    names = list(table.loc[table["kept"], "name"])
    # COLMAP on --threads threads (deterministic: 1 thread, as the rule runs it by default)
    options = {**config.section_defaults("sfm"), "mapper": args.mapper, "deterministic": args.threads == 1}
    with tempfile.TemporaryDirectory() as tmp:
        masks = Path(tmp) / "masks"
        masks.mkdir()
        backend = segment.make_backend(seg["backend"], seg["weights"], seg["labels_dir"])
        t0 = time.perf_counter()
        for n in names:
            ids, labels = backend.labels(folder / n)
            mask = segment.mask_and_classes(ids, labels, seg["watermark_box"], seg["dilate_px"])[0]
            Image.fromarray(mask).save(masks / f"{n}.png")
        print(
            f"masks: {len(names)} of {len(table)} images ({backend.name} backend) in {time.perf_counter() - t0:.1f} s"
        )
        full = 0
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            try:
                rec, stats, _ = sfm.reconstruct(
                    folder,
                    table,
                    masks,
                    Path(tmp) / f"seed{seed}",
                    options,
                    seed,
                    args.threads,
                    log=lambda *a: None,
                    native_log=os.devnull,
                )
                s = stats.iloc[0]
                kept, removed, pts = int(s["registered"]), int(s["removed_cameras"]), int(s["points3D"])
                err = float(s["mean_reprojection_error_px"])
            except Exception as e:  # report the failure as a row
                kept, removed, pts, err = 0, 0, 0, float("nan")
                print(f"seed {seed}: failed ({e})")
            full += kept + removed == len(names)
            print(
                f"seed {seed}: {kept + removed}/{len(names)} registered, {kept} kept after cleaning, {pts} points, "
                f"{err:.2f} px, {time.perf_counter() - t0:.1f} s"
            )
        print(
            f"all images registered in {full} of {args.seeds} seeds ({args.mapper} mapping, {args.threads} thread(s))"
        )


if __name__ == "__main__":
    main()
