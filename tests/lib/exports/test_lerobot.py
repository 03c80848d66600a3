"""The LeRobot v3.0 export (demoforge.lib.exports.lerobot), read back by Rerun's own LeRobot reader: layout,
statistics, data files, the validator, atomic writes, rendered images.

The episodes are real: the task library's scripted pouring demonstration, augmented by
demoforge.lib.trajectories.augmentation into translated and mirrored episodes, written with the warehouse's contracts.
The other exports: test_robomimic.py, test_rerun_view.py, test_joint_space.py beside this file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demoforge.lib.exports import ExportError
from tests.support.episodes import TAKE, TASK
from tests.support.lerobot_reference import reference_episode_quantiles
from tests.support.paths import REPO_ROOT


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
    per_ep = [reference_episode_quantiles(info["actions"][i].reshape(-1, 16)) for i in valid_ids]
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
