"""The torch HaMeR (demoforge.lib.perception.hamer): checkpoint key layout, strict loading, cameras, crops, flips, determinism."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from demoforge.lib.geometry import project_points
from demoforge.lib.perception.hamer.camera import (
    FOCAL_LENGTH, IMAGE_SIZE, boxes_to_crops, cam_crop_to_camera, cam_crop_to_full, crop_images,
    crop_points_to_image,
)
from demoforge.lib.perception.hamer.checkpoint import (
    CheckpointError, load_hamer, read_state_dict, save_random_checkpoint,
)
from demoforge.lib.perception.hamer.decoder import rot6d_to_rotmat
from demoforge.lib.perception.hamer.model import HamerConfig, HamerNet, HamerPredictor
from demoforge.lib.perception.hamer.synthetic import synthetic_mano

TINY = HamerConfig.tiny()


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    path = tmp_path_factory.mktemp("hamer") / "hamer.ckpt"
    sd = save_random_checkpoint(path, TINY, seed=1)
    return path, sd


@pytest.fixture(scope="module")
def predictor(ckpt):
    net, _ = load_hamer(ckpt[0], TINY)
    return HamerPredictor(net, synthetic_mano()[0], device="cpu", batch_size=4)


def test_released_layout_names_and_shapes():
    with torch.device("meta"):
        net = HamerNet(HamerConfig())
    shapes = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    expected = {
        "backbone.patch_embed.proj.weight": (1280, 3, 16, 16),
        "backbone.pos_embed": (1, 193, 1280),
        "backbone.blocks.31.attn.qkv.weight": (3840, 1280),
        "backbone.blocks.31.attn.qkv.bias": (3840,),
        "backbone.blocks.31.mlp.fc1.weight": (5120, 1280),
        "backbone.last_norm.weight": (1280,),
        "mano_head.transformer.to_token_embedding.weight": (1024, 1),
        "mano_head.transformer.pos_embedding": (1, 1, 1024),
        "mano_head.transformer.transformer.layers.5.0.fn.to_qkv.weight": (1536, 1024),
        "mano_head.transformer.transformer.layers.5.1.fn.to_kv.weight": (1024, 1280),
        "mano_head.transformer.transformer.layers.5.1.fn.to_q.weight": (512, 1024),
        "mano_head.transformer.transformer.layers.5.1.fn.to_out.0.weight": (1024, 512),
        "mano_head.transformer.transformer.layers.5.2.fn.net.3.weight": (1024, 1024),
        "mano_head.decpose.weight": (96, 1024),
        "mano_head.decshape.weight": (10, 1024),
        "mano_head.deccam.weight": (3, 1024),
        "mano_head.init_hand_pose": (1, 96),
        "mano_head.init_betas": (1, 10),
        "mano_head.init_cam": (1, 3),
    }
    for k, s in expected.items():
        assert shapes.get(k) == s, k
    assert "backbone.blocks.32.norm1.weight" not in shapes and "backbone.blocks.31.norm1.weight" in shapes
    assert "mano_head.transformer.transformer.layers.6.0.norm.weight" not in shapes
    assert not any("qkv" in k and k.endswith("to_qkv.bias") for k in shapes)  # decoder q/k/v have no bias
    # the tiny test model has exactly the same names
    assert set(HamerNet(TINY).state_dict()) == {k for k in shapes if not _deeper(k, TINY)}


def _deeper(key: str, cfg: HamerConfig) -> bool:
    parts = key.split(".")
    if key.startswith("backbone.blocks."):
        return int(parts[2]) >= cfg.depth
    if key.startswith("mano_head.transformer.transformer.layers."):
        return int(parts[4]) >= cfg.dec_depth
    return False


def test_load_round_trip_and_ignored_training_keys(ckpt):
    path, sd = ckpt
    net, rep = load_hamer(path, TINY)
    assert rep.ok and rep.matched == len(sd)
    assert sorted(rep.ignored) == ["discriminator.D_conv1.weight", "initialized", "mano.joint_map", "mano.v_template"]
    for k, v in net.state_dict().items():
        torch.testing.assert_close(v, sd[k], rtol=0, atol=0)


def test_strict_check_names_missing_and_unexpected_keys(ckpt, tmp_path):
    _, sd = ckpt
    bad = dict(sd)
    del bad["mano_head.deccam.weight"]
    bad["mano_head.extra_head.weight"] = torch.zeros(3)
    torch.save({"state_dict": bad}, tmp_path / "bad.ckpt")
    with pytest.raises(CheckpointError) as e:
        load_hamer(tmp_path / "bad.ckpt", TINY)
    msg = str(e.value)
    assert "1 missing: mano_head.deccam.weight" in msg and "1 unexpected: mano_head.extra_head.weight" in msg
    net, rep = load_hamer(tmp_path / "bad.ckpt", TINY, strict=False)
    assert rep.missing == ["mano_head.deccam.weight"] and rep.unexpected == ["mano_head.extra_head.weight"]
    torch.testing.assert_close(net.state_dict()["mano_head.decpose.weight"], sd["mano_head.decpose.weight"])


def test_shape_mismatch_and_wrong_sizes_are_reported(ckpt):
    with pytest.raises(CheckpointError, match=r"backbone.pos_embed expected \[1, 193, 1280\] found \[1, 193, 64\]"):
        load_hamer(ckpt[0])  # released sizes against the tiny file


def test_unreadable_and_missing_files(tmp_path):
    with pytest.raises(CheckpointError, match="not found.*hamer.ckpt"):
        read_state_dict(tmp_path / "hamer.ckpt")
    (tmp_path / "junk.ckpt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="cannot read"):
        read_state_dict(tmp_path / "junk.ckpt")


def test_lightning_checkpoint_with_yacs_config_loads_safely(tmp_path):
    # the released file's hyper_parameters hold a yacs CfgNode; yacs is not installed here
    ymod, cmod = types.ModuleType("yacs"), types.ModuleType("yacs.config")

    class CfgNode(dict):
        pass

    CfgNode.__module__, CfgNode.__qualname__ = "yacs.config", "CfgNode"
    cmod.CfgNode, ymod.config = CfgNode, cmod
    sys.modules["yacs"], sys.modules["yacs.config"] = ymod, cmod
    try:
        cfg = CfgNode(MODEL=CfgNode(IMAGE_SIZE=256))
        sd = save_random_checkpoint(tmp_path / "h.ckpt", TINY, hyper_parameters={"cfg": cfg})
    finally:
        del sys.modules["yacs"], sys.modules["yacs.config"]
    loaded = read_state_dict(tmp_path / "h.ckpt")
    assert set(sd) <= set(loaded)

    class Evil:
        def __reduce__(self):
            return (print, ("should not run",))

    Evil.__qualname__ = "Evil"

    torch.save({"state_dict": sd, "hyper_parameters": Evil()}, tmp_path / "evil.ckpt")
    with pytest.raises(CheckpointError, match="refusing"):
        read_state_dict(tmp_path / "evil.ckpt")


@settings(max_examples=30, deadline=None)
@given(x=st.lists(st.floats(-3, 3), min_size=6, max_size=6))
def test_rot6d_gives_rotations_whose_first_columns_follow_the_input(x):
    a = np.asarray(x)
    if np.linalg.norm(a[:3]) < 1e-2 or np.linalg.norm(np.cross(a[:3], a[3:])) < 1e-2:
        return
    R = rot6d_to_rotmat(torch.tensor(a)).numpy()
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R[:, 0], a[:3] / np.linalg.norm(a[:3]), atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(s=st.floats(0.3, 2.0), tx=st.floats(-0.3, 0.3), ty=st.floats(-0.3, 0.3), cx=st.floats(50, 1800),
       cy=st.floats(50, 1000), b=st.floats(40, 600), w=st.integers(640, 1920), h=st.integers(480, 1080))
def test_real_intrinsics_conversion_reduces_to_hamers_with_its_virtual_camera(s, tx, ty, cx, cy, b, w, h):
    cam, center, size = np.array([[s, tx, ty]]), np.array([[cx, cy]]), np.array([b])
    f = FOCAL_LENGTH / IMAGE_SIZE * max(w, h)  # demo.py's scaled_focal_length
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])
    np.testing.assert_allclose(cam_crop_to_camera(cam, center, size, K),
                               cam_crop_to_full(cam, center, size, np.array([[w, h]]), f), rtol=1e-9)


@settings(max_examples=40, deadline=None)
@given(s=st.floats(0.3, 2.0), tx=st.floats(-0.3, 0.3), ty=st.floats(-0.3, 0.3), cx=st.floats(50, 600),
       cy=st.floats(50, 400), b=st.floats(40, 300), f=st.floats(300, 1500))
def test_hand_origin_lands_where_the_crop_camera_puts_it(s, tx, ty, cx, cy, b, f):
    """With the real K the MANO origin projects to the same pixel as in HaMeR's crop, and the depth
    scales with the real focal length."""
    cam, center, size = np.array([[s, tx, ty]]), np.array([[cx, cy]]), np.array([b])
    K = np.array([[f, 0, 320.0], [0, f, 240.0], [0, 0, 1]])
    t = cam_crop_to_camera(cam, center, size, K)
    uv_real = project_points(t, K)
    uv_crop = crop_points_to_image(np.zeros((1, 1, 3)), cam, center, size)[:, 0]
    np.testing.assert_allclose(uv_real, uv_crop, atol=1e-6)
    assert t[0, 2] == pytest.approx(2 * f / (b * s))


def test_boxes_expand_to_hamers_aspect_ratio():
    center, size = boxes_to_crops(np.array([[100, 100, 160, 200], [0, 0, 90, 60]]), rescale_factor=2.0)
    np.testing.assert_allclose(center, [[130, 150], [45, 30]])
    np.testing.assert_allclose(size, [200.0, 2 * 90 * 256 / 192])  # tall box: height; wide box: width * 4/3


def test_crop_samples_the_box_and_flips_about_its_centre():
    img = np.zeros((1, 300, 400, 3), np.uint8)
    img[0, 150, 210] = 255  # 10 px right of the crop centre (200, 150)
    args = dict(image_index=torch.tensor([0, 0]), center=torch.tensor([[200.0, 150.0]] * 2),
                size=torch.tensor([256.0, 256.0]))
    crops = crop_images(torch.as_tensor(img), flip=torch.tensor([False, True]), **args)
    bright = crops[:, 0].flatten(1).argmax(1)
    assert [(int(i) // 256, int(i) % 256) for i in bright] == [(128, 138), (128, 118)]
    black = (0 - 0.485) / 0.229
    assert float(crops[0, 0, 0, 0]) == pytest.approx(black, abs=1e-5)


def _image(seed=0, h=240, w=320):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (1, h, w, 3), dtype=np.uint8)


def test_output_shapes_and_empty_batch(predictor):
    imgs = np.concatenate([_image(0), _image(1)])
    K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    boxes = np.array([[100, 80, 160, 150], [150, 60, 200, 130], [10, 10, 50, 60]], float)
    p = predictor.predict(imgs, boxes, [0, 0, 1], [True, False, True], K)
    assert p.joints_cam.shape == (3, 21, 3) and p.joints_px.shape == (3, 21, 2)
    assert p.betas.shape == (3, 10) and p.cam_crop.shape == (3, 3) and p.translation.shape == (3, 3)
    assert np.isfinite(p.joints_cam).all() and (p.joints_cam[..., 2] > 0).all()
    empty = predictor.predict(imgs, np.zeros((0, 4)), [], [], K)
    assert empty.joints_cam.shape == (0, 21, 3)


def test_left_hand_is_the_mirror_of_the_right_hand_in_the_mirrored_image(predictor):
    img = _image(2)
    W = img.shape[2]
    K = np.array([[300.0, 0, (W - 1) / 2], [0, 300.0, 119.5], [0, 0, 1]])
    box = np.array([[90.0, 70.0, 150.0, 160.0]])
    mbox = np.array([[W - 1 - box[0, 2], box[0, 1], W - 1 - box[0, 0], box[0, 3]]])
    r = predictor.predict(img, box, [0], [True], K)
    l_ = predictor.predict(img[:, :, ::-1].copy(), mbox, [0], [False], K)
    np.testing.assert_allclose(l_.joints_px[..., 0], W - 1 - r.joints_px[..., 0], atol=1e-3)
    np.testing.assert_allclose(l_.joints_px[..., 1], r.joints_px[..., 1], atol=1e-3)
    mirror = np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(l_.joints_cam, r.joints_cam * mirror, atol=1e-5)
    # a right hand is not its own mirror: the flip matters
    assert np.abs(l_.joints_model - r.joints_model).max() > 1e-3


def test_deterministic_and_independent_of_batch_size(ckpt, predictor):
    imgs = np.concatenate([_image(3), _image(4)])
    K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    boxes = np.array([[100, 80, 160, 150], [150, 60, 200, 130], [10, 10, 50, 60], [200, 100, 260, 200],
                      [30, 30, 90, 120]], float)
    idx, right = [0, 0, 1, 1, 0], [True, False, True, False, True]
    a = predictor.predict(imgs, boxes, idx, right, K)
    b = predictor.predict(imgs, boxes, idx, right, K)
    np.testing.assert_array_equal(a.joints_cam, b.joints_cam)
    net, _ = load_hamer(ckpt[0], TINY)
    one = HamerPredictor(net, synthetic_mano()[0], device="cpu", batch_size=1).predict(imgs, boxes, idx, right, K)
    np.testing.assert_allclose(one.joints_cam, a.joints_cam, atol=1e-5)
    fit = HamerPredictor(net, synthetic_mano()[0], device="cpu", translation="fit_2d").predict(imgs, boxes, idx, right, K)
    # fitted translation: the 3D joints reproject onto the network's own 2D keypoints better than
    # with the crop camera's closed form (the crop camera is nearly orthographic, K is not)
    rms = lambda p: float(np.sqrt(((project_points(p.joints_cam, K) - p.joints_px) ** 2).mean()))  # noqa: E731
    assert rms(fit) <= rms(a) and rms(fit) < 1.0, (rms(fit), rms(a))


def test_crops_of_many_images_in_any_order_equal_single_crops():
    rng = np.random.default_rng(0)
    imgs = torch.as_tensor(rng.integers(0, 256, (3, 120, 160, 3), dtype=np.uint8))
    idx = torch.tensor([2, 0, 2, 1, 2])
    c = torch.tensor(rng.uniform(0, 160, (5, 2)), dtype=torch.float32)
    s = torch.tensor(rng.uniform(20, 200, 5), dtype=torch.float32)
    fl = torch.tensor([True, False, False, True, True])
    together = crop_images(imgs, idx, c, s, fl)
    for k in range(5):
        alone = crop_images(imgs, idx[k:k + 1], c[k:k + 1], s[k:k + 1], fl[k:k + 1])
        torch.testing.assert_close(together[k:k + 1], alone, atol=1e-5, rtol=0)
