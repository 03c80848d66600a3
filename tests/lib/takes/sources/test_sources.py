"""Take sources (demoforge.lib.takes.sources): a RealSense recording written by the SDK itself, ROS 2 bags
written by rosbags (MCAP and SQLite), a Record3D .r3d in Record3D's layout, each made from one small
synthetic take, ingest to the same gripper poses as the take folder; bad recordings are refused in one
line with nothing written; dropped frames, a moving camera and the topic choice are reported; a
recording's cache key reads it once."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from demoforge.cli import app
from demoforge.lib.takes import iter_frames, open_take, read_frame
from demoforge.lib.takes.sources import sidecar_dir
from demoforge.lib.takes.sources.writers import write_realsense, write_realsense_bag, write_record3d, write_rosbag2

N_FRAMES = 12
runner = CliRunner()


@pytest.fixture(scope="module")
def base(tmp_path_factory, prefect_api):
    """A 12-frame synthetic trash_in_bin take, ingested as a folder (the reference gripper poses)."""
    from demoforge.flows.ingest import ingest_take
    from demoforge.lib.synth.take import generate_take

    root = tmp_path_factory.mktemp("take_sources")
    take = root / "tk"
    generate_take("trash_in_bin", 0, False, take, max_frames=N_FRAMES, video=False)
    wh = root / "wh_folder"
    ingest_take(str(take), str(wh), show_progress=False)
    return {"root": root, "take": take, "poses": _poses(wh)}


def _poses(wh: Path) -> np.ndarray:
    t = pq.read_table(next((wh / "gripper_poses").rglob("*.parquet"))).to_pydict()
    order = np.lexsort((np.array(t["hand"]), np.array(t["frame"])))
    return np.array(t["pose"], float)[order]


def _frames(take) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    return {int(i): (r, d) for b in iter_frames(take) for i, r, d in zip(b.indices, b.rgb, b.depth)}


WRITERS = {
    "realsense.db3": lambda take, out: write_realsense(take, out),
    "realsense.bag": lambda take, out: write_realsense_bag(take, out),
    "rosbag2_mcap": lambda take, out: write_rosbag2(take, out, storage="mcap", depth_encoding="32FC1"),
    "rosbag2_db3": lambda take, out: write_rosbag2(take, out, storage="sqlite3", depth_encoding="32FC1"),
    "record3d.r3d": lambda take, out: write_record3d(take, out),
}


@pytest.mark.parametrize("name", list(WRITERS))
def test_recording_ingests_to_the_folders_gripper_poses(base, tmp_path, name):
    from demoforge.flows.ingest import ingest_take

    rec = WRITERS[name](base["take"], tmp_path / name)
    take = open_take(rec)
    assert take.source == name.split(".")[0].split("_")[0] and take.n_frames == N_FRAMES
    assert take.status_counts() == {"ok": N_FRAMES}
    ref, got = _frames(open_take(base["take"])), _frames(take)
    assert sorted(got) == sorted(ref)
    assert max(np.abs(got[i][1] - ref[i][1]).max() for i in ref) < 1e-4  # depth lossless (RealSense: 0.1 mm units)
    wh = tmp_path / "wh"
    ingest_take(str(rec), str(wh), show_progress=False)
    a, b = base["poses"], _poses(wh)
    assert a.shape == b.shape and np.array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a).any(axis=1)
    assert ok.sum() >= N_FRAMES  # both hands on most frames
    assert np.abs(a[ok, :3] - b[ok, :3]).max() < 1e-3            # positions within 1 mm
    assert np.abs(np.abs((a[ok, 3:7] * b[ok, 3:7]).sum(1)) - 1).max() < 1e-4  # same rotations
    assert np.array_equal(a[ok, 7], b[ok, 7])                       # same open/close


def test_record3d_depth_at_a_lower_resolution_and_a_moving_camera(base, tmp_path):
    path = np.zeros((N_FRAMES, 3))
    path[6:, 0] = 0.02  # the phone slid 2 cm half-way through
    rec = write_record3d(base["take"], tmp_path / "low", as_zip=False, depth_size=(160, 120), camera_path_m=path)
    (tmp_path / "low" / "rgbd" / "3.depth").unlink()
    take = open_take(rec)
    assert take.source == "record3d" and (take.camera.width, take.camera.height) == (640, 480)
    assert [f.status for f in take.frames] == ["ok"] * 3 + ["missing_depth"] + ["ok"] * 2 + ["camera_moved"] * 6
    assert any("moved 2.0 cm" in n for n in take.notes)
    ref, got = _frames(open_take(base["take"])), _frames(take)
    d, r = got[0][1], ref[0][1]
    both = (d > 0) & (r > 0)
    assert both.mean() > 0.9 and np.median(np.abs(d - r)[both]) < 0.01  # nearest-neighbour upsampled
    assert not got[3][1].any()


def test_realsense_dropped_frames_and_the_sdks_align(base, tmp_path):
    rec = write_realsense(base["take"], tmp_path / "rs.db3", drop=(4, 5), depth_size=(320, 240))
    take = open_take(rec)
    assert [f.index for f in take.frames if f.status == "dropped_frame"] == [4, 5]
    assert "dropped by the camera" in take.frames[4].message
    ref, got = _frames(open_take(base["take"])), _frames(take)
    assert sorted(got) == [i for i in range(N_FRAMES) if i not in (4, 5)]
    rgb, depth = read_frame(take, 10)  # one frame (the annotate page): the playback seeks to it
    assert np.array_equal(rgb, got[10][0]) and np.array_equal(depth, got[10][1])
    d, r = got[0][1], ref[0][1]
    both = (d > 0) & (r > 0)
    assert d.shape == (480, 640) and both.mean() > 0.9 and np.median(np.abs(d - r)[both]) < 0.01


def test_rosbag_topics_found_chosen_and_remembered(base, tmp_path):
    from demoforge.lib.takes.sources.rosbag2 import choose_topics, pair_by_stamp

    topics = {"/cam/color/image_raw": "sensor_msgs/msg/Image", "/cam/color/image_raw/compressed":
              "sensor_msgs/msg/CompressedImage", "/cam/depth/image_rect_raw": "sensor_msgs/msg/Image",
              "/cam/stereo/aligned_depth_to_color/image_raw": "sensor_msgs/msg/Image",
              "/cam/color/camera_info": "sensor_msgs/msg/CameraInfo", "/cam/depth/camera_info": "sensor_msgs/msg/CameraInfo"}
    rgb, depth, info, notes = choose_topics(topics, {}, "bag")
    assert (rgb, depth, info) == ("/cam/color/image_raw", "/cam/stereo/aligned_depth_to_color/image_raw",
                                  "/cam/color/camera_info")
    assert any("--depth-topic" in n for n in notes)
    assert choose_topics(topics, {"depth_topic": "/cam/depth/image_rect_raw"}, "bag")[1] == "/cam/depth/image_rect_raw"
    match, dt = pair_by_stamp(np.array([0, 33, 66, 100]) * 10**6, np.array([1, 70, 34]) * 10**6, 5 * 10**6)
    assert match.tolist() == [0, 2, 1, -1] and dt[:3].tolist() == [1e6, 1e6, 4e6]
    rec = write_rosbag2(base["take"], tmp_path / "bag", storage="mcap")
    r = runner.invoke(app, ["convert", str(rec), "--out", str(tmp_path / "conv"), "--rgb-topic", "/camera/color/image_raw"])
    assert r.exit_code == 0, r.output
    assert json.loads((sidecar_dir(rec) / "source.json").read_text()) == {"rgb_topic": "/camera/color/image_raw"}
    assert "paired by header stamp within 16.7 ms" in r.stderr
    conv, orig = _frames(open_take(tmp_path / "conv")), _frames(open_take(rec))
    assert all(np.array_equal(conv[i][0], orig[i][0]) and np.array_equal(conv[i][1], orig[i][1]) for i in orig)
    jpeg = write_rosbag2(base["take"], tmp_path / "jpeg_bag", storage="mcap", jpeg=True)  # CompressedImage colour
    got, ref = _frames(open_take(jpeg)), _frames(open_take(base["take"]))
    assert open_take(jpeg).decoder.info["rgb_topic"].endswith("/compressed") and sorted(got) == sorted(ref)
    assert max(np.abs(got[i][0].astype(int) - ref[i][0]).mean() for i in ref) < 3  # JPEG at quality 95


def test_frames_are_placed_on_the_time_axis_by_their_timestamps():
    from demoforge.lib.takes.sources import place_on_time_axis

    fps, stamps, keys, status, message = place_on_time_axis(
        np.array([0.0, 1 / 30, 1 / 30 + 0.002, 4 / 30, 5 / 30]), ["a", "b", "b2", "e", "f"], 30.0, "rec")
    assert keys == ["a", "b", None, None, "e", "f"]
    assert status == ["ok", "repeated_frame", "dropped_frame", "dropped_frame", "ok", "ok"]
    assert "delivered twice" in message[1] and "dropped by the camera" in message[2]
    assert np.allclose(stamps, [0, 1 / 30, 2 / 30, 3 / 30, 4 / 30, 5 / 30])
    assert place_on_time_axis(np.array([0.0, 0.1, 0.2]), [1, 2, 3], None, "rec")[0] == pytest.approx(10.0)


def _one_line_error(r, *needles):
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and "%|" not in ln]
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (r.exit_code, r.output)
    for n in needles:
        assert n in lines[0], (n, lines[0])


def _truncate(path: Path) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    return path


def test_bad_recordings_are_refused_in_one_line_with_nothing_written(base, tmp_path):
    from rosbags.rosbag1 import Writer as Bag1Writer
    from rosbags.typesys import Stores, get_typestore

    cases = {}
    cases["realsense"] = (_truncate(write_realsense(base["take"], tmp_path / "rs.db3")), ("truncated",))
    bag = tmp_path / "viewer.bag"
    ts = get_typestore(Stores.ROS1_NOETIC)
    with Bag1Writer(bag) as w:
        c = w.add_connection("/file_version", "std_msgs/msg/UInt32", typestore=ts)
        for i in range(2000):
            w.write(c, i, ts.serialize_ros1(ts.types["std_msgs/msg/UInt32"](data=3), "std_msgs/msg/UInt32"))
    cases["bag"] = (_truncate(bag), ("RealSense SDK cannot play",))
    r3d = _truncate(write_record3d(base["take"], tmp_path / "cut.r3d"))
    cases["r3d"] = (r3d, ("not a readable .r3d", "truncated"))
    bag2 = write_rosbag2(base["take"], tmp_path / "cut_bag", storage="mcap")
    mcap = next(bag2.glob("*.mcap"))
    cases["mcap"] = (_truncate(mcap.rename(tmp_path / "cut.mcap")), ("truncated",))
    cases["no_depth"] = (write_rosbag2(base["take"], tmp_path / "nodepth", depth=False), ("no depth topic", "--depth-topic"))
    export = write_record3d(base["take"], tmp_path / "export", as_zip=False)
    (export / "metadata").unlink()
    cases["no_metadata"] = (export, ("without its `metadata`",))
    for name, (path, needles) in cases.items():
        out = tmp_path / f"out_{name}"
        side = sidecar_dir(path)
        had_side = side.exists()
        r = runner.invoke(app, ["convert", str(path), "--out", str(out)])
        _one_line_error(r, str(path.name), *needles)
        assert not out.exists() and side.exists() == had_side, name
        assert not any(p.name.startswith(f".{out.name}") for p in tmp_path.iterdir())


def test_a_recordings_cache_key_reads_it_once(base, tmp_path, monkeypatch):
    import demoforge.tasks.common as common
    from demoforge.tasks.common import content_fingerprint
    from demoforge.tasks.ingest import take_media_key

    rec = write_record3d(base["take"], tmp_path / "once.r3d")
    os.utime(rec, (time.time() - 60, time.time() - 60))  # recorded a minute ago (a file written in the last 2 s is hashed again)
    monkeypatch.setenv("DEMOFORGE_DIGEST_CACHE", str(tmp_path / "digests"))
    read = []
    real = common.file_sha256
    monkeypatch.setattr(common, "file_sha256", lambda p: read.append(Path(p).name) or real(p))
    monkeypatch.setattr(common, "_FILE_HASH_MEMO", {})
    fingerprint = content_fingerprint(rec)
    assert read.count("once.r3d") == 1  # (and the side folder's small files)
    monkeypatch.setattr(common, "_FILE_HASH_MEMO", {})  # a new process: the digest is remembered on disk
    assert content_fingerprint(rec) == fingerprint and read.count("once.r3d") == 1
    monkeypatch.setattr(common, "_FILE_HASH_MEMO", {})
    key = take_media_key(rec), fingerprint
    assert read.count("once.r3d") == 1
    (sidecar_dir(rec) / "annotations.json").write_text("{}")  # annotations: not part of the media key
    assert take_media_key(rec) == key[0] and content_fingerprint(rec) != key[1]
    shutil.rmtree(sidecar_dir(rec))
    assert take_media_key(rec) != key[0]


def _count_source_opens(monkeypatch) -> list[str]:
    """The names of the take sources that open a take from now on (every way of opening one ends there)."""
    from demoforge.lib.takes.sources.folder import FolderSource, Mp4Source
    from demoforge.lib.takes.sources.recording import RecordingSource

    opened: list[str] = []
    for cls in (FolderSource, Mp4Source, RecordingSource):
        def counted(self, path, *args, _real=cls.open, **kwargs):
            opened.append(self.name)
            return _real(self, path, *args, **kwargs)
        monkeypatch.setattr(cls, "open", counted)
    return opened


def test_an_ingest_opens_its_take_once(base, tmp_path, monkeypatch):
    """The ingest flow opens its take once and its stages get that take (demoforge.tasks.common.opened_take):
    a take folder and a recording each opened once per ingest, where the flow and each of its seven stages
    used to open it again (8 opens); an unchanged take ingested again in the same process is not opened."""
    from demoforge.flows.ingest import ingest_take
    from demoforge.tasks.common import forget_opened_takes

    rec = write_record3d(base["take"], tmp_path / "rec.r3d")
    forget_opened_takes()  # as in a new process (the fixture ingested the folder in this one)
    opened = _count_source_opens(monkeypatch)
    ingest_take(str(base["take"]), str(tmp_path / "wh"), show_progress=False)
    assert opened == ["folder"]
    ingest_take(str(base["take"]), str(tmp_path / "wh2"), show_progress=False)
    assert opened == ["folder"]
    out = ingest_take(str(rec), str(tmp_path / "wh3"), show_progress=False)
    assert opened == ["folder", "record3d"] and out["object_keypoints"].rows == 11
    assert np.array_equal(_poses(tmp_path / "wh"), base["poses"], equal_nan=True)


def test_a_shared_take_is_opened_again_when_it_changes_and_each_stage_gets_its_own_frames(base, tmp_path, monkeypatch):
    from demoforge.tasks.common import opened_take

    take_dir = tmp_path / "tk"
    shutil.copytree(base["take"], take_dir)
    opened = _count_source_opens(monkeypatch)
    first = opened_take(take_dir)
    first.frames[3].flag("unreadable_rgb", "seen by the stage that decoded it")
    again = opened_take(take_dir)
    assert opened == ["folder"] and again.frames[3].status == "ok" and again.frames is not first.frames
    assert again.decoder is first.decoder and again.annotations is first.annotations  # read once, shared
    ann = json.loads((take_dir / "annotations.json").read_text())
    ann["gripper_closed_ranges"] = {"left": [], "right": [[2, 5]]}
    (take_dir / "annotations.json").write_text(json.dumps(ann))  # annotated: another take for the stages
    changed = opened_take(take_dir)
    assert opened == ["folder", "folder"]
    assert [tuple(r) for r in changed.annotations.gripper_closed_ranges["right"]] == [(2, 5)]


def test_ingest_folder_finds_recordings_beside_take_folders(base, tmp_path):
    from demoforge.flows.ingest_folder import find_take_folders

    inbox = tmp_path / "inbox"
    shutil.copytree(base["take"], inbox / "lab" / "folder_take")
    write_record3d(base["take"], inbox / "phone.r3d")
    write_rosbag2(base["take"], inbox / "lab" / "bag", storage="sqlite3")  # a bag folder holding its .db3
    (inbox / "notes.txt").write_text("not a take")
    assert find_take_folders(inbox) == [inbox / "lab" / "bag", inbox / "lab" / "folder_take", inbox / "phone.r3d"]
    from demoforge.lib.takes.sources import take_root

    video = inbox / "lab" / "folder_take" / "rgb.mp4"
    video.write_bytes(b"")
    assert take_root(video) == (inbox / "lab" / "folder_take").resolve()  # its content is the whole folder's
    assert take_root(inbox / "phone.r3d") == (inbox / "phone.r3d").resolve()
