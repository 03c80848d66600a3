"""Benchmark cases of the ingest stage after detection (registered in demoforge/bench/registry.py)."""

from __future__ import annotations

import numpy as np

from demoforge.bench.timing import BenchCase
from demoforge.lib.geometry import transform_points
from demoforge.lib.ingest.alignment import align_to_depth
from demoforge.lib.ingest.gripper_mapping import gripper_state, hand_to_gripper
from demoforge.lib.perception.hand_model import hand_from_pinch
from demoforge.lib.perception.simulated_detector import simulate_detections
from demoforge.lib.task_library import get_task


def _take_arrays(T: int):
    """A realistic take without rendering: the pouring demo's hands through the simulated detector,
    over depth maps of a plane at the hands' depth (the read cost is what matters here)."""
    # lazy: mujoco
    from demoforge.lib.synth.render import camera_K, camera_T_world_camera, world_to_camera
    from demoforge.lib.synth.take import hand_styles_for

    demo = get_task("pouring").scripted_demo(0)
    idx = np.arange(T) % demo.n_frames
    styles = hand_styles_for(0)
    world = np.stack([hand_from_pinch(demo.pinch_poses[idx, h], demo.aperture[idx, h],
                                      ("left", "right")[h], styles[h])[0] for h in range(2)], 1)
    K, Twc = camera_K(), camera_T_world_camera()
    cam = world_to_camera(world, Twc)
    det = simulate_detections(cam, K, seed=0)
    depth = np.full((T, 480, 640), np.float32(np.nanmedian(cam[..., 2])))
    return det, depth, K, Twc


def cases(quick: bool) -> list[BenchCase]:
    frames = 120 if quick else 600

    def setup(T: int):
        det, depth, K, Twc = _take_arrays(T)

        def stages(j_cam, j_px, d):
            res = align_to_depth(j_cam, d, K, j_px)
            n = res.joints_cam.shape[0]
            world = transform_points(Twc, res.joints_cam.reshape(n, 42, 3)).reshape(n, 2, 21, 3)
            pose7, dist = hand_to_gripper(world)
            return pose7, gripper_state(dist, "threshold")

        def fast():  # the whole take at once
            return stages(det.joints_cam, det.joints_px, depth)[0]

        def baseline():  # the same stages called frame by frame
            return np.concatenate([stages(det.joints_cam[t:t + 1], det.joints_px[t:t + 1], depth[t:t + 1])[0]
                                   for t in range(T)])

        return fast, baseline

    return [BenchCase("ingest", "depth alignment + gripper mapping after detection (640x480)", frames,
                      "frames", "the same stages called once per frame in a Python loop", setup,
                      repeats=2, baseline_size=min(frames, 120))]
