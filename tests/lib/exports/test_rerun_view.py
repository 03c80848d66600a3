"""Rerun recordings (demoforge.lib.exports.rerun_view): back-projected depth lands on its pixels, and the view of a
take and of an episode holds the scene."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demoforge.lib.exports import ExportError
from tests.support.camera import look_at
from tests.support.episodes import TAKE, TASK


def build_take(root: Path, warehouse: Path, demo, frames: int = 4, width: int = 64, height: int = 48) -> Path:
    """A small take folder (camera.json, rgb/, depth/) and its ingested tables, frames from ``demo``."""
    import cv2

    from demoforge.lib.task_library import get_task
    from demoforge.schemas.core import write_table

    take = root / TAKE
    (take / "rgb").mkdir(parents=True)
    (take / "depth").mkdir()
    K = np.array([[60.0, 0, width / 2], [0, 60.0, height / 2], [0, 0, 1]])
    T = look_at(np.array([0.0, -0.6, 0.7]), np.array([0.0, 0.3, 0.0]))
    (take / "camera.json").write_text(json.dumps({"K": K.tolist(), "width": width, "height": height,
                                                  "T_world_camera": T.tolist(), "fps": 30.0, "depth_unit": "m"}))
    rng = np.random.default_rng(0)
    for f in range(frames):
        cv2.imwrite(str(take / "rgb" / f"{f:06d}.png"), rng.integers(0, 255, (height, width, 3), dtype=np.uint8))
        depth = np.full((height, width), 0.9 + 0.01 * f, np.float32)
        depth[:5] = 0.0  # a band of invalid depth
        np.save(take / "depth" / f"{f:06d}.npy", depth)
    poses = demo.gripper_actions()[:frames]
    joints = poses[:, :, None, :3] + rng.normal(0, 0.02, (frames, 2, 21, 3))
    # both hands in one write: rows of the left hand, then of the right
    n2 = 2 * frames
    present = np.ones((2, frames), bool)
    present[1, 1] = False  # the right hand is missing in frame 1
    jw = np.concatenate([joints[:, 0], joints[:, 1]])
    jw[~present.reshape(-1)] = np.nan
    flags = ~present.reshape(-1)
    rows = {"take": [TAKE] * n2, "task": [TASK] * n2, "frame": np.tile(np.arange(frames, dtype=np.int32), 2),
            "hand": ["left"] * frames + ["right"] * frames, "detector": ["simulated"] * n2}
    write_table("gripper_poses", {**rows, "pose": np.concatenate([poses[:, 0], poses[:, 1]]), "valid": [True] * n2,
                                  "fingertip_distance": np.full(n2, 0.05), "g_threshold": np.ones(n2, np.int8),
                                  "g_auto": np.ones(n2, np.int8), "g_manual": [None] * n2,
                                  "state_method": ["auto"] * n2, "depth_problem": [""] * n2}, warehouse)
    write_table("aligned_keypoints", {**rows, "present": ~flags, "detected": ~flags, "joints_cam": jw,
                                      "joints_world": jw, "translation": np.zeros((n2, 3)),
                                      "anchors_used": np.zeros(n2, np.int64), "n_anchors_valid": np.zeros(n2, np.int32),
                                      "no_depth": flags, "depth_outlier": flags, "outlier_frozen": flags,
                                      "swap_repaired": flags, "filled_missing": flags,
                                      "track_id": np.where(flags, -1, 0).astype(np.int32), "rejected": [""] * n2,
                                      "depth_ratio": np.ones(n2), "depth_problem": [""] * n2}, warehouse)
    spec = get_task(TASK)
    kp = demo.keypoints()[0]
    write_table("object_keypoints", {
        "take": [TAKE] * len(kp), "task": [TASK] * len(kp), "keypoint": np.arange(len(kp), dtype=np.int32),
        "name": list(spec.keypoint_names), "uv": np.full((len(kp), 1, 2), np.nan), "point_world": kp,
        "valid": [True] * len(kp), "reason": ["ok"] * len(kp), "source": ["ground truth"] * len(kp)}, warehouse)
    return take


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 5))
def test_backprojected_points_reproject_onto_their_pixels(seed, stride):
    from scipy.spatial.transform import Rotation

    from demoforge.lib.exports.rerun_view import backproject

    rng = np.random.default_rng(seed)
    H, W = 12, 17
    K = np.array([[rng.uniform(20, 80), 0, rng.uniform(5, 12)], [0, rng.uniform(20, 80), rng.uniform(4, 8)], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = rng.normal(0, 1, 3)
    depth = rng.uniform(0.2, 3, (H, W)).astype(np.float32)
    depth[rng.random((H, W)) < 0.2] = 0
    depth[rng.random((H, W)) < 0.1] = np.nan
    pts, _ = backproject(depth, K, T, stride)
    grid = depth[::stride, ::stride]
    v, u = np.mgrid[0:H:stride, 0:W:stride]
    ok = np.isfinite(grid) & (grid > 0)
    assert len(pts) == ok.sum()
    cam = (pts - T[:3, 3]) @ T[:3, :3]             # world -> camera
    np.testing.assert_allclose(cam[:, 2], grid[ok], rtol=1e-5)
    uv = cam[:, :2] / cam[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    np.testing.assert_allclose(uv, np.stack([u[ok], v[ok]], 1), atol=1e-6)


def test_view_take_and_episode_recordings_hold_the_scene(episode_wh, tmp_path):
    from demoforge.flows.view import write_view
    from demoforge.lib.exports.rerun_view import read_recording
    from demoforge.lib.task_library import get_task

    wh, info = episode_wh
    take = build_take(tmp_path / "takes", wh, info["demo"])
    out = tmp_path / "take.rrd"
    r = write_view(str(wh), str(take), str(out), point_stride=4)
    assert r["frames"] == 4 and r["hand_frames"] == 7  # the right hand is missing in one frame
    rec = read_recording(out)
    pts = [b for b in rec["/world/points"]]
    n_points = sum(len(p) for b in pts for p in b.column("Points3D:positions").to_pylist())
    assert n_points == r["points"] == 4 * (12 - 2) * 16  # rows 0-4 of the depth are invalid: grid rows 2..11
    # the first frame's cloud lies on the depth plane z_cam = 0.9 in front of the camera
    cam = json.loads((take / "camera.json").read_text())
    T = np.array(cam["T_world_camera"])
    first = np.array(pts[0].column("Points3D:positions").to_pylist()[0])
    np.testing.assert_allclose(((first - T[:3, 3]) @ T[:3, :3])[:, 2], 0.9, atol=1e-5)
    g = rec["/world/grippers/left"][0]
    np.testing.assert_allclose(np.array(g.column("Transform3D:translation").to_pylist())[:, 0],
                               info["demo"].gripper_actions()[:4, 0, :3], atol=1e-5)
    kp = rec["/world/object_keypoints"][0]
    assert kp.column("Points3D:labels").to_pylist()[0] == list(get_task(TASK).keypoint_names)
    bones = rec["/world/hands/right/bones"][0]
    assert len(bones.column("LineStrips3D:strips").to_pylist()[0]) == 6  # five fingers and the palm
    assert "/world/camera/image/rgb" in rec and "/world/camera/image" in rec

    ep = tmp_path / "ep.rrd"
    valid = [i for i, v in info["valid"].items() if v and i]
    r = write_view(str(wh), f"{TASK}/{valid[0]}", str(ep))
    rec = read_recording(ep)
    traj = rec["/world/trajectory/right"]
    last = max((s for b in traj for s in b.column("LineStrips3D:strips").to_pylist()), key=lambda s: len(s[0]))
    np.testing.assert_allclose(np.array(last[0]), info["actions"][valid[0]][:, 1, :3], atol=1e-5)
    assert "/world/reference/left" in rec  # the demonstration for comparison
    with pytest.raises(ExportError, match="neither a take folder"):
        write_view(str(wh), "no_such_take", str(tmp_path / "x.rrd"))
    with pytest.raises(ExportError, match="no episode 99999"):
        write_view(str(wh), f"{TASK}/99999", str(tmp_path / "x.rrd"))
    assert not (tmp_path / "x.rrd").exists()
