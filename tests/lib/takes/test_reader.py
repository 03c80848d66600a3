"""demoforge.lib.takes.reader: a synthetic take read back, and every kind of bad input."""

import json
import os
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from demoforge.lib.takes import (
    FRAME_STATUSES, TakeError, iter_frames, open_take, read_frame, read_thesis_keypoints_json,
)


@pytest.fixture(scope="module")
def synth_take(tmp_path_factory):
    from demoforge.lib.synth.take import generate_take

    out = tmp_path_factory.mktemp("take") / "t"
    generate_take("pouring", seed=0, mirror=False, out_dir=out, max_frames=12, video=True)
    return out


@pytest.fixture()
def take_copy(synth_take, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(synth_take, dst)
    return dst


def _all_frames(take, **kw):
    idx, rgb, depth = [], [], []
    for b in iter_frames(take, **kw):
        idx += b.indices.tolist()
        rgb.append(b.rgb)
        depth.append(b.depth)
    return idx, (np.concatenate(rgb) if rgb else None), (np.concatenate(depth) if depth else None)


def test_synthetic_take_reads_back(synth_take):
    take = open_take(synth_take)
    cam = json.loads((synth_take / "camera.json").read_text())
    assert take.n_frames == 12 and take.rgb_kind == "images"
    np.testing.assert_allclose(take.camera.K, np.asarray(cam["K"]))
    assert (take.camera.width, take.camera.height) == (640, 480) and take.camera.fps == 30.0
    assert take.status_counts() == {"ok": 12}
    np.testing.assert_allclose(take.timestamps_s, np.arange(12) / 30.0)
    assert take.annotations is not None and len(take.annotations.object_keypoint_names) == 11
    assert take.annotations.closed_mask(12).shape == (12, 2)
    assert take.has_ground_truth
    idx, rgb, depth = _all_frames(take, batch_size=5)
    assert idx == list(range(12))
    assert rgb.shape == (12, 480, 640, 3) and rgb.dtype == np.uint8
    assert depth.shape == (12, 480, 640) and depth.dtype == np.float32
    # RGB order and metres: equal to the files
    png = cv2.imread(str(synth_take / "rgb" / "000003.png"))[..., ::-1]
    np.testing.assert_array_equal(rgb[3], png)
    raw = np.load(synth_take / "depth" / "000003.npy")
    np.testing.assert_allclose(depth[3], np.where(np.isfinite(raw) & (raw > 0), raw, 0))
    valid = depth[depth > 0]
    assert 0.2 < np.median(valid) < 3.0          # metres, not millimetres


def test_every_source_opens_and_decodes_through_one_interface(synth_take, tmp_path, monkeypatch):
    """open_take asks the registered sources (a take folder and its video as any other) and iter_frames /
    iter_depth / read_frame ask the opened take's decoder: a source of one's own (here a take in one .npz)
    plugs in with its decoder, and the stage cache hashes the inputs it names beside the path."""
    from demoforge.lib.takes import CameraInfo, FrameInfo, Take, iter_depth
    from demoforge.lib.takes.sources import SOURCES, TakeDecoder, TakeSource
    from demoforge.lib.takes.sources.folder import FolderDecoder, VideoDecoder
    from demoforge.tasks.common import content_fingerprint

    assert type(open_take(synth_take).decoder) is FolderDecoder
    assert type(open_take(synth_take, prefer="video").decoder) is VideoDecoder
    _, rgb, depth = _all_frames(open_take(synth_take))
    np.savez(tmp_path / "t.npz", rgb=rgb, depth=depth)
    (tmp_path / "t.notes").write_text("first")

    class NpzDecoder(TakeDecoder):
        def __init__(self, data):
            self.data = data

        def rgbd(self, take, idx, batch_size, num_workers):
            for s in range(0, len(idx), batch_size):
                yield [(i, self.data["rgb"][i], self.data["depth"][i]) for i in idx[s:s + batch_size]]

        def depth(self, take, batch_size, num_workers):
            for s in range(0, take.n_frames, batch_size):
                i = np.arange(s, min(s + batch_size, take.n_frames))
                yield i, self.data["depth"][i]

        def lone_depth(self, take, index):
            return self.data["depth"][index]

    class NpzSource(TakeSource):
        name = "npz"

        @classmethod
        def claims(cls, path):
            return path.suffix == ".npz"

        @classmethod
        def cache_key_inputs(cls, path):
            return {"notes": path.with_suffix(".notes")}

        def open(self, path, *, require_pose=True, prefer="images", cache_dir=None, **options):
            data = dict(np.load(path))
            camera = CameraInfo(K=np.eye(3), width=640, height=480, T_world_camera=np.eye(4))
            frames = [FrameInfo(i, i / 30, f"{path.name}#{i}", f"{path.name}#{i}") for i in range(len(data["rgb"]))]
            return Take(path=path, camera=camera, frames=frames, annotations=None, rgb_kind="recording",
                        source=self.name, decoder=NpzDecoder(data))

    monkeypatch.setitem(SOURCES._entries, "npz", NpzSource)
    take = open_take(tmp_path / "t.npz")
    assert take.source == "npz" and take.take_id == "t" and take.n_frames == 12
    idx, got_rgb, got_depth = _all_frames(take, batch_size=5)
    assert idx == list(range(12)) and np.array_equal(got_rgb, rgb) and np.array_equal(got_depth, depth)
    assert np.array_equal(np.concatenate([d for _, d in iter_depth(take, 5)]), depth)
    frame_rgb, frame_depth = read_frame(take, 4)
    assert np.array_equal(frame_rgb, rgb[4]) and np.array_equal(frame_depth, depth[4])
    key = content_fingerprint(tmp_path / "t.npz")
    (tmp_path / "t.notes").write_text("second")
    changed = content_fingerprint(tmp_path / "t.npz")
    assert changed["sha256"] == key["sha256"] and changed["notes"] != key["notes"]


def test_video_take_matches_images(synth_take, tmp_path):
    dst = tmp_path / "vid"
    shutil.copytree(synth_take, dst)
    shutil.rmtree(dst / "rgb")
    take = open_take(dst)
    assert take.rgb_kind == "video" and take.n_frames == 12
    idx, rgb, _ = _all_frames(take, batch_size=4)
    assert idx == list(range(12))
    png = cv2.imread(str(synth_take / "rgb" / "000005.png"))[..., ::-1]
    assert np.abs(rgb[5].astype(int) - png).mean() < 8       # lossy mp4v, same frame


def test_missing_camera_json(take_copy):
    (take_copy / "camera.json").unlink()
    with pytest.raises(TakeError, match="camera.json is missing"):
        open_take(take_copy)


@pytest.mark.parametrize("change, match", [
    ({"K": [[600, 0, 320], [0, 600, 240]]}, "K.*3x3"),
    ({"K": [[0, 0, 320], [0, 600, 240], [0, 0, 1]]}, "non-positive focal length"),
    ({"K": [[-600, 0, 320], [0, 600, 240], [0, 0, 1]]}, "non-positive focal length"),
    ({"T_world_camera": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "not a rigid transform"),
    ({"T_world_camera": [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "not a rigid transform"),
    ({"width": 0}, "'width' must be a positive integer"),
    ({"fps": -5}, "'fps' must be a positive number"),
])
def test_bad_camera_json(take_copy, change, match):
    cam = json.loads((take_copy / "camera.json").read_text())
    cam.update(change)
    (take_copy / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(TakeError, match=match) as e:
        open_take(take_copy)
    assert "camera.json" in str(e.value)


def test_camera_json_missing_key_and_bad_syntax(take_copy):
    cam = json.loads((take_copy / "camera.json").read_text())
    del cam["T_world_camera"]
    (take_copy / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(TakeError, match="'T_world_camera' is missing"):
        open_take(take_copy)
    (take_copy / "camera.json").write_text("{not json")
    with pytest.raises(TakeError, match="not valid JSON"):
        open_take(take_copy)


def test_camera_size_differs_from_frames(take_copy):
    cam = json.loads((take_copy / "camera.json").read_text())
    cam["width"], cam["height"] = 1280, 720
    (take_copy / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(TakeError, match="640 x 480"):
        open_take(take_copy)


def test_fps_defaults_to_30(take_copy):
    cam = json.loads((take_copy / "camera.json").read_text())
    del cam["fps"]
    (take_copy / "camera.json").write_text(json.dumps(cam))
    take = open_take(take_copy)
    assert take.camera.fps == 30.0 and take.frames[3].timestamp_s == pytest.approx(0.1)


def test_corrupt_image_is_flagged_and_skipped(take_copy):
    (take_copy / "rgb" / "000004.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage garbage")
    data = (take_copy / "rgb" / "000007.png").read_bytes()
    (take_copy / "rgb" / "000007.png").write_bytes(data[: len(data) // 3])     # truncated PNG
    (take_copy / "rgb" / "000009.png").write_bytes(b"")                      # empty file
    take = open_take(take_copy)
    assert take.frames[9].status == "unreadable_rgb"                        # found at index time
    idx, rgb, _ = _all_frames(take, batch_size=4)
    assert 4 not in idx and 9 not in idx
    assert take.frames[4].status == "unreadable_rgb" and "000004.png" in take.frames[4].message
    # a truncated PNG does not decode here (OpenCV's libpng refuses an incomplete buffer): flagged and
    # left out of the batches like the corrupt one, with no exception
    assert take.frames[7].status == "unreadable_rgb" and "000007.png" in take.frames[7].message
    assert 7 not in idx and idx == [i for i in range(take.n_frames) if i not in (4, 7, 9)]
    assert len(rgb) == len(idx)
    assert all(f.status in FRAME_STATUSES for f in take.frames)


def test_truncated_video_keeps_decodable_frames(synth_take, tmp_path):
    dst = tmp_path / "trunc"
    shutil.copytree(synth_take, dst)
    shutil.rmtree(dst / "rgb")
    data = (dst / "rgb.mp4").read_bytes()
    (dst / "rgb.mp4").write_bytes(data[: int(len(data) * 0.6)])
    take = open_take(dst, cache_dir=tmp_path / "cache")
    idx, rgb, depth = _all_frames(take, batch_size=4)
    assert 3 <= len(idx) < 12 and idx == list(range(len(idx)))
    bad = [f for f in take.frames if f.status != "ok"]
    assert len(bad) == 12 - len(idx)
    assert all(f.status == "unreadable_rgb" and "truncated" in f.message for f in bad)
    png = cv2.imread(str(synth_take / "rgb" / "000002.png"))[..., ::-1]
    assert np.abs(rgb[2].astype(int) - png).mean() < 8
    assert take.notes and "truncated" in take.notes[0]


def test_salvaged_streams_are_decoded_and_their_folders_removed_when_the_process_ends(synth_take, tmp_path):
    """Without a cache_dir the salvaged stream lives in a temporary folder: there while the process
    reads the take, gone after it exits, and no folder is left behind by a video that cannot be saved."""
    trunc, broken = tmp_path / "trunc", tmp_path / "broken"
    for dst in (trunc, broken):
        shutil.copytree(synth_take, dst)
        shutil.rmtree(dst / "rgb")
    data = (trunc / "rgb.mp4").read_bytes()
    (trunc / "rgb.mp4").write_bytes(data[: int(len(data) * 0.6)])
    (broken / "rgb.mp4").write_bytes(b"\x00\x00\x00\x18ftypisom" + b"\x00" * 100)
    scratch = tmp_path / "tmpdir"
    scratch.mkdir()
    code = ("import sys, pathlib; from demoforge.lib.takes import open_take; "
            "t = open_take(sys.argv[1]); b = open_take(sys.argv[2]); "
            "print(sorted(p.name for p in pathlib.Path(sys.argv[3]).rglob('*'))); "
            "print(sum(f.status == 'ok' for f in t.frames), sum(f.status == 'ok' for f in b.frames))")
    r = subprocess.run([sys.executable, "-c", code, str(trunc), str(broken), str(scratch)], capture_output=True,
                       text=True, env={**os.environ, "TMPDIR": str(scratch)}, timeout=120)
    assert r.returncode == 0, r.stderr
    during, ok = r.stdout.splitlines()[-2:]
    assert "rgb.salvaged.m4v" in during and during.count("demoforge_video_") == 1  # the failed one: none
    n_trunc, n_broken = map(int, ok.split())
    assert 3 <= n_trunc < 12 and n_broken == 0
    assert list(scratch.iterdir()) == []


def test_unopenable_video_is_reported_not_fatal(take_copy):
    shutil.rmtree(take_copy / "rgb")
    (take_copy / "rgb.mp4").write_bytes(b"\x00\x00\x00\x18ftypisom" + b"\x00" * 100)
    take = open_take(take_copy)
    assert take.n_frames == 12                                # indexed from depth/
    assert {f.status for f in take.frames} == {"unreadable_rgb"}
    assert _all_frames(take)[0] == []


def test_depth_wrong_size(take_copy):
    np.save(take_copy / "depth" / "000002.npy", np.ones((240, 320), np.float32))
    take = open_take(take_copy)
    assert take.frames[2].status == "depth_size_mismatch" and "(240, 320)" in take.frames[2].message
    idx, _, depth = _all_frames(take)
    assert 2 in idx and not depth[idx.index(2)].any()        # kept, all-invalid depth


def test_all_zero_and_nan_depth(take_copy):
    np.save(take_copy / "depth" / "000001.npy", np.zeros((480, 640), np.float32))
    np.save(take_copy / "depth" / "000002.npy", np.full((480, 640), np.nan, np.float32))
    d = np.load(take_copy / "depth" / "000003.npy")
    d[:10] = np.nan
    d[10:20] = -1
    np.save(take_copy / "depth" / "000003.npy", d)
    take = open_take(take_copy)
    idx, _, depth = _all_frames(take)
    assert take.frames[1].status == "all_zero_depth" and take.frames[2].status == "all_zero_depth"
    assert take.frames[3].status == "ok"
    assert np.all(depth[3][:20] == 0) and np.all(np.isfinite(depth))


def test_unreadable_depth(take_copy):
    (take_copy / "depth" / "000005.npy").write_bytes(b"not an npy file")
    take = open_take(take_copy)
    assert take.frames[5].status == "unreadable_depth"
    rgb, depth = read_frame(take, 5)
    assert rgb is not None and not depth.any()


def test_missing_depth_frames_count_mismatch(take_copy):
    (take_copy / "depth" / "000004.npy").unlink()
    (take_copy / "depth" / "000011.npy").unlink()
    (take_copy / "depth" / "000010.npy").unlink()
    take = open_take(take_copy)
    assert take.n_frames == 12
    assert [f.index for f in take.frames if f.status == "missing_depth"] == [4, 10, 11]
    idx, _, depth = _all_frames(take)
    assert idx == list(range(12)) and not depth[4].any()


def test_missing_rgb_frames(take_copy):
    (take_copy / "rgb" / "000006.png").unlink()
    take = open_take(take_copy)
    assert take.frames[6].status == "missing_rgb"
    assert 6 not in _all_frames(take)[0]


def test_malformed_annotations(take_copy):
    ann = json.loads((take_copy / "annotations.json").read_text())
    bad = dict(ann, object_keypoints_2d=dict(ann["object_keypoints_2d"], uv=ann["object_keypoints_2d"]["uv"][:3]))
    (take_copy / "annotations.json").write_text(json.dumps(bad))
    with pytest.raises(TakeError, match="11 names but 3 uv"):
        open_take(take_copy)
    bad = dict(ann, gripper_closed_ranges={"left": [[5, 2]], "right": []})
    (take_copy / "annotations.json").write_text(json.dumps(bad))
    with pytest.raises(TakeError, match=r"gripper_closed_ranges.left\[0\]"):
        open_take(take_copy)
    bad = dict(ann, gripper_closed_ranges={"left": [[0, 5], [3, 8]]})
    (take_copy / "annotations.json").write_text(json.dumps(bad))
    with pytest.raises(TakeError, match="overlapping"):
        open_take(take_copy)
    bad = dict(ann, gripper_closed_ranges={"left": [[0, 500]]})
    (take_copy / "annotations.json").write_text(json.dumps(bad))
    with pytest.raises(TakeError, match="has 12 frames"):
        open_take(take_copy)
    (take_copy / "annotations.json").write_text("[1, 2")
    with pytest.raises(TakeError, match="annotations.json"):
        open_take(take_copy)


def test_png16_depth_in_mm_and_jpg_frames(take_copy):
    for p in sorted((take_copy / "depth").glob("*.npy")):
        d = np.load(p)
        mm = np.round(np.nan_to_num(d) * 1000).astype(np.uint16)
        cv2.imwrite(str(p.with_suffix(".png")), mm)
        p.unlink()
    for p in sorted((take_copy / "rgb").glob("*.png")):
        cv2.imwrite(str(p.with_suffix(".jpg")), cv2.imread(str(p)), [cv2.IMWRITE_JPEG_QUALITY, 95])
        p.unlink()
    take = open_take(take_copy)
    assert take.n_frames == 12 and take.status_counts() == {"ok": 12}
    idx, rgb, depth = _all_frames(take)
    assert rgb.shape == (12, 480, 640, 3)
    assert depth.dtype == np.float32 and 0.2 < np.median(depth[depth > 0]) < 3.0


def test_png16_depth_matches_metres(synth_take, tmp_path):
    dst = tmp_path / "mm"
    shutil.copytree(synth_take, dst)
    d = np.load(dst / "depth" / "000000.npy")
    (dst / "depth" / "000000.npy").unlink()
    cv2.imwrite(str(dst / "depth" / "000000.png"), np.round(np.nan_to_num(d) * 1000).astype(np.uint16))
    take = open_take(dst)
    _, depth = read_frame(take, 0)
    ok = np.isfinite(d) & (d > 0)
    np.testing.assert_allclose(depth[ok], d[ok], atol=6e-4)


def test_real_dexcap_depth_png(tmp_path):
    from demoforge.lib import SHARED_DATA

    src = SHARED_DATA / "rgbd" / "dexcap_frame_0"
    if not src.is_dir():
        pytest.skip(f"{src} absent: the real RGB-D frame comes with the shared data folder "
                    "(../shared/data beside the checkout)")
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    shutil.copy(src / "color_image.jpg", tmp_path / "rgb" / "frame_0.jpg")
    shutil.copy(src / "depth_image.png", tmp_path / "depth" / "frame_0.png")
    K = [[898.2010498046875, 0, 657.4981079101562], [0, 897.86669921875, 364.30950927734375], [0, 0, 1]]
    pose = np.loadtxt(src / "pose.txt")
    (tmp_path / "camera.json").write_text(json.dumps(
        {"K": K, "width": 1280, "height": 720, "T_world_camera": np.eye(4).tolist()}))
    take = open_take(tmp_path)
    assert take.n_frames == 1 and take.camera.fps == 30.0
    rgb, depth = read_frame(take, 0)
    assert rgb.shape == (720, 1280, 3)
    valid = depth > 0
    assert 0.85 < valid.mean() < 1.0 and 0.3 < np.median(depth[valid]) < 0.8   # README: ~95 %, ~0.50 m
    assert pose.shape == (4, 4)


def test_thesis_keypoint_json(tmp_path):
    rng = np.random.default_rng(0)
    rel = rng.normal(0, 0.03, (21, 3))
    t = np.array([0.1, -0.05, 0.6])
    doc = {
        "rgb_frame000010.png": {"left": {"3d_keypoints": rel.tolist(), "translation": t.tolist(),
                                         "2d_keypoints": rng.normal(300, 5, (21, 2)).tolist(),
                                         "focal_length": 525.0},
                                "right": {}},
        "rgb_frame000012.png": {"left": None, "right": {"3d_keypoints": rel.tolist(), "translation": t.tolist(),
                                                        "2d_keypoints": np.zeros((21, 2)).tolist()}},
    }
    p = tmp_path / "kp.json"
    p.write_text(json.dumps(doc))
    hands = read_thesis_keypoints_json(p)
    assert [(h.frame, h.hand) for h in hands] == [(0, "left"), (2, "right")]
    np.testing.assert_allclose(hands[0].joints_cam, rel + t)
    assert hands[0].focal_length == 525.0 and hands[1].confidence is None
    names = [f"rgb_frame{i:06d}.png" for i in range(5, 15)]
    hands = read_thesis_keypoints_json(p, frame_names=names)
    assert [h.frame for h in hands] == [5, 7]
    doc["rgb_frame000012.png"]["right"]["3d_keypoints"] = [[0, 0]]
    p.write_text(json.dumps(doc))
    with pytest.raises(TakeError, match="21x3"):
        read_thesis_keypoints_json(p)
