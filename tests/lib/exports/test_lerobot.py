"""Exports: LeRobot v3.0 (read back by Rerun's own LeRobot reader), robomimic hdf5, Rerun recordings.

The episodes are real: the task library's scripted pouring demonstration, augmented by
demoforge.lib.trajectories.augmentation into translated and mirrored episodes, written with the warehouse's contracts.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demoforge.lib.exports import ExportError, next_poses
from tests.support.paths import REPO_ROOT
from tests.support.episodes import TAKE, TASK, build_episode_warehouse


# ------------------------------------------------------------------------------------------ fixtures

@pytest.fixture(scope="module")
def episode_wh(tmp_path_factory):
    root = tmp_path_factory.mktemp("wh_exports") / "warehouse"
    root.mkdir()
    info = build_episode_warehouse(root)
    return root, info


def _look_at(eye, target) -> np.ndarray:
    """camera-to-world of an OpenCV camera at ``eye`` looking at ``target`` (world z up)."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def build_take(root: Path, warehouse: Path, demo, frames: int = 4, width: int = 64, height: int = 48) -> Path:
    """A small take folder (camera.json, rgb/, depth/) and its ingested tables, frames from ``demo``."""
    import cv2

    from demoforge.lib.task_library import get_task
    from demoforge.schemas.core import write_table

    take = root / TAKE
    (take / "rgb").mkdir(parents=True)
    (take / "depth").mkdir()
    K = np.array([[60.0, 0, width / 2], [0, 60.0, height / 2], [0, 0, 1]])
    T = _look_at(np.array([0.0, -0.6, 0.7]), np.array([0.0, 0.3, 0.0]))
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


# ------------------------------------------------------------------------------------------ LeRobot

def test_lerobot_export_reads_back_with_rerun_lerobot_reader(episode_wh, tmp_path):
    """The export follows the v3.0 layout: our validator agrees, and Rerun's independent LeRobot
    reader (rerun.experimental.LeRobotReader, written against LeRobot's format) loads every episode
    with the exported states, actions and task text."""
    import pyarrow.parquet as pq
    from rerun.experimental import LeRobotReader

    from demoforge.tasks.export import export_lerobot
    from demoforge.lib.exports.lerobot import read_lerobot_episode

    wh, info = episode_wh
    out = tmp_path / "lerobot"
    summary = export_lerobot(str(wh), TASK, str(out))
    valid_ids = sorted(i for i, v in info["valid"].items() if v)
    assert summary["episodes"] == len(valid_ids) and summary["tasks"] == ["Pour from the bottle into the cup."]
    assert summary["frames"] == sum(len(info["actions"][i]) for i in valid_ids)

    meta = json.loads((out / "meta/info.json").read_text())
    assert meta["codebase_version"] == "v3.0" and meta["fps"] == 30 and meta["data_path"].startswith("data/chunk-")
    assert meta["features"]["observation.state"]["shape"] == [16]
    assert meta["features"]["action"]["names"][8] == "right_x"
    for p in ("meta/tasks.parquet", "meta/stats.json", "meta/episodes/chunk-000/file-000.parquet",
              "data/chunk-000/file-000.parquet"):
        assert (out / p).is_file(), p
    eps = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    assert eps["demoforge/episode_id"] == valid_ids and eps["demoforge/take"] == [TAKE] * len(valid_ids)

    reader = LeRobotReader(out)
    assert reader.version == "v3" and reader.episodes() == list(range(len(valid_ids)))
    k = len(valid_ids) - 1  # the last one: a mirrored episode if any is valid
    src = info["actions"][valid_ids[k]]
    got: dict[str, np.ndarray] = {}
    for chunk in reader.stream(k).to_chunks():
        rb = chunk.to_record_batch()
        if "Scalars:scalars" in rb.schema.names and "frame_index" in rb.schema.names:
            order = np.argsort(rb.column("frame_index").to_numpy())
            got[chunk.entity_path] = np.array(rb.column("Scalars:scalars").to_pylist(), float)[order]
        if "TextDocument:text" in rb.schema.names:
            got.setdefault(chunk.entity_path, []).extend(rb.column("TextDocument:text").to_pylist())
    np.testing.assert_allclose(got["/observation.state"], src.reshape(len(src), 16), atol=1e-6)
    np.testing.assert_allclose(got["/action"][:-1], src[1:].reshape(-1, 16), atol=1e-6)
    np.testing.assert_allclose(got["/action"][-1], src[-1].reshape(16), atol=1e-6)  # the last step holds
    assert set(np.ravel(got["/task"])) == {"Pour from the bottle into the cup."}

    # our own reader and the global statistics agree with the source actions
    back = read_lerobot_episode(out, 0)
    np.testing.assert_allclose(back["observation.state"], info["actions"][valid_ids[0]].reshape(-1, 16), atol=1e-6)
    np.testing.assert_allclose(back["timestamp"], np.arange(len(back["timestamp"])) / 30, atol=1e-6)
    stats = json.loads((out / "meta/stats.json").read_text())
    every = np.concatenate([info["actions"][i].reshape(-1, 16) for i in valid_ids]).astype(np.float64)
    np.testing.assert_allclose(stats["observation.state"]["mean"], every.mean(0), atol=1e-5)
    np.testing.assert_allclose(stats["observation.state"]["std"], every.std(0), atol=1e-5)
    assert stats["index"]["count"] == [len(every)] and stats["index"]["max"] == [len(every) - 1]
    # quantiles as LeRobot aggregates them: the count-weighted mean of the episodes' histogram quantiles
    per_ep = [_reference_episode_quantiles(info["actions"][i].reshape(-1, 16)) for i in valid_ids]
    w = np.array([len(info["actions"][i]) for i in valid_ids], float)
    for k in ("q01", "q10", "q50", "q90", "q99"):
        want = sum(wi * p[k] for wi, p in zip(w, per_ep)) / w.sum()
        width = (every.max(0) - every.min(0)) / 5000  # one histogram bin of the widest episode at most
        assert (np.abs(np.array(stats["observation.state"][k]) - want) <= width + 1e-7).all(), k

    # the provenance in every data row, and the object keypoints as the environment state
    assert meta["features"]["observation.environment_state"]["shape"] == [33]
    assert meta["features"]["observation.environment_state"]["names"][:3] == ["bottle_base_x", "bottle_base_y",
                                                                              "bottle_base_z"]
    k_last = read_lerobot_episode(out, len(valid_ids) - 1)
    assert set(k_last["demoforge.take"]) == {TAKE} and set(k_last["demoforge.episode_id"]) == {valid_ids[-1]}
    assert set(k_last["demoforge.kind"]) == {info["kind"][valid_ids[-1]]}
    env = k_last["observation.environment_state"].reshape(-1, 11, 3)
    np.testing.assert_allclose(env[0], info["keypoints"][valid_ids[-1]], atol=1e-6)  # the scene at the start
    assert "observation.environment_state" in stats and stats["observation.environment_state"]["count"] == [len(every)]


def _reference_episode_quantiles(x: np.ndarray) -> dict:
    """LeRobot's RunningQuantileStats quantiles of one episode, written out per dimension as in
    lerobot/datasets/compute_stats.py (np.histogram, cumsum, searchsorted, linear in the bin)."""
    out = {}
    for q, key in zip((0.01, 0.10, 0.50, 0.90, 0.99), ("q01", "q10", "q50", "q90", "q99")):
        vals = []
        for d in range(x.shape[1]):
            edges = np.linspace(x[:, d].min() - 1e-10, x[:, d].max() + 1e-10, 5001)
            cs = np.cumsum(np.histogram(x[:, d], bins=edges)[0])
            target = q * len(x)
            i = int(np.searchsorted(cs, target))
            if i == 0:
                vals.append(edges[0])
                continue
            before, inside = cs[i - 1], cs[i] - cs[i - 1]
            vals.append(edges[i] if inside == 0 else edges[i] + (target - before) / inside * (edges[i + 1] - edges[i]))
        out[key] = np.array(vals)
    return out


def test_lerobot_splits_data_files_and_validator_rejects_broken_datasets(episode_wh, tmp_path):
    from demoforge.schemas.reads.episodes import load_episodes
    from demoforge.lib.exports.lerobot import (
        LeRobotFormatError, validate_lerobot_dataset, write_lerobot_dataset,
    )

    wh, info = episode_wh
    sel = load_episodes(str(wh), TASK, include_invalid=True, limit=5)
    assert sel.episode_id.tolist() == [0, 1, 2, 3, 4] and sel.kind[0] == "original"
    out = tmp_path / "split"
    # a tiny file cap: every episode gets its own data file, and the layout still holds
    write_lerobot_dataset(out, sel.poses, sel.lengths, tasks=["t"], data_files_size_in_mb=0.01)
    s = validate_lerobot_dataset(out)
    assert s["data_files"] == 5 and s["frames"] == int(sel.lengths.sum())
    assert sorted(p.name for p in (out / "data/chunk-000").iterdir()) == [f"file-{i:03d}.parquet" for i in range(5)]

    info_path = out / "meta/info.json"
    meta = json.loads(info_path.read_text())
    info_path.write_text(json.dumps({**meta, "codebase_version": "v2.1"}))
    with pytest.raises(LeRobotFormatError, match="codebase_version"):
        validate_lerobot_dataset(out)
    info_path.write_text(json.dumps(meta))
    (out / "data/chunk-000/file-003.parquet").unlink()
    with pytest.raises(LeRobotFormatError, match="file-003.parquet"):
        validate_lerobot_dataset(out)


def test_exports_are_atomic_and_refuse_bad_input(episode_wh, tmp_path):
    from demoforge.lib.exports.lerobot import write_lerobot_dataset

    wh, info = episode_wh
    poses = info["actions"][0]
    out = tmp_path / "ds"
    write_lerobot_dataset(out, poses, [len(poses)], tasks=["t"])
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    with pytest.raises(ExportError, match="already exists"):
        write_lerobot_dataset(out, poses, [len(poses)], tasks=["t"])
    # a failure while writing (a provenance column of the wrong length) leaves the old export untouched
    with pytest.raises(ExportError, match="provenance"):
        write_lerobot_dataset(out, poses, [len(poses)], tasks=["t"], provenance={"take": ["a", "b"]}, overwrite=True)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # no temporary folder left behind
    with pytest.raises(ExportError, match="sum to"):
        write_lerobot_dataset(tmp_path / "x", poses, [len(poses) + 1], tasks=["t"])
    bad = poses.copy()
    bad[3, 0, 0] = np.nan
    with pytest.raises(ExportError, match="NaN"):
        write_lerobot_dataset(tmp_path / "x", bad, [len(bad)], tasks=["t"])
    assert not (tmp_path / "x").exists()


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 6), min_size=1, max_size=6))
def test_next_poses_shifts_within_episodes_only(lengths):
    lengths = np.array(lengths)
    F = int(lengths.sum())
    poses = np.arange(F * 16, dtype=float).reshape(F, 2, 8)
    nxt = next_poses(poses, lengths)
    ends = np.cumsum(lengths) - 1
    inner = np.setdiff1d(np.arange(F), ends)
    np.testing.assert_array_equal(nxt[inner], poses[inner + 1])
    np.testing.assert_array_equal(nxt[ends], poses[ends])


# ------------------------------------------------------------------------------------------ robomimic

def test_robomimic_export_layout_and_provenance(episode_wh, tmp_path):
    import h5py

    from demoforge.tasks.export import export_robomimic
    from demoforge.lib.exports.robomimic import is_demoforge_robomimic, read_robomimic_demo

    wh, info = episode_wh
    out = tmp_path / "pouring.hdf5"
    s = export_robomimic(str(wh), TASK, str(out), include_invalid=True, valid_fraction=0.25, seed=3)
    ids = sorted(info["actions"])
    assert s["demos"] == len(ids) and s["valid"] == round(0.25 * len(ids))
    assert is_demoforge_robomimic(out)
    with h5py.File(out, "r") as f:
        data = f["data"]
        assert data.attrs["total"] == sum(len(a) for a in info["actions"].values())
        env = json.loads(data.attrs["env_args"])
        assert env["env_name"] == "demoforge/pouring" and env["env_kwargs"]["control_freq"] == 30
        assert sorted(data.keys(), key=lambda k: int(k.split("_")[1])) == [f"demo_{i}" for i in range(len(ids))]
        train = {x.decode() for x in f["mask/train"][()]}
        valid = {x.decode() for x in f["mask/valid"][()]}
        assert not train & valid and train | valid == set(data.keys())
        mirrored = {x.decode() for x in f["mask/mirrored"][()]}
        assert len(mirrored) == sum(k == "mirrored" for k in info["kind"].values())
    for i in (0, len(ids) - 1):
        d = read_robomimic_demo(out, f"demo_{i}")
        src = info["actions"][d["attrs"]["src_episode_id"]].astype(np.float64)
        assert d["attrs"]["src_take"] == TAKE and d["attrs"]["src_task"] == TASK
        assert d["attrs"]["src_kind"] == info["kind"][d["attrs"]["src_episode_id"]]
        assert d["attrs"]["num_samples"] == len(src) == len(d["actions"])
        np.testing.assert_allclose(d["obs"]["robot0_eef_pos"], src[:, 0, :3], atol=1e-6)
        np.testing.assert_allclose(d["obs"]["robot1_eef_quat"], src[:, 1, 3:7], atol=1e-6)
        np.testing.assert_allclose(d["obs"]["robot0_gripper"][:, 0], src[:, 0, 7])
        np.testing.assert_allclose(d["actions"][:-1], src[1:].reshape(-1, 16), atol=1e-6)
        np.testing.assert_allclose(d["next_obs"]["robot1_eef_pos"][:-1], src[1:, 1, :3], atol=1e-6)
        np.testing.assert_allclose(d["obs"]["object"][0], info["keypoints"][d["attrs"]["src_episode_id"]].reshape(-1),
                                   atol=1e-6)
        # the keypoints follow the carried objects: the bottle (manipulated) is lifted off its start
        # (and put back), the next observation is the next step's
        assert np.abs(d["obs"]["object"] - d["obs"]["object"][0]).max() > 0.05
        np.testing.assert_allclose(d["next_obs"]["object"][:-1], d["obs"]["object"][1:])
        assert d["dones"].sum() == 1 and d["dones"][-1] == 1


# ------------------------------------------------------------------------------------------ Rerun

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


# ------------------------------------------------------------------------------------------ CLI errors

def test_cli_refuses_bad_exports_with_one_line_and_exit_2(episode_wh, tmp_path, monkeypatch):
    """User errors are caught before any Prefect run: exit code 2 and a message that says what to fix."""
    from typer.testing import CliRunner

    from demoforge.cli import app

    wh, _ = episode_wh
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(wh))
    runner = CliRunner()
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    (tmp_path / "old.rrd").write_bytes(b"x")
    (tmp_path / "other.hdf5").write_bytes(b"not ours")
    for args, msg in ((["export", "lerobot", "--task", TASK, "--out", str(foreign)], "not a demoforge export"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "a.zip")], ".hdf5"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "other.hdf5")],
                       "not a demoforge export"),
                      (["export", "lerobot", "--task", "juggling", "--out", str(tmp_path / "j")], "unknown task"),
                      (["export", "lerobot", "--task", "mix_bowl", "--out", str(tmp_path / "m")], "demoforge augment"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "r.hdf5"),
                        "--valid-fraction", "1.5"], "--valid-fraction"),
                      (["view", "pouring/123456", "--rrd", str(tmp_path / "v.rrd")], "no episode 123456"),
                      (["view", "no_such_take", "--rrd", str(tmp_path / "v.rrd")], "neither a take folder"),
                      (["view", "pouring/0", "--rrd", str(tmp_path / "old.rrd")], "--overwrite"),
                      (["view", str(tmp_path), "--rrd", str(tmp_path / "v.rrd")], "demoforge ingest"),
                      (["view", "pouring/0", "--rrd", str(tmp_path / "v.txt")], ".rrd"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "i"), "--with-images"],
                       "demoforge ingest"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "r.hdf5"), "--with-images"],
                       "lerobot` only"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "i"), "--with-images",
                        "--image-size", "33x20"], "--image-size"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "i"), "--image-size", "64x48"],
                       "needs --with-images"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--robot", "aloha"],
                       "demoforge simulate --task pouring --robot aloha --gripper aloha"),
                      (["export", "robomimic", "--task", TASK, "--out", str(tmp_path / "a.hdf5"), "--robot", "aloha"],
                       "is for `export lerobot`"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--unchecked"],
                       "--unchecked is for"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--robot", "ur5"],
                       "--robot must be one of grippers, aloha"),
                      (["export", "lerobot", "--task", TASK, "--out", str(tmp_path / "a"), "--robot", "aloha",
                        "--gripper", "robotiq"], "carries aloha or 2f140")):
        r = runner.invoke(app, args)
        assert r.exit_code == 2 and msg in r.stderr and len(r.stderr.strip().splitlines()) == 1, (args, r.output)
    assert (foreign / "notes.txt").read_text() == "keep me" and not (tmp_path / "j").exists()
    assert (tmp_path / "other.hdf5").read_bytes() == b"not ours"
    r = runner.invoke(app, ["export", "--help"])
    assert r.exit_code == 0 and "lerobot" in r.output and "robomimic" in r.output


@pytest.mark.parametrize("mirror", [False, True])
def test_carried_object_keypoints_match_the_task_library_scenes(mirror):
    """The environment state's keypoints, rebuilt from an episode's gripper poses and its first
    scene only, equal the task library's own per-frame object keypoints for every task's scripted
    demonstration (plain and mirrored: the arms' roles swap)."""
    from demoforge.lib.exports.object_state import episode_object_keypoints
    from demoforge.lib.task_library import TASK_NAMES, get_task

    demos, moved = [], 0
    for name in TASK_NAMES:
        spec = get_task(name)
        d = spec.scripted_demo(0, mirror=mirror)
        demos.append((spec, d.gripper_actions(), d.keypoints()))
    poses = np.concatenate([a for _, a, _ in demos])
    lengths = np.array([len(a) for _, a, _ in demos])
    # all six in one call: concatenated episodes of different lengths (every task has 11 keypoints)
    got = episode_object_keypoints(poses, lengths, np.stack([k[0] for _, _, k in demos]), demos[0][0].keypoint_object)
    for (spec, a, kp), part in zip(demos, np.split(got, np.cumsum(lengths)[:-1])):
        assert (spec.keypoint_object == demos[0][0].keypoint_object).all()
        np.testing.assert_allclose(part, kp, atol=1e-9, err_msg=spec.name)
        moved += np.abs(kp - kp[0]).max() > 0.1  # the manipulated object travels
    assert moved == len(TASK_NAMES)
    with pytest.raises(ExportError, match="object keypoints must be"):
        episode_object_keypoints(poses, lengths, np.zeros((len(lengths), 10, 3)), demos[0][0].keypoint_object)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 4), st.integers(1, 300), st.integers(1, 5))
def test_lerobot_stats_equal_lerobots_histogram_algorithm(seed, n_eps, length, dims):
    """The vectorised statistics equal a per-dimension transcription of LeRobot's RunningQuantileStats
    (to one histogram bin), and the aggregate is LeRobot's count-weighted one."""
    from demoforge.lib.exports.lerobot_stats import aggregate_stats, lerobot_stats

    rng = np.random.default_rng(seed)
    x = rng.normal(0, rng.uniform(0.01, 5), (n_eps, length, dims)).astype(np.float32)
    x[:, :, 0] = np.round(x[:, :, 0])  # ties and repeated values
    s = lerobot_stats(x)
    for e in range(n_eps):
        np.testing.assert_allclose(s["mean"][e], x[e].mean(0), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(s["std"][e], x[e].std(0), rtol=1e-3, atol=1e-4)
        if length < 2:
            continue
        ref = _reference_episode_quantiles(x[e].astype(np.float64))
        width = (x[e].max(0) - x[e].min(0)) / 5000 + 1e-9
        for k, v in ref.items():
            assert (np.abs(s[k][e] - v) <= width * 1.01).all(), (k, s[k][e], v)
    agg = aggregate_stats(s)
    flat = x.reshape(-1, dims).astype(np.float64)
    np.testing.assert_allclose(agg["mean"], flat.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(agg["std"], flat.std(0), rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(agg["q50"], s["q50"].astype(np.float64).mean(0), rtol=1e-6)  # equal counts: the plain mean
    assert agg["count"].tolist() == [n_eps * length]


def test_pinhole_camera_draws_points_where_k_projects_them():
    """A MuJoCo scene camera set from K and T_world_camera draws small spheres at the pixels the
    pinhole model predicts (off-centre principal point, different fx and fy)."""
    import mujoco

    from demoforge.lib.sim.render import pinhole_gl_camera

    pts = np.array([[0.1, 0.2, 0.05], [-0.15, 0.35, 0.0], [0.05, 0.05, 0.1]])
    colors = ["1 0 0 1", "0 1 0 1", "0 0 1 1"]
    geoms = "".join(f'<geom type="sphere" size="0.008" pos="{" ".join(map(str, p))}" rgba="{c}"/>'
                    for p, c in zip(pts, colors))
    m = mujoco.MjModel.from_xml_string(f'<mujoco><worldbody><light pos="0 0 3"/>{geoms}</worldbody></mujoco>')
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    W, H = 320, 200
    K = np.array([[250.0, 0, 140], [0, 270, 115], [0, 0, 1]])
    T = _look_at(np.array([0.05, -0.6, 0.7]), np.array([0.0, 0.3, 0.0]))
    with mujoco.Renderer(m, H, W) as r:
        r.update_scene(d)
        for c in r.scene.camera:
            pinhole_gl_camera(c, K, T, W, H)
        img = r.render().astype(int)
    for ch, p in enumerate(pts):
        pc_ = (p - T[:3, 3]) @ T[:3, :3]
        uv = pc_[:2] / pc_[2] * [K[0, 0], K[1, 1]] + K[:2, 2]
        others = [c for c in range(3) if c != ch]
        v, u = np.nonzero((img[..., ch] > 100) & (img[..., others[0]] < 60) & (img[..., others[1]] < 60))
        assert len(u) >= 4
        np.testing.assert_allclose([u.mean() + 0.5, v.mean() + 0.5], uv, atol=1.0)


def _register_take_camera(wh: Path, takes_dir: Path) -> dict:
    """A take folder with the synthetic head camera's camera.json, registered in the `takes` table."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("check_exports_sample",
                                                  REPO_ROOT / "scripts/check_exports_sample.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    from demoforge.schemas.core import write_table

    from demoforge.lib.synth.render import HEIGHT, WIDTH, camera_K, camera_T_world_camera

    take = takes_dir / TAKE
    take.mkdir(parents=True, exist_ok=True)
    cam = {"K": camera_K().tolist(), "width": WIDTH, "height": HEIGHT, "T_world_camera": camera_T_world_camera().tolist()}
    (take / "camera.json").write_text(json.dumps(cam))
    write_table("takes", mod.takes_row(take), wh)
    return cam


def test_lerobot_export_with_images_holds_the_rendered_episodes(episode_wh, tmp_path):
    """--with-images: each episode executed in MuJoCo and drawn from the take's camera (K scaled to
    the chosen size) is in the mp4 at the episode's from/to timestamps, frame for frame, and the
    image statistics are LeRobot's per-channel ones."""
    import cv2

    from demoforge.schemas.reads.episodes import load_episodes
    from demoforge.tasks.export import export_lerobot
    from demoforge.lib.sim.render import episode_frames

    import shutil

    wh = tmp_path / "warehouse"  # a copy: the takes table written below stays out of the shared one
    shutil.copytree(episode_wh[0], wh)
    out = tmp_path / "lr_img"
    with pytest.raises(ExportError, match="demoforge ingest"):
        export_lerobot(str(wh), TASK, str(out), limit=2, with_images=True, image_size=(48, 36))
    cam = _register_take_camera(wh, tmp_path / "takes")
    s = export_lerobot(str(wh), TASK, str(out), limit=2, with_images=True, image_size=(48, 36))
    assert s["videos"] == ["observation.images.camera"] and s["episodes"] == 2
    meta = json.loads((out / "meta/info.json").read_text())
    ft = meta["features"]["observation.images.camera"]
    assert ft["dtype"] == "video" and ft["shape"] == [36, 48, 3] and ft["info"]["video.codec"] == "mpeg4"
    assert meta["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    import pyarrow.parquet as pq

    eps = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    frm = eps["videos/observation.images.camera/from_timestamp"]
    assert frm[0] == 0 and abs(frm[1] - eps["length"][0] / 30) < 1e-9

    cap = cv2.VideoCapture(str(out / "videos/observation.images.camera/chunk-000/file-000.mp4"))
    decoded = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        decoded.append(cv2.cvtColor(f, cv2.COLOR_BGR2RGB))
    assert len(decoded) == s["frames"]
    sel = load_episodes(str(wh), TASK, limit=2)
    K = np.diag([48 / cam["width"], 36 / cam["height"], 1.0]) @ np.array(cam["K"])
    L0 = int(sel.lengths[0])
    second = list(episode_frames(TASK, sel.keypoints[1], sel.poses[L0:L0 + int(sel.lengths[1])].astype(float), K,
                                 np.array(cam["T_world_camera"]), 48, 36))
    got = np.stack(decoded[L0:]).astype(float)
    psnr = 10 * np.log10(255 ** 2 / np.mean((got - np.stack(second)) ** 2))
    assert psnr > 25, psnr  # the second episode's frames, through a lossy codec
    assert np.abs(got[-1] - got[0]).mean() > 1  # the grippers moved between its first and last frame
    stats = json.loads((out / "meta/stats.json").read_text())["observation.images.camera"]
    assert np.shape(stats["mean"]) == (3, 1, 1) and stats["count"] == [2 * 100]  # LeRobot samples 100 a episode
    np.testing.assert_allclose(np.ravel(stats["mean"]), np.stack(decoded).mean((0, 1, 2)) / 255, atol=0.03)


def test_carried_keypoints_vectorised_equal_the_per_episode_segmentation_rule(episode_wh):
    """Over a real augmented database (translated and mirrored episodes, one call), the vectorised
    carry equals demoforge.lib.trajectories.segmentation's per-episode functions (infer_object_arm + object_keypoints_over_time)."""
    from demoforge.schemas.reads.episodes import load_episodes
    from demoforge.lib.exports.object_state import episode_object_keypoints, object_arms
    from demoforge.lib.trajectories.segmentation import infer_object_arm, object_keypoints_over_time
    from demoforge.lib.task_library import get_task

    wh, _ = episode_wh
    sel = load_episodes(str(wh), TASK, include_invalid=True)
    ko = get_task(TASK).keypoint_object
    got = episode_object_keypoints(sel.poses, sel.lengths, sel.keypoints, ko)
    arms = object_arms(sel.poses.astype(float), sel.lengths, sel.keypoints, ko)
    start = 0
    for i, L in enumerate(sel.lengths.tolist()):
        traj = sel.poses[start:start + L].astype(float)
        arm_of = infer_object_arm(traj, sel.keypoints[i], ko)
        assert arms[i].tolist() == arm_of.tolist()
        held = np.stack([np.where(traj[:, a, 7] < 0.5, np.flatnonzero(arm_of == a)[0], -1) for a in (0, 1)], axis=1)
        want = object_keypoints_over_time(traj, sel.keypoints[i], ko, held)
        np.testing.assert_allclose(got[start:start + L], want, atol=1e-9)
        start += L
    mirrored = sel.kind == "mirrored"
    assert mirrored.any() and (arms[mirrored] == 1 - arms[~mirrored][0]).all()  # the roles swap


# ------------------------------------------------------------------------------------------ joint space

@pytest.fixture(scope="module")
def arm_episode_wh(tmp_path_factory):
    """A pouring database from the seed-1 demonstration, which the ALOHA arms reach (seed 0's they do not),
    with one episode's right hand moved a metre to the right, beyond the arm's reach."""
    from demoforge.schemas.core import column_numpy, read_table, write_table

    root = tmp_path_factory.mktemp("wh_arm_exports") / "warehouse"
    root.mkdir()
    info = build_episode_warehouse(root, n=4, n_mirrored=2, demo_seed=1)
    far = sorted(i for i, v in info["valid"].items() if v)[-1]
    steps = read_table("episode_steps", root, task=TASK)
    act = column_numpy(steps, "action").copy()
    act[steps.column("episode_id").to_numpy() == far, 1, 0] += 1.0
    write_table("episode_steps", {**{c: steps.column(c) for c in steps.column_names}, "action": act}, root)
    info["actions"][far][:, 1, 0] += 1.0
    return root, {**info, "far": far}


def _sim_rows(ids: list[int], success: list[bool], robot: str = "aloha", gripper: str = "aloha") -> dict:
    n = len(ids)
    return {"task": [TASK] * n, "take": [TAKE] * n, "robot": [robot] * n, "gripper": [gripper] * n,
            "selection": ["ids-test"] * n, "chunk": [0] * n, "episode_id": ids, "kind": ["translated"] * n,
            "success": success, "failure": ["" if s else "unreachable" for s in success], "detail": [""] * n,
            "predicate_ok": [None] * n, "predicate_detail": [""] * n, "reachable": success,
            "ik_position_error_m": [0.001] * n, "ik_rotation_error_deg": [0.1] * n, "time_scale": [1.0] * n,
            "duration_s": [1.0] * n,
            "physics_steps": [480] * n, "wall_s": [0.1] * n}


def test_joint_space_export_reproduces_the_poses_and_keeps_only_checked_reachable_episodes(arm_episode_wh, tmp_path):
    """`export lerobot --robot aloha`: 14 joint values per step named as the ALOHA datasets name them; the
    arms' FK of the exported joints is the path they were planned to follow (the episode's gripper poses as
    the motion retargets them), within 1 cm and 5 degrees as the check, position and orientation, at every
    exported step inside each arm's window; the gripper columns are g; only
    episodes whose arm check passed (all it reaches with --unchecked), never one the IK cannot reach. The
    exported trajectory is what the arms run (their ready-pose start and time-scaling included), at the
    dataset's fps."""
    from scipy.spatial.transform import Rotation

    from demoforge.lib.exports.lerobot import read_lerobot_episode
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.sim import SimOptions, planned_execution
    from demoforge.lib.sim.robots.aloha import JOINT_NAMES
    from demoforge.lib.sim.robots.aloha.model import REST
    from demoforge.lib.sim.robots.retiming import at
    from demoforge.schemas.core import write_table
    from demoforge.schemas.reads.episodes import load_episodes
    from demoforge.tasks.export import export_lerobot

    wh, info = arm_episode_wh
    with pytest.raises(ExportError, match="demoforge simulate --task pouring --robot aloha"):
        export_lerobot(str(wh), TASK, str(tmp_path / "none"), robot="aloha")
    s = export_lerobot(str(wh), TASK, str(tmp_path / "all"), robot="aloha", unchecked=True)
    meta = json.loads((tmp_path / "all" / "meta" / "info.json").read_text())
    source = json.loads((tmp_path / "all" / "meta" / "demoforge.json").read_text())
    assert meta["robot_type"] == "aloha" and meta["features"]["observation.state"]["names"] == list(JOINT_NAMES)
    assert meta["features"]["action"]["shape"] == [14] and JOINT_NAMES[:7] == (
        "left_waist", "left_shoulder", "left_elbow", "left_forearm_roll", "left_wrist_angle", "left_wrist_rotate",
        "left_gripper")
    valid = sum(info["valid"].values())
    assert s["episodes"] == valid - 1 and s["left_out_unreachable"] == 1, s
    assert [r[1] for r in source["left_out_unreachable"]] == [info["far"]]
    arms = get_robot("aloha")
    ik = arms.ik(TASK)
    sel = load_episodes(str(wh), TASK)
    assert len(source["time_scale"]) == s["episodes"] and min(source["time_scale"]) > 1.0
    for e in range(s["episodes"]):
        ep = read_lerobot_episode(tmp_path / "all", e)
        i = int(np.flatnonzero(sel.episode_id == int(ep["demoforge.episode_id"][0]))[0])
        poses = info["actions"][int(ep["demoforge.episode_id"][0])]
        # what the arms run: from their ready pose, slowed where a servo is too slow, at the dataset's fps
        motion = planned_execution(TASK, sel.keypoints[i], poses, options=SimOptions(robot=arms)).state
        state = ep["observation.state"].astype(np.float64)
        assert state.shape == (len(motion.q), 14) and len(motion.q) > len(poses)
        assert source["time_scale"][e] == pytest.approx(motion.time_scale, abs=1e-4)
        np.testing.assert_allclose(state[0, [0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]], REST * 2, atol=1e-6)
        np.testing.assert_array_equal(ep["action"][:-1], ep["observation.state"][1:])
        np.testing.assert_allclose(state[:, [6, 13]], np.clip(motion.poses[:, :, 7], 0, 1), atol=1e-6)
        # inside each arm's window, at every exported step, the FK of the exported joints is on the path the
        # arm was planned to follow, position and orientation: the poses the motion records for its windows
        # (ArmMotion.targets: the demonstrated poses as the arms follow them, smoothed, the grasp turned about
        # the held object's symmetry axis), between two demonstrated steps the position interpolated and the
        # rotation slerped, turned half a turn about the pinch frame's z (the gripper's symmetric grasp)
        # where the IK chose that orientation for the window (IKSolution.flipped)
        targets = np.asarray(motion.targets, float)
        assert targets.shape == poses.shape
        fk_pos, fk_R = ik.fk(state[:, [0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]])
        for a in range(2):
            w0, w1 = motion.windows[a]
            rows = np.flatnonzero((motion.s >= w0 - 1e-6) & (motion.s <= w1 - 1 + 1e-6))  # s of repeated retimings
            assert len(rows) >= w1 - 1 - w0 > 0, (e, a, w0, w1)  # (an executed frame moves on by one step at most)
            s_rows = motion.s[rows]
            f0 = np.clip(np.floor(s_rows + 1e-9).astype(int), 0, len(targets) - 2)
            frac = np.clip(s_rows - f0, 0.0, 1.0)
            want_pos = at(targets[:, a, :3], s_rows)
            r0, r1 = Rotation.from_quat(targets[f0, a, 3:7]), Rotation.from_quat(targets[f0 + 1, a, 3:7])
            want_R = r0 * Rotation.from_rotvec(frac[:, None] * (r0.inv() * r1).as_rotvec())
            if motion.ik.flipped[a]:
                want_R = want_R * Rotation.from_euler("z", np.pi)
            pos_err = np.linalg.norm(fk_pos[rows, a] - want_pos, axis=1)
            rot_err = np.degrees((Rotation.from_matrix(fk_R[rows, a]).inv() * want_R).magnitude())
            assert pos_err.max() < 0.01, (e, a, int(rows[np.argmax(pos_err)]), pos_err.max())
            assert rot_err.max() < 5.0, (e, a, int(rows[np.argmax(rot_err)]), rot_err.max())
    exported = [int(read_lerobot_episode(tmp_path / "all", e)["demoforge.episode_id"][0]) for e in range(s["episodes"])]
    dropped = [r[1] for r in source["left_out_unreachable"]]
    # the arm check: only the episodes whose check passed, less any the IK cannot reach
    write_table("sim_results", _sim_rows([exported[0], exported[1], *dropped[:1], 10_000],
                                         [True, False, True, True]), wh)
    c = export_lerobot(str(wh), TASK, str(tmp_path / "checked"), robot="aloha")
    got = [int(read_lerobot_episode(tmp_path / "checked", e)["demoforge.episode_id"][0]) for e in range(c["episodes"])]
    assert got == [exported[0]] and c["left_out_unreachable"] == len(dropped[:1])
