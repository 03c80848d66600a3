"""demoforge.lib.evaluation.arctic on a tiny fake ARCTIC tree (tests/support/arctic_fixture.py), no real ARCTIC data."""

import json

import numpy as np
import pytest

from demoforge.lib.evaluation.arctic import (
    MANO_TO_OPENPOSE, THESIS_TAKES, ArcticDataset, ArcticError, mano_to_openpose, object_of,
)
from tests.support.arctic_fixture import K_ego, build_arctic_tree, openpose_hand

T = 30
IOI = 2


@pytest.fixture()
def tree(tmp_path):
    return build_arctic_tree(tmp_path / "arctic", seqs=("box_grab_01", "phone_use_01"), T=T, ioi_offset=IOI)


def test_mapping_is_the_standard_permutation():
    assert sorted(MANO_TO_OPENPOSE) == list(range(21))
    # fixed order joint -> MANO(+tips) joint, by name
    assert MANO_TO_OPENPOSE[0] == 0                    # wrist
    assert MANO_TO_OPENPOSE[1:5] == (13, 14, 15, 16)   # thumb: MANO 13-15 + thumb tip (16)
    assert MANO_TO_OPENPOSE[5:9] == (1, 2, 3, 17)      # index: MANO 1-3 + index tip (17)
    assert MANO_TO_OPENPOSE[9:13] == (4, 5, 6, 18)     # middle
    assert MANO_TO_OPENPOSE[13:17] == (10, 11, 12, 19)  # ring: MANO 10-12
    assert MANO_TO_OPENPOSE[17:21] == (7, 8, 9, 20)    # pinky: MANO 7-9
    a = np.arange(21 * 2).reshape(21, 2)
    assert mano_to_openpose(a)[8].tolist() == a[17].tolist()
    assert len(THESIS_TAKES) == 18 and object_of("capsulemachine_use_01") == "capsulemachine"


def test_listing_and_find(tree):
    ds = ArcticDataset(tree)
    assert ds.subjects() == ["s01"]
    assert ds.sequences("s01") == ["box_grab_01", "phone_use_01"]
    assert ds.find("box_grab_01") == ["s01"]
    assert ds.find("ketchup_use_01") == []


def test_load_shapes_frames_images_and_validity(tree):
    ds = ArcticDataset(tree)
    tk = ds.load("s01", "box_grab_01", view=0)
    n = T - 20
    assert tk.joints_cam.shape == (n, 2, 21, 3)
    assert tk.joints_px.shape == (n, 2, 21, 2)
    assert tk.valid.shape == (n, 2) and tk.K.shape == (n, 3, 3)
    assert tk.frame_indices.tolist() == list(range(10, T - 10))       # first/last 10 skipped
    assert tk.image_paths[0].endswith(f"images/s01/box_grab_01/0/{10 + IOI:05d}.jpg")
    assert tk.image_paths[-1].endswith(f"{T - 11 + IOI:05d}.jpg")
    assert tk.object == "box" and tk.subject == "s01" and tk.image_size == (1000, 800)
    np.testing.assert_allclose(tk.K[0], K_ego(10))                   # per-frame K_ego, frame 10
    # fixture: frame 12 left invalid, frame 13 both invalid
    assert tk.valid[2].tolist() == [False, True] and tk.valid[3].tolist() == [False, False]
    assert tk.valid.sum() == 2 * n - 3
    assert "left_valid" in tk.valid_source and "is_valid" in tk.valid_source
    # slot 0 = left: the hand comes back in the fixed order
    np.testing.assert_allclose(tk.joints_cam[0, 0], openpose_hand("left", 10))
    np.testing.assert_allclose(tk.joints_cam[5, 1], openpose_hand("right", 15))
    assert tk.reprojection_error_px() == pytest.approx(0.0, abs=1e-6)
    bl = tk.bone_length_check()
    assert bl["loaded"] < 1e-9 < bl["raw_as_openpose"]


def test_stride_and_allocentric_view(tree):
    ds = ArcticDataset(tree)
    tk = ds.load(None, "phone_use_01", view=1, stride=3)
    assert tk.frame_indices.tolist() == list(range(10, T - 10, 3))
    assert tk.K.shape == (3, 3) and tk.K[0, 0] == 1000.0             # misc intris_mat[view - 1]
    assert tk.image_size == (640, 480)
    assert tk.image_paths[1].endswith(f"images/s01/phone_use_01/1/{13 + IOI:05d}.jpg")
    np.testing.assert_allclose(tk.joints_cam[0, 1], openpose_hand("right", 10) + [0, 0, 0.1])


def test_reindexing_with_distinct_values(tmp_path):
    root = build_arctic_tree(tmp_path / "a", distinct=True)
    tk = ArcticDataset(root).load("s01", "box_grab_01")
    # stored: MANO joint k of the right hand = (k, 100 + k, 1000 + k); left = negated
    for j in range(21):
        k = MANO_TO_OPENPOSE[j]
        assert tk.joints_cam[0, 1, j].tolist() == [k, 100 + k, 1000 + k]
        assert tk.joints_cam[0, 0, j].tolist() == [-k, -100 - k, -1000 - k]
    # named spot checks: thumb tip (4) <- MANO 16, index tip (8) <- 17, pinky MCP (17) <- MANO 7
    assert tk.joints_cam[0, 1, 4, 0] == 16 and tk.joints_cam[0, 1, 8, 0] == 17 and tk.joints_cam[0, 1, 17, 0] == 7
    # joint_order="openpose" keeps the stored order
    tk2 = ArcticDataset(root, joint_order="openpose").load("s01", "box_grab_01")
    assert tk2.joints_cam[0, 1, :, 0].tolist() == list(range(21))


def test_missing_files_are_named(tmp_path):
    with pytest.raises(ArcticError, match="does not exist"):
        ArcticDataset(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ArcticError, match="processed sequences folder"):
        ArcticDataset(tmp_path / "empty")
    root = build_arctic_tree(tmp_path / "a")
    ds = ArcticDataset(root)
    with pytest.raises(ArcticError, match=r"s01/ketchup_use_01\.npy"):
        ds.load("s01", "ketchup_use_01")
    # a missing image is named, with the ioi_offset rule
    img = root / "images" / "s01" / "box_grab_01" / "0" / f"{15 + 2:05d}.jpg"
    img.unlink()
    with pytest.raises(ArcticError, match=f"{15 + 2:05d}.jpg"):
        ds.load("s01", "box_grab_01")
    tk = ds.load("s01", "box_grab_01", require_images=False)
    assert any("1 of 10 images missing" in n for n in tk.notes)
    (root / "meta" / "misc.json").unlink()
    with pytest.raises(ArcticError, match="misc.json"):
        ArcticDataset(root).load("s01", "box_grab_01")


@pytest.mark.parametrize("path, key", [
    (("cam_coord", "joints.left"), "joints.left"),
    (("2d",), "'2d'"),
    (("params", "K_ego"), "K_ego"),
])
def test_missing_keys_are_named(tmp_path, path, key):
    root = build_arctic_tree(tmp_path / "a", drop_keys=(path,))
    with pytest.raises(ArcticError, match=key):
        ArcticDataset(root).load("s01", "box_grab_01")


def test_missing_misc_keys_and_subject(tmp_path):
    root = build_arctic_tree(tmp_path / "a")
    p = root / "meta" / "misc.json"
    misc = json.loads(p.read_text())
    del misc["s01"]["ioi_offset"]
    p.write_text(json.dumps(misc))
    with pytest.raises(ArcticError, match="ioi_offset"):
        ArcticDataset(root).load("s01", "box_grab_01")
    p.write_text(json.dumps({"s02": {}}))
    with pytest.raises(ArcticError, match="'s01'"):
        ArcticDataset(root).load("s01", "box_grab_01")


def test_missing_validity_flags_fall_back(tmp_path):
    root = build_arctic_tree(tmp_path / "a", drop_keys=(("cam_coord", "is_valid"), ("cam_coord", "left_valid"),
                                                        ("cam_coord", "right_valid")))
    tk = ArcticDataset(root).load("s01", "box_grab_01")
    assert tk.valid.all() and tk.valid_source.startswith("none")
