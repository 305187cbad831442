"""The learned backends run for real: tiny, randomly initialised Mask2Former (Vistas classes) and
Depth-Anything models of the real architectures, saved with save_pretrained (nothing downloaded),
on Lund images (the fixture lund). Outputs are controlled through the class and depth head biases."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from PIL import Image
from scipy import ndimage
from snakemake_runner import smk

from flatlandia.classes import CLASSES
from flatlandia.images import depth, segment
from flatlandia.images.image_queries import View
from flatlandia.plumbing.errors import InputError

IMAGES = ["01.jpg", "15.jpg", "29.jpg"]  # geotagged, ~170 m apart: enough for the images audit
#: the 65 classes of the public Mask2Former Vistas checkpoints, by their readable names
VISTAS_V12 = [n for n in segment.VISTAS_V12_READABLE if n != "Unlabeled"]
WATERMARK = [0.0, 0.95, 1.0, 1.0]


def save_mask2former(folder: Path, names: list[str], winner: str | None = None) -> Path:
    """A tiny Mask2Former (Swin backbone) with ``names`` as classes; ``winner``: every query votes for it."""
    from transformers import (
        Mask2FormerConfig,
        Mask2FormerForUniversalSegmentation,
        Mask2FormerImageProcessorPil,
        SwinConfig,
    )

    torch.manual_seed(0)
    backbone = SwinConfig(
        embed_dim=16,
        depths=[1, 1, 1, 1],
        num_heads=[1, 1, 1, 1],
        window_size=4,
        out_features=["stage1", "stage2", "stage3", "stage4"],
    )
    config = Mask2FormerConfig(
        backbone_config=backbone,
        feature_size=32,  # GroupNorm(32) in the pixel decoder: multiples of 32
        mask_feature_size=32,
        hidden_dim=32,
        encoder_feedforward_dim=32,
        encoder_layers=1,
        decoder_layers=2,
        num_attention_heads=2,
        dim_feedforward=32,
        num_queries=4,
        id2label=dict(enumerate(names)),
        label2id={n: i for i, n in enumerate(names)},
    )
    model = Mask2FormerForUniversalSegmentation(config).eval()
    if winner is not None:
        vote_for(model, names.index(winner))
    model.save_pretrained(folder)
    Mask2FormerImageProcessorPil(size={"shortest_edge": 128, "longest_edge": 192}).save_pretrained(folder)
    return folder


def vote_for(model, class_id: int) -> None:
    """Every query classifies as ``class_id`` whatever the image: the semantic map is that class."""
    with torch.no_grad():
        model.class_predictor.weight.zero_()
        model.class_predictor.bias.fill_(-10.0)
        model.class_predictor.bias[class_id] = 10.0


def save_depth_anything(folder: Path, constant: float | None = None) -> Path:
    """A tiny Depth-Anything (DINOv2 backbone); ``constant``: the head predicts that value everywhere."""
    from transformers import DepthAnythingConfig, DepthAnythingForDepthEstimation, Dinov2Config, DPTImageProcessorPil

    torch.manual_seed(0)
    backbone = Dinov2Config(
        image_size=56,
        patch_size=14,
        hidden_size=16,
        num_hidden_layers=4,
        num_attention_heads=2,
        intermediate_size=32,
        out_indices=[1, 2, 3, 4],
        reshape_hidden_states=False,
    )
    config = DepthAnythingConfig(
        backbone_config=backbone,
        reassemble_hidden_size=16,
        neck_hidden_sizes=[8, 8, 16, 16],
        fusion_hidden_size=8,
        head_hidden_size=8,
    )
    model = DepthAnythingForDepthEstimation(config).eval()
    if constant is not None:
        with torch.no_grad():
            model.head.conv3.weight.zero_()
            model.head.conv3.bias.fill_(constant)
    model.save_pretrained(folder)
    DPTImageProcessorPil(
        size={"height": 70, "width": 70}, keep_aspect_ratio=True, ensure_multiple_of=14, resample=3
    ).save_pretrained(folder)
    return folder


@pytest.fixture(scope="module")
def vistas_model(tmp_path_factory):
    return save_mask2former(tmp_path_factory.mktemp("m2f"), VISTAS_V12)


@pytest.fixture(scope="module")
def backend(vistas_model):
    return segment.make_backend("transformers", weights=str(vistas_model))


@pytest.mark.slow  # the Lund photos
def test_mask2former_labels_every_pixel_of_lund_images(backend, lund):
    assert backend.names == [segment.VISTAS_V12_READABLE[n] for n in VISTAS_V12]  # readable -> label names
    for name in IMAGES[:2]:
        ids, names = backend.labels(lund / name)
        assert ids.shape == (768, 1024) and ids.dtype == np.int32
        assert 0 <= ids.min() and ids.max() < len(names) == 65


@pytest.mark.parametrize(
    ("winner", "flatlandia_class", "masked"),
    [
        ("Street Light", "object--street-light", False),
        ("Traffic Sign (Front)", "object--traffic-sign", False),
        ("Lane Marking - Crosswalk", "crosswalk-zebra", False),
        ("Traffic Light", "object--traffic-light--general-upright", False),
        ("Building", None, False),
        ("Person", None, True),
        ("Car", None, True),
        ("Ego Vehicle", None, True),
    ],
)
@pytest.mark.slow  # the Lund photos
def test_vistas_classes_map_to_flatlandia_classes_and_masks(backend, lund, winner, flatlandia_class, masked):
    vote_for(backend.model, VISTAS_V12.index(winner))
    ids, names = backend.labels(lund / IMAGES[0])
    assert (ids == VISTAS_V12.index(winner)).all()
    mask, cls, shares = segment.mask_and_classes(ids, names, WATERMARK)
    body = slice(0, 729)  # above the watermark strip (rows 730-767)
    assert (mask[730:] == 0).all() and (cls[730:] == segment.NOT_AN_OBJECT).all()
    assert (mask[body] == (0 if masked else 255)).all()
    want = segment.NOT_AN_OBJECT if flatlandia_class is None else CLASSES.index(flatlandia_class)
    assert (cls[body] == want).all()
    assert shares["objects"] == pytest.approx(0.0 if flatlandia_class is None else 1 - shares["watermark"])


def test_a_checkpoint_without_vistas_classes_is_refused(tmp_path):
    save_mask2former(tmp_path, ["wall", "sky", "person"])  # ADE20k-style names
    with pytest.raises(InputError, match="not Mapillary Vistas labels"):
        segment.make_backend("transformers", weights=str(tmp_path))


def test_label_map_upsamples_scores_to_the_image_size():
    scores = torch.zeros(3, 4, 6)
    scores[1, :, :3] = 1.0  # left half: class 1
    scores[2, :, 3:] = 1.0  # right half: class 2
    ids = segment.label_map(scores, (40, 60))
    assert ids.shape == (40, 60)
    assert (ids[:, :30] == 1).all() and (ids[:, 30:] == 2).all()  # the border stays in the middle


def test_readable_names_of_the_public_checkpoints_miss_known_classes():
    missing = segment.missing_classes(segment.vistas_names(dict(enumerate(VISTAS_V12))))
    assert "object--street-light" not in missing and "object--traffic-sign" not in missing
    assert "marking--discrete--arrow--left" in missing and "object--sign--store" in missing  # v2.0 only
    assert len(missing) == 22  # of 42: the reference maps' store signs (619 objects) among them


def test_dilation_grows_moving_things_only():
    names = ["void", "human--person", "nature--sky", "object--support--pole"]
    ids = np.zeros((60, 80), np.int32)
    ids[:10] = 2  # sky strip
    ids[30:40, 30:36] = 1  # a person
    ids[20:50, 40:42] = 3  # a pole 4 px right of the person
    pole = CLASSES.index("object--support--pole")
    mask0, cls0, _ = segment.mask_and_classes(ids, names, None)
    mask, cls, shares = segment.mask_and_classes(ids, names, None, dilate_px=5)
    disk = np.hypot(*np.mgrid[-5:6, -5:6]) <= 5
    person = ndimage.binary_dilation(ids == 1, structure=disk)
    assert ((mask == 0) == (person | (ids == 2))).all()  # the person grows by a 5 px disk, the sky does not
    assert (mask0 == 0).sum() == 10 * 80 + 60
    assert (cls[person] == segment.NOT_AN_OBJECT).all() and (cls0[30:40, 40] == pole).all()  # pole rim given up
    assert (cls[20:25, 40:42] == pole).all() and (cls[30:40, 41] == pole).all()
    assert shares["masked"] == pytest.approx((mask == 0).mean())


@pytest.mark.slow  # the published data (flat_root)
def test_segment_rule_with_the_transformers_backend(repo, flat_root, lund, tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in IMAGES:
        shutil.copy(lund / name, photos / name)
    weights = save_mask2former(tmp_path / "m2f", VISTAS_V12, winner="Pole")
    sheet = tmp_path / "scenes.tsv"
    sheet.write_text(f"scene\tsource\tcity\tname\tpath\turl\tsubfolder\nmine\timages\tLund\tmine\t{photos}\t\t\n")
    res = smk(
        repo,
        tmp_path,
        "--cores",
        "1",
        "results/mine/segment/segment_stats.parquet",
        "--config",
        f"flatlandia_root={flat_root}",
        f"scenes={sheet}",
        f"segment={{backend: transformers, weights: {weights}}}",
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    stats = pd.read_parquet(tmp_path / "results/mine/segment/segment_stats.parquet")
    assert sorted(stats["name"]) == IMAGES and (stats["backend"] == "transformers").all()
    assert np.allclose(stats["objects"], 1 - stats["watermark"]) and np.allclose(stats["masked"], stats["watermark"])
    for name in IMAGES:
        mask = np.asarray(Image.open(tmp_path / f"results/mine/segment/masks/{name}.png"))
        cls = np.asarray(Image.open(tmp_path / f"results/mine/segment/classes/{name}.png"))
        assert mask.shape == cls.shape == (768, 1024)
        assert (mask[:729] == 255).all() and (cls[:729] == CLASSES.index("object--support--pole")).all()


# ----------------------------------------------------------------------- depth
def _view(name: str, depths: np.ndarray) -> tuple[View, dict[int, np.ndarray]]:
    """A camera at the origin looking down +z, observing points at ``depths`` spread over the image."""
    K = np.array([[800.0, 0, 512], [0, 800.0, 384], [0, 0, 1]])
    rng = np.random.default_rng(1)
    xy = np.column_stack([rng.uniform(0, 1024, len(depths)), rng.uniform(0, 768, len(depths))])
    rays = np.linalg.solve(K, np.column_stack([xy, np.ones(len(depths))]).T).T
    xyz = rays * depths[:, None]
    ids = np.arange(len(depths), dtype=np.int64)
    return View(name, K, np.eye(3), np.zeros(3), 1024, 768, ids, xy), dict(enumerate(xyz))


@pytest.mark.slow  # the Lund photos
def test_depth_anything_predicts_at_the_camera_size(lund, tmp_path):
    model = depth.MonocularDepth(str(save_depth_anything(tmp_path)))
    pred = model.predict(lund / IMAGES[0], (768, 1024))
    assert pred.shape == (768, 1024) and np.isfinite(pred).all() and (pred >= 0).all()  # ReLU head


@pytest.mark.parametrize("inverse", [True, False])
@pytest.mark.slow  # the Lund photos
def test_monocular_depth_is_scaled_to_the_sfm_depths(lund, tmp_path, inverse):
    c = 0.25
    model = depth.MonocularDepth(str(save_depth_anything(tmp_path, constant=c)), inverse=inverse)
    view, xyz = _view(IMAGES[0], np.full(40, 3.0 / c if inverse else 3.0 * c))
    dm = model.scaled_map(view, lund / IMAGES[0], xyz)
    assert dm.shape == (768, 1024)
    # the known scale: depth = 3 / prediction (inverse) or 3 * prediction
    assert np.allclose(dm, 3.0 / c if inverse else 3.0 * c)


@pytest.mark.slow  # the Lund photos
def test_queries_lifter_puts_detections_at_the_scaled_depth(lund, tmp_path):
    weights = save_depth_anything(tmp_path, constant=0.5)
    depths = np.linspace(4.0, 20.0, 41)  # median 12
    view, xyz = _view(IMAGES[1], depths)
    lift = depth.make_lifter("transformers", xyz, images_dir=str(lund), weights=str(weights), inverse=True)
    box = [600.0, 300.0, 700.0, 500.0]
    X = lift(view, box)
    ray = np.linalg.solve(view.K, [650.0, 400.0, 1.0])
    assert np.allclose(X, ray * 12.0)  # a constant prediction: every pixel at the median SfM depth
    assert lift(view, [0.0, 0.0, 5.0, 5.0])[2] == pytest.approx(12.0)
