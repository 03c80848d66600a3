"""The RealSense take source on a real recording written by the SDK: ../shared/data/realsense/
single_depth_color_640x480.bag (librealsense's unit-test recording, ../shared/data/README.md), an Intel
D435 whose depth (640x480 z16, its own intrinsics fx = fy = 390.43, cx 331.39, cy 242.19) is not aligned
to the colour image (640x480 rgb8, fx 613.2, fy 613.42, cx 319.94, cy 239.18). The take reports the colour
camera's intrinsics and gives the RGB frame with the depth the SDK aligned to it (rs.align), in metres."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest

from demoforge.lib import SHARED_DATA
from demoforge.lib.takes import open_take, read_frame

BAG = SHARED_DATA / "realsense" / "single_depth_color_640x480.bag"
COLOUR_K = (613.2, 613.42, 319.94, 239.18)  # fx, fy, cx, cy of the colour stream (README)
DEPTH_K = (390.43, 390.43, 331.39, 242.19)  # ... and of the depth stream

pytestmark = pytest.mark.skipif(not BAG.is_file(), reason=f"{BAG} absent: the real RealSense recording comes with "
                                "the shared data folder (../shared/data beside the checkout)")


def _sdk_framesets(path) -> tuple[list[tuple[int, np.ndarray, np.ndarray]], dict]:
    """The recording played with pyrealsense2 itself, not through demoforge: per frameset (colour frame
    number, depth as recorded (uint16, the depth camera's pixels), depth aligned to the colour image by
    rs.align(rs.stream.color) (uint16)), and {stream: (fx, fy, cx, cy, width, height)} with the depth scale."""
    import pyrealsense2 as rs

    cfg = rs.config()
    cfg.enable_device_from_file(str(path), repeat_playback=False)
    pipe = rs.pipeline()
    profile = pipe.start(cfg)
    out = []
    try:
        playback = profile.get_device().as_playback()
        playback.pause()  # as fast as it is read, from the start (not in real time: no frameset let go by)
        playback.set_real_time(False)
        playback.seek(timedelta(0))
        playback.resume()
        streams = {}
        for s in profile.get_streams():
            i = s.as_video_stream_profile().get_intrinsics()
            streams[s.stream_type()] = (i.fx, i.fy, i.ppx, i.ppy, i.width, i.height)
        info = {"colour": streams[rs.stream.color], "depth": streams[rs.stream.depth],
                "scale": profile.get_device().first_depth_sensor().get_depth_scale()}
        align = rs.align(rs.stream.color)
        for _ in range(100):
            ok, fs = pipe.try_wait_for_frames(500)
            if not ok:
                if playback.current_status() == rs.playback_status.stopped:
                    break
                continue
            colour, depth = fs.get_color_frame(), fs.get_depth_frame()
            if not colour or not depth:
                continue
            raw = np.asanyarray(depth.get_data()).copy()
            aligned = np.asanyarray(align.process(fs).get_depth_frame().get_data()).copy()
            out.append((int(colour.get_frame_number()), raw, aligned))
    finally:
        pipe.stop()
    return out, info


def test_realsense_bag_gives_the_colour_intrinsics_rgb_and_depth_aligned_by_the_sdk():
    sdk, info = _sdk_framesets(BAG)
    # the recording is what the README says (so what follows tests the reader, not the file)
    np.testing.assert_allclose(info["colour"][:4], COLOUR_K, atol=0.01)
    np.testing.assert_allclose(info["depth"][:4], DEPTH_K, atol=0.01)
    assert info["colour"][4:] == info["depth"][4:] == (640, 480) and sdk

    take = open_take(BAG, require_pose=False)
    assert take.source == "realsense" and take.n_frames == 1 and take.camera.T_world_camera is None
    assert (take.camera.width, take.camera.height) == (640, 480)
    K = take.K
    np.testing.assert_allclose([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], COLOUR_K, atol=0.01)  # the colour camera's
    assert K[0, 1] == 0 and list(K[2]) == [0, 0, 1]
    assert any("depth aligned to colour by the SDK" in n for n in take.notes), take.notes

    rgb, depth = read_frame(take, 0)
    assert rgb is not None and rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8
    assert rgb.std() > 20 and len(np.unique(rgb.reshape(-1, 3), axis=0)) > 1000  # a picture, not a blank frame
    assert depth.shape == (480, 640) and depth.dtype == np.float32  # the colour image's grid
    valid = depth > 0
    assert valid.mean() > 0.9  # the scene is in range almost everywhere
    metres = depth[valid]
    assert ((metres > 0.2) & (metres < 10.0)).mean() > 0.99 and 0.3 < np.median(metres) < 5.0  # metres, not mm

    # the SDK's own alignment of the frameset with this colour frame, in metres: the same depth, pixel for pixel
    number = take.decoder.index.keys[0]
    raw, aligned = next((r, a) for n, r, a in sdk if n == number)
    np.testing.assert_allclose(depth, aligned.astype(np.float32) * np.float32(info["scale"]), rtol=0, atol=1e-6)
    # ... which is not the depth as recorded: another valid mask, other values (the depth camera's pixels)
    assert ((raw > 0) != valid).mean() > 0.02
    assert (np.abs(raw.astype(np.float32) * np.float32(info["scale"]) - depth) < 1e-6).mean() < 0.5


def test_a_colour_frame_the_syncer_delivers_alone_then_with_depth_is_not_a_repeat(tmp_path):
    """On a loaded machine the SDK's syncer sometimes hands a colour frame over alone and then again with its
    depth frame: one frame, status ok. A frame that came twice with depth is a repeat (the copy discarded)."""
    from types import SimpleNamespace

    from demoforge.lib.takes.sources.realsense import RealSenseRecording

    intr = SimpleNamespace(fx=600.0, fy=600.0, ppx=320.0, ppy=240.0, width=640, height=480, model="none",
                           coeffs=[0.0] * 5)
    rec = RealSenseRecording.__new__(RealSenseRecording)
    rec.path = tmp_path / "x.bag"
    numbers, times = [0, 1, 1, 2, 3, 3], [0.0, 1 / 30, 1 / 30, 2 / 30, 3 / 30, 3 / 30]
    paired = [True, False, True, True, True, True]  # frame 1: alone, then with depth; frame 3: twice with depth
    has_depth = {0: True, 1: True, 2: True, 3: True}
    index = rec._index(numbers, times, has_depth, {"hardware_clock"}, intr, 0.0001, 30, paired)
    assert dict(zip(index.keys, index.status)) == {0: "ok", 1: "ok", 2: "ok", 3: "repeated_frame"}


def test_a_repeat_seen_in_one_reading_only_is_the_playbacks_and_one_in_every_reading_is_the_files(tmp_path):
    """build_index reads the file until two passes agree on the colour frames and their repeats: a frame the
    playback handed over twice in one pass only is ok; one repeated in every pass stays a repeat."""
    from types import SimpleNamespace

    from demoforge.lib.takes.sources.realsense import RealSenseRecording

    intr = SimpleNamespace(fx=600.0, fy=600.0, ppx=320.0, ppy=240.0, width=640, height=480, model="none",
                           coeffs=[0.0] * 5)

    def reading(numbers):
        times = [n / 30 for n in numbers]
        return (numbers, times, {n: True for n in numbers}, {"hardware_clock"}, {n: 0 for n in numbers},
                [True] * len(numbers), intr, 0.0001, 30, False)

    def index_of(readings):
        rec = RealSenseRecording.__new__(RealSenseRecording)
        rec.path = tmp_path / "x.bag"
        it = iter(readings)
        rec._index_pass = lambda: next(it)
        index = rec.build_index()
        return dict(zip(index.keys, index.status))

    clean, spurious = [0, 1, 2, 3], [0, 1, 1, 2, 3]
    assert index_of([reading(spurious), reading(clean), reading(clean)]) == {0: "ok", 1: "ok", 2: "ok", 3: "ok"}
    assert index_of([reading(clean), reading(spurious), reading(clean)]) == {0: "ok", 1: "ok", 2: "ok", 3: "ok"}
    assert index_of([reading(spurious), reading(spurious)])[1] == "repeated_frame"
