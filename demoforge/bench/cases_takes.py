"""Benchmark cases of the take sources (stage `takes`): opening a recording again and keying it for the
cache, against doing the straightforward thing every time."""

from __future__ import annotations

import os
import time
from pathlib import Path

from demoforge.bench.timing import BenchCase
from demoforge.lib.scratch import folder_removed_at_exit
from demoforge.lib.takes import iter_frames, open_take
from demoforge.lib.takes.sources.realsense import RealSenseRecording
from demoforge.lib.takes.sources.writers import write_realsense


def _recording(frames: int) -> tuple[Path, Path]:
    """A RealSense recording (written by the SDK) of a synthetic take's frames, looped to ``frames``."""
    from demoforge.lib.synth.take import generate_take  # lazy: mujoco

    d = folder_removed_at_exit("demoforge_bench_takes_")
    generate_take("pouring", 0, False, d / "take", max_frames=12, video=False)
    take = open_take(d / "take")
    base = [(r, z) for b in iter_frames(take) for r, z in zip(b.rgb, b.depth)]
    rec = write_realsense(None, d / "rec.db3", camera=take.camera, pace_s=1 / take.fps,
                          frames=((i, *base[i % len(base)]) for i in range(frames)))
    old = time.time() - 60  # a recording made a minute ago (one written in the last 2 s is hashed again)
    os.utime(rec, (old, old))
    return d, rec


def _both_digests(a: str, b: str) -> None:
    assert len(a) == len(b) == 64 and int(a, 16) >= 0 and int(b, 16) >= 0


def cases(quick: bool) -> list[BenchCase]:
    n = 60 if quick else 300

    def open_setup(k: int):
        _, rec = _recording(k)
        open_take(rec, require_pose=False)  # the first open indexes and remembers

        def fast():  # every later command: the remembered index
            return [f.status for f in open_take(rec, require_pose=False).frames]

        def baseline():  # index the recording again (one playback pass through the SDK)
            return RealSenseRecording(rec).build_index().status

        return fast, baseline

    def key_setup(k: int):
        from demoforge.tasks import common  # lazy: prefect

        _, rec = _recording(k)
        # right before it is fast: the remembered digest is the file's (each setup writes its own recording,
        # with the SDK's wall-clock times in it, so fast and baseline hash different files)
        assert common.content_fingerprint(rec)["sha256"] == common.file_sha256(rec)

        def fast():  # a new process: the digest remembered with the file's identity
            common.forget_file_digests()
            return common.content_fingerprint(rec)["sha256"]

        def baseline():  # hash the recording's bytes again
            return common.file_sha256(rec)

        return fast, baseline

    def same(a, b):
        assert list(a) == list(b)

    return [
        BenchCase("takes", "open a RealSense recording again (its frame index)", n, "frames",
                  "index it again: one SDK playback pass", open_setup, same, repeats=2),
        BenchCase("takes", "cache key of a RealSense recording in a new process", n, "frames",
                  "sha256 of the whole file again", key_setup, _both_digests, repeats=3),
    ]
