"""SfM bad input and edge cases on real images (small sets of the Lund photos, seconds each)."""

import shutil

import numpy as np
import pytest
from PIL import Image

from flatlandia.images import sfm
from flatlandia.plumbing.errors import InputError

OPTS = sfm.SfmOptions(num_threads=1, max_image_size=800)


@pytest.mark.slow  # the Lund photos
def test_a_folder_with_one_image_is_a_clear_error(lund, tmp_path):
    with pytest.raises(InputError, match="SfM needs at least 3 images, 1 kept"):
        sfm.run_sfm(lund, ["01.jpg"], None, tmp_path / "w", OPTS)


def test_images_that_do_not_overlap_give_a_clear_error(tmp_path):
    rng = np.random.default_rng(0)
    for k in range(3):  # noise images: features but no consistent geometry
        Image.fromarray(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)).save(tmp_path / f"n{k}.jpg")
    with pytest.raises(InputError, match="SfM produced no model"):
        sfm.run_sfm(tmp_path, [f"n{k}.jpg" for k in range(3)], None, tmp_path / "w", OPTS)


@pytest.mark.slow
def test_mixed_image_sizes_reconstruct_with_one_camera_per_size(lund, tmp_path):
    names = [f"{k:02d}.jpg" for k in range(1, 9)]
    for n in names[0::2]:
        shutil.copy(lund / n, tmp_path / n)
    for n in names[1::2]:
        Image.open(lund / n).resize((800, 600)).save(tmp_path / n, quality=95)
    rec = sfm.run_sfm(tmp_path, names, None, tmp_path / "w", sfm.SfmOptions(num_threads=1))
    assert rec.num_reg_images() >= 3
    sizes = {(c.width, c.height) for c in rec.cameras.values()}
    assert sizes == {(1024, 768), (800, 600)}


def test_height_outliers_flag_a_camera_in_the_sky():
    rng = np.random.default_rng(1)
    c = np.column_stack([rng.uniform(0, 100, 30), rng.uniform(0, 20, 30), rng.normal(0, 0.2, 30)])
    c[7, 2] = 25.0  # far above the street
    out = sfm.height_outliers(c, k=6.0)
    assert out[7] and out.sum() == 1
