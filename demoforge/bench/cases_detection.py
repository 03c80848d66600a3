"""Benchmark cases of hand detection (registered in demoforge/bench/registry.py).

MediaPipe's hand landmarker on 640x480 frames of the default pouring take (skin look, rendered
here, untimed): video mode (palm detection only when a hand is lost, landmark tracking otherwise;
the default for takes) against image mode (palm detection on every frame) as the baseline, the
same frames in the same run. Frames per second = size / seconds. No case when MediaPipe or its
model is not installed.
"""

from __future__ import annotations

import numpy as np

from demoforge.bench.timing import BenchCase
from demoforge.lib.perception.detectors.mediapipe_backend import MediaPipeDetector
from demoforge.lib.perception.hand_model import hand_from_pinch
from demoforge.lib.task_library import get_task


def _frames(n: int) -> tuple[np.ndarray, np.ndarray]:
    # lazy: mujoco
    from demoforge.lib.synth.render import SceneRenderer, camera_K, extra_worldbody_xml, hands_assets_xml
    from demoforge.lib.synth.take import hand_styles_for

    task = get_task("pouring")
    demo = task.scripted_demo(0)
    styles = hand_styles_for(0)
    xml = task.scene_xml(demo.placement, extra_worldbody=extra_worldbody_xml(styles, hand_style="skin"),
                         extra_assets=hands_assets_xml(styles, "skin"))
    idx = np.arange(60, 60 + n) % demo.n_frames          # consecutive frames: what a tracker sees
    joints = np.stack([hand_from_pinch(demo.pinch_poses[idx, h], demo.aperture[idx, h],
                                       ("left", "right")[h], styles[h])[0] for h in range(2)], 1)
    out = np.empty((n, 480, 640, 3), np.uint8)
    with SceneRenderer(xml, task.object_names, styles, blur_sigma=0.6, hand_style="skin") as r:
        for k, i in enumerate(idx):
            out[k] = r.render_state(demo.object_poses[i], joints[k]).rgb
    return out, camera_K()


def cases(quick: bool) -> list[BenchCase]:
    try:
        MediaPipeDetector().close()
    except Exception:  # noqa: BLE001 - no mediapipe or no model: nothing to measure
        return []
    frames = 30 if quick else 120

    def setup(n: int):
        rgb, K = _frames(n)
        video = MediaPipeDetector(running_mode="auto")
        image = MediaPipeDetector(running_mode="image")

        def run_video():
            video.start_take()                            # a fresh tracker: the first frame detects
            try:
                return sum(len(c) for c in video.detect(rgb, K, np.arange(n)))
            finally:
                video.end_take()

        def run_image():
            return sum(len(c) for c in image.detect(rgb, K, np.arange(n)))

        return run_video, run_image

    return [BenchCase("detection", "MediaPipe hand landmarker, video mode (tracking), 640x480 take frames",
                      frames, "frames", "image mode (palm detection on every frame), same frames", setup,
                      repeats=2)]
