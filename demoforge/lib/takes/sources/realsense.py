"""Intel RealSense recordings read with the SDK (``pyrealsense2``, playback without a camera): the
``.bag`` files of the RealSense Viewer and ``rs.recorder`` (ROS 1 bag layout, SDK before 2.57) and the
``.db3`` files the SDK writes since (ROS 2 bag layout, ``/device_0/...`` topics).

Depth is aligned to the colour image with the SDK's own ``rs.align``; the intrinsics come from the
colour stream's profile, the depth scale from the depth sensor (``depth_units``), the timestamps are
the colour frames' (hardware clock when the recording has it). A frame missing from the colour stream
(a jump in the timestamps) is a ``dropped_frame``, a colour frame delivered twice a ``repeated_frame``.
"""

from __future__ import annotations

import sqlite3
from datetime import timedelta
from pathlib import Path
from typing import Iterator

import numpy as np

from demoforge.lib.takes.sources.recording import (
    Recording, RecordingIndex, RecordingSource, place_on_time_axis,
)
from demoforge.lib.takes.types import TakeError

WAIT_MS = 200      # one wait for the next frameset; the end of the file is the playback's "stopped"
STALL_S = 30.0     # no frame for this long while the playback says it is playing: give up
SEEK_BACK_NS = 200_000_000  # decoding starts this long before the first frame wanted (the seek is not exact)
INDEX_PASSES = 3   # readings of the file at most, until two agree on the colour frames and repeats (build_index)


def _repeats(numbers: list[int], paired: list[bool]) -> dict[int, int]:
    """{colour frame number: extra deliveries} of one reading (RealSenseRecording._index's rule: a frame delivered
    alone and then with its depth is one frame)."""
    counts: dict[int, list[int]] = {}  # frame number -> [deliveries without depth, with depth]
    for n, d in zip(numbers, paired):
        counts.setdefault(n, [0, 0])[int(d)] += 1
    copies = {n: (with_depth or alone) for n, (alone, with_depth) in counts.items()}  # the count that matters
    return {n: k - 1 for n, k in copies.items() if k > 1}


def is_realsense_db3(path: Path) -> bool:
    """A ``.db3`` written by the RealSense SDK (its topics start with ``/device_0/``)."""
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            names = [r[0] for r in con.execute("SELECT name FROM topics LIMIT 200")]
        finally:
            con.close()
    except sqlite3.Error:
        return False
    return any(n.startswith("/device_0/") for n in names)


class RealSenseRecording(Recording):
    version = "4"   # 2: the playback position of every frame (seeking); 3: a frame delivered alone, then with depth, is not
    # a repeat, and the file read until two passes agree; 4: the passes agree on the repeats too

    def _start(self, seek_ns: int = 0):
        """A started pipeline playing the file as fast as it is read from ``seek_ns`` (the playback's
        position), and the aligner."""
        import pyrealsense2 as rs

        cfg = rs.config()
        try:
            cfg.enable_device_from_file(str(self.path), repeat_playback=False)
            pipe = rs.pipeline()
            profile = pipe.start(cfg)
        except RuntimeError as e:
            raise TakeError(f"{self.path}: the RealSense SDK cannot play this recording ({e}); the file is truncated "
                            f"or corrupt, or has no colour and depth streams") from None
        # as fast as it is read, from the very start: started in real time, the playback has already
        # let the first frames go by (seen: frame 0 lost in about half the runs)
        playback = profile.get_device().as_playback()
        playback.pause()
        playback.set_real_time(False)
        playback.seek(timedelta(microseconds=max(0, int(seek_ns)) // 1000))
        playback.resume()
        return pipe, profile, rs.align(rs.stream.color)

    @staticmethod
    def _framesets(pipe, profile) -> Iterator:
        """Every frameset of the playback, until it stops."""
        import pyrealsense2 as rs

        playback = profile.get_device().as_playback()
        waited = 0.0
        while True:
            ok, fs = pipe.try_wait_for_frames(WAIT_MS)
            if ok:
                waited = 0.0
                yield fs
                continue
            waited += WAIT_MS / 1000
            if playback.current_status() == rs.playback_status.stopped or waited > STALL_S:
                return

    def build_index(self) -> RecordingIndex:
        # the playback pipeline can lose a frame when the machine is loaded (seen: the first one, or one
        # handed over twice) or deliver one twice; a frame the camera dropped or repeated is so in every pass:
        # the file is read until two passes agree on the colour frames and their repeats, at most INDEX_PASSES
        # times, and the fullest pass with the fewest repeats is kept
        passes, seen = [], []
        for _ in range(INDEX_PASSES):
            passes.append(self._index_pass())
            seen.append((set(passes[-1][0]), _repeats(passes[-1][0], passes[-1][5])))
            if len(seen) > 1 and seen[-1] == seen[-2]:
                break
        best = max(range(len(passes)), key=lambda i: (len(seen[i][0]), -sum(seen[i][1].values())))
        numbers, times, has_depth, domains, position, paired, intr, scale, fps, registered = passes[best]
        index = self._index(numbers, times, has_depth, domains, intr, scale, fps, paired)
        index.info["registered"] = registered
        index.info["position_ns"] = [None if n is None else position.get(n) for n in index.keys]
        if registered:
            index.notes[0] = index.notes[0].replace("depth aligned to colour by the SDK",
                                                    "depth recorded already registered to colour (used as is)")
        return index

    def _index_pass(self) -> tuple:
        """One reading of the file: (colour frame numbers, their times s, has depth per number, timestamp
        domains, playback position per number, whether each delivery held depth, intrinsics, depth scale,
        fps, depth registered to colour)."""
        import pyrealsense2 as rs

        pipe, profile, _ = self._start()
        try:
            streams = {s.stream_type(): s for s in profile.get_streams()}
            if rs.stream.color not in streams:
                raise TakeError(f"{self.path}: the recording has no colour stream (only "
                                f"{', '.join(str(s) for s in streams)}); record colour and depth")
            if rs.stream.depth not in streams:
                raise TakeError(f"{self.path}: the recording has no depth stream; record colour and depth")
            colour = streams[rs.stream.color].as_video_stream_profile()
            intr = colour.get_intrinsics()
            registered = _registered(streams[rs.stream.depth].as_video_stream_profile(), colour)
            scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
            numbers, times, has_depth, domains, position, paired = [], [], {}, set(), {}, []
            playback = profile.get_device().as_playback()
            for fs in self._framesets(pipe, profile):
                c = fs.get_color_frame()
                if not c:
                    continue
                n = int(c.get_frame_number())
                numbers.append(n)
                position.setdefault(n, int(playback.get_position()))
                times.append(float(c.get_timestamp()) / 1000.0)
                domains.add(str(c.get_frame_timestamp_domain()).rsplit(".", 1)[-1])
                paired.append(bool(fs.get_depth_frame()))
                has_depth[n] = has_depth.get(n, False) or paired[-1]
        except RuntimeError as e:
            raise TakeError(f"{self.path}: the RealSense recording cannot be read to the end ({e}); the file is "
                            f"truncated or corrupt") from None
        finally:
            pipe.stop()
        if not numbers:
            raise TakeError(f"{self.path}: no colour frames could be read from the recording (truncated or empty)")
        return numbers, times, has_depth, domains, position, paired, intr, scale, colour.fps(), registered

    def _index(self, numbers, times, has_depth, domains, intr, scale, fps, paired) -> RecordingIndex:
        """paired: per delivery, whether its frameset held depth. A colour frame the SDK's syncer delivers
        alone and then again with its depth (seen on a loaded machine) is one frame, not a repeat: a frame
        counts as repeated when it came more than once with depth, or more than once and never with it."""
        first_time: dict[int, float] = {}
        for n, t in zip(numbers, times):
            first_time.setdefault(n, t)
        repeats = _repeats(numbers, paired)
        nums = sorted(first_time, key=first_time.get)
        fps, stamps, keys, status, message = place_on_time_axis(
            np.array([first_time[n] for n in nums]), nums, float(fps), str(self.path))
        for i, n in enumerate(keys):
            if n is None:
                continue
            if n in repeats:
                status[i], message[i] = "repeated_frame", (f"colour frame {n} delivered {repeats[n] + 1} times; "
                                                           f"the copies are discarded")
            elif not has_depth.get(n):
                status[i], message[i] = "missing_depth", f"no depth frame with colour frame {n}"
        K = [[intr.fx, 0.0, intr.ppx], [0.0, intr.fy, intr.ppy], [0.0, 0.0, 1.0]]
        dropped = sum(s == "dropped_frame" for s in status)
        notes = [f"RealSense recording: {len(nums)} colour frames at {fps:.1f} fps ({', '.join(sorted(domains))} "
                 f"timestamps), depth scale {scale * 1000:.3f} mm/unit, depth aligned to colour by the SDK"
                 + (f"; {dropped} frame(s) dropped" if dropped else "")
                 + (f"; {len(repeats)} frame(s) repeated" if repeats else "")]
        info = {"format": "realsense", "depth_scale": scale, "depth_integer_scale": scale, "timestamp_domains": sorted(domains),
                "distortion": str(intr.model), "coeffs": list(intr.coeffs)}
        return RecordingIndex(width=int(intr.width), height=int(intr.height), K=K, fps=fps, timestamps_s=stamps,
                              keys=keys, status=status, message=message, notes=notes, info=info)

    def decode(self, index: RecordingIndex, wanted: list[int], retry: bool = True
               ) -> Iterator[tuple[int, np.ndarray | None, np.ndarray | None, str]]:
        slot = {index.keys[i]: i for i in wanted}
        position = {n: i for i, n in enumerate(index.keys) if n is not None}
        last = max(wanted)
        done: set[int] = set()
        scale = np.float32(index.info["depth_scale"])
        positions = index.info.get("position_ns") or []
        first = positions[wanted[0]] if wanted[0] < len(positions) and positions[wanted[0]] is not None else 0
        pipe, profile, align = self._start(seek_ns=first - SEEK_BACK_NS)  # a frame shown on the annotate page:
        try:                                                                # no replay from the start
            for fs in self._framesets(pipe, profile):
                if len(done) == len(wanted):
                    break
                c = fs.get_color_frame()
                if not c:
                    continue
                n = int(c.get_frame_number())
                i = slot.get(n)
                if i is None or i in done:
                    if position.get(n, -1) > last:
                        break
                    continue
                done.add(i)
                aligned = fs if index.info.get("registered") else align.process(fs)
                d = aligned.get_depth_frame()
                rgb = _colour(aligned.get_color_frame() or c)
                depth = np.asanyarray(d.get_data()).astype(np.float32) * scale if d else None
                yield i, rgb, depth, "" if rgb is not None else f"colour format {c.get_profile().format()} not read"
        finally:
            pipe.stop()
        missing = [i for i in wanted if i not in done]
        if missing and retry:  # the SDK's playback now and then lets a frameset go by: play those again
            yield from self.decode(index, missing, retry=False)
            return
        for i in missing:
            yield i, None, None, "frame not found when playing the recording back (truncated?)"


def _registered(depth, colour) -> bool:
    """Depth already in the colour camera's pixels (same intrinsics, identity extrinsics): the SDK's
    align would only resample it (holes where its pixel footprints round apart), so it is used as is."""
    a, b = depth.get_intrinsics(), colour.get_intrinsics()
    same = (a.width, a.height) == (b.width, b.height) and np.allclose(
        [a.fx, a.fy, a.ppx, a.ppy], [b.fx, b.fy, b.ppx, b.ppy], atol=1e-3)
    e = depth.get_extrinsics_to(colour)
    return bool(same and np.allclose(e.rotation, np.eye(3).reshape(-1), atol=1e-6)
                and np.allclose(e.translation, 0.0, atol=1e-6))


def _colour(frame) -> np.ndarray | None:
    import cv2
    import pyrealsense2 as rs

    img = np.asanyarray(frame.get_data())
    fmt = frame.get_profile().format()
    if fmt == rs.format.rgb8:
        return np.array(img, copy=True)
    conv = {rs.format.bgr8: cv2.COLOR_BGR2RGB, rs.format.rgba8: cv2.COLOR_RGBA2RGB,
            rs.format.bgra8: cv2.COLOR_BGRA2RGB, rs.format.yuyv: cv2.COLOR_YUV2RGB_YUYV}.get(fmt)
    return None if conv is None else cv2.cvtColor(np.ascontiguousarray(img), conv)


class RealSenseSource(RecordingSource):
    """A RealSense recording: ``.bag`` (ROS 1 layout) or an SDK-written ``.db3`` (ROS 2 layout)."""

    name = "realsense"
    description = "RealSense recording (.bag, or the .db3 the SDK writes since 2.57), read with pyrealsense2"
    recording_cls = RealSenseRecording

    @classmethod
    def claims(cls, path: Path) -> bool:
        if not path.is_file():
            return False
        suffix = path.suffix.lower()
        return suffix == ".bag" or (suffix == ".db3" and is_realsense_db3(path))
