"""MANO forward kinematics in torch (demoforge.lib.perception.hamer.mano) against hand-computed cases on a synthetic model."""

from __future__ import annotations

import pickle
import sys
import types

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from demoforge.lib.perception.hamer.mano import (
    MANO_TIP_VERTEX_IDS, MANO_TO_OPENPOSE, MANOError, ManoLayer, axis_angle_to_rotmat, load_mano_model,
)
from demoforge.lib.perception.hamer.synthetic import synthetic_mano, write_synthetic_mano
from demoforge.lib.joints import PARENTS

torch.set_default_dtype(torch.float32)
MODEL, REST = synthetic_mano(seed=0)
MODEL_PD, _ = synthetic_mano(seed=0, posedirs_scale=0.01)
LAYER = ManoLayer(MODEL, dtype=torch.float64)
LAYER_PD = ManoLayer(MODEL_PD, dtype=torch.float64)
# openpose index of each MANO joint (0..15) and tip (16..20)
OP_OF = {m: j for j, m in enumerate(MANO_TO_OPENPOSE)}


def run(layer, rot16, betas=None):
    rot = torch.as_tensor(np.asarray(rot16), dtype=torch.float64).reshape(-1, 16, 3, 3)
    v, j = layer(rot[:, 0], rot[:, 1:], None if betas is None else torch.as_tensor(betas, dtype=torch.float64))
    return v.numpy(), j.numpy()


def identity(n=1):
    return np.broadcast_to(np.eye(3), (n, 16, 3, 3)).copy()


rotations = st.lists(st.floats(-np.pi, np.pi), min_size=3, max_size=3).map(lambda a: Rotation.from_rotvec(a).as_matrix())


def test_rest_pose_gives_template_joints_in_mediapipe_order():
    _, j = run(LAYER, identity())
    np.testing.assert_allclose(j[0], REST, atol=1e-12)
    # tips are the smplx fingertip vertices, at openpose 4 / 8 / 12 / 16 / 20
    for op, vid in zip((4, 8, 12, 16, 20), MANO_TIP_VERTEX_IDS):
        np.testing.assert_allclose(j[0, op], MODEL.v_template[vid], atol=1e-12)
    # the re-indexed skeleton follows demoforge's tree: every bone of demoforge.lib.joints is a MANO bone
    assert j.shape == (1, 21, 3)
    # index finger (openpose 5-8) = MANO joints 1, 2, 3 then the index tip
    np.testing.assert_allclose(j[0, 5:8], MODEL.v_template[1:4], atol=1e-12)


def test_one_joint_rotation_moves_only_its_finger_about_that_joint():
    R = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    rot = identity()
    rot[0, 1] = R  # MANO joint 1 = index MCP
    _, j = run(LAYER, rot)
    J1 = REST[5]
    expected = REST.copy()
    expected[6:9] = J1 + (REST[6:9] - J1) @ R.T  # index PIP, DIP, tip rotate about the MCP
    np.testing.assert_allclose(j[0], expected, atol=1e-12)
    # hand-computed with numbers: a 90 degree turn about y maps +x to -z
    bone = REST[6] - J1
    np.testing.assert_allclose(j[0, 6] - J1, [bone[2], bone[1], -bone[0]], atol=1e-12)


def test_chained_rotations_compose_down_the_finger():
    Ra = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    Rb = Rotation.from_euler("z", 45, degrees=True).as_matrix()
    rot = identity()
    rot[0, 4], rot[0, 5] = Ra, Rb  # middle MCP, middle PIP
    _, j = run(LAYER, rot)
    M, P = REST[9], REST[10]
    P_new = M + Ra @ (P - M)
    np.testing.assert_allclose(j[0, 10], P_new, atol=1e-12)
    np.testing.assert_allclose(j[0, 11], P_new + Ra @ Rb @ (REST[11] - P), atol=1e-12)
    np.testing.assert_allclose(j[0, 12], P_new + Ra @ Rb @ (REST[12] - P), atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(R0=rotations)
def test_global_orientation_rotates_the_hand_about_the_wrist(R0):
    rot = identity()
    rot[0, 0] = R0
    _, j = run(LAYER, rot)
    J0 = REST[0]
    np.testing.assert_allclose(j[0], J0 + (REST - J0) @ R0.T, atol=1e-10)


def test_betas_shift_joints_by_their_shape_directions():
    betas = np.linspace(-2, 2, 10)[None]
    _, j = run(LAYER, identity(), betas)
    # J_regressor picks vertex m for joint m; tips are vertices: both move by shapedirs @ betas
    vid = [m if m < 16 else MANO_TIP_VERTEX_IDS[m - 16] for m in MANO_TO_OPENPOSE]
    np.testing.assert_allclose(j[0], REST + MODEL.shapedirs[vid] @ betas[0], atol=1e-12)


def test_pose_correctives_use_R_minus_identity():
    R = Rotation.from_euler("x", 40, degrees=True).as_matrix()
    rot = identity()
    rot[0, 1] = R
    v, j = run(LAYER_PD, rot)
    feature = np.zeros(135)
    feature[:9] = (R - np.eye(3)).ravel()  # joint 1 comes first in (R_i - I) for i = 1..15
    tip = MANO_TIP_VERTEX_IDS[1]
    corrected = MODEL_PD.v_template[tip] + MODEL_PD.posedirs[tip] @ feature
    J1 = REST[5]
    np.testing.assert_allclose(j[0, 8], J1 + R @ (corrected - J1), atol=1e-12)
    # joints come from the unposed shape: correctives do not move them
    np.testing.assert_allclose(j[0, 6], J1 + R @ (REST[6] - J1), atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_random_poses_keep_bone_lengths(seed):
    rng = np.random.default_rng(seed)
    rot = Rotation.from_rotvec(rng.uniform(-1.5, 1.5, (16, 3))).as_matrix()[None]
    _, j = run(LAYER, rot)
    bones = lambda p: np.linalg.norm(p[1:] - p[PARENTS[1:]], axis=-1)  # noqa: E731
    np.testing.assert_allclose(bones(j[0]), bones(REST), atol=1e-10)


def test_batch_matches_single_and_float32_is_close():
    rng = np.random.default_rng(3)
    rot = Rotation.from_rotvec(rng.uniform(-1, 1, (4 * 16, 3))).as_matrix().reshape(4, 16, 3, 3)
    betas = rng.normal(size=(4, 10))
    _, jb = run(LAYER, rot, betas)
    for i in range(4):
        np.testing.assert_allclose(jb[i], run(LAYER, rot[i:i + 1], betas[i:i + 1])[1][0], atol=1e-12)
    l32 = ManoLayer(MODEL)
    _, j32 = l32(torch.tensor(rot[:, 0], dtype=torch.float32), torch.tensor(rot[:, 1:], dtype=torch.float32),
                 torch.tensor(betas, dtype=torch.float32))
    np.testing.assert_allclose(j32.numpy(), jb, atol=1e-5)


@settings(max_examples=25, deadline=None)
@given(aa=st.lists(st.floats(-3, 3), min_size=3, max_size=3))
def test_axis_angle_matches_scipy(aa):
    R = axis_angle_to_rotmat(torch.tensor(aa, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(R, Rotation.from_rotvec(aa).as_matrix(), atol=1e-10)


@pytest.mark.parametrize("name", ["m.pkl", "m.npz"])
def test_model_file_round_trip(tmp_path, name):
    write_synthetic_mano(tmp_path / name, MODEL_PD)
    m = load_mano_model(tmp_path / name)
    for k in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights"):
        np.testing.assert_array_equal(getattr(m, k), getattr(MODEL_PD, k))
    assert m.parents.tolist() == MODEL_PD.parents.tolist()


def test_official_pickle_with_chumpy_arrays_loads_without_chumpy(tmp_path):
    # build a pickle whose arrays are chumpy.ch.Ch objects, like MANO_RIGHT.pkl, then load it with
    # chumpy absent
    mod, sub = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    sub.Ch, mod.ch = Ch, sub
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = mod, sub
    try:
        write_synthetic_mano(tmp_path / "plain.pkl", MODEL)
        with open(tmp_path / "plain.pkl", "rb") as fh:
            d = pickle.load(fh)
        d["shapedirs"] = Ch(d["shapedirs"])
        d["J"] = Ch(MODEL.v_template[:16])
        with open(tmp_path / "MANO_RIGHT.pkl", "wb") as fh:
            pickle.dump(d, fh, protocol=2)
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]
    m = load_mano_model(tmp_path / "MANO_RIGHT.pkl")
    np.testing.assert_array_equal(m.shapedirs, MODEL.shapedirs)


def test_model_file_errors_say_what_is_wrong(tmp_path):
    with pytest.raises(MANOError, match="not found.*MANO_RIGHT.pkl"):
        load_mano_model(tmp_path / "nope.pkl")
    np.savez(tmp_path / "bad.npz", v_template=np.zeros((778, 3)))
    with pytest.raises(MANOError, match="missing MANO keys.*shapedirs"):
        load_mano_model(tmp_path / "bad.npz")

    class Evil:
        def __reduce__(self):
            return (print, ("x",))

    with open(tmp_path / "evil.pkl", "wb") as fh:
        pickle.dump({"v_template": Evil()}, fh)
    with pytest.raises(MANOError, match="refusing"):
        load_mano_model(tmp_path / "evil.pkl")
    small, _ = synthetic_mano()
    small.weights = small.weights[:, :15]
    with pytest.raises(MANOError, match="weights"):
        small.validate()
