"""Synthetic RGB-D takes with exact ground truth, in the layout of a real recording.

:func:`generate_take` scripts a demo with the task library, poses two human hands on its pinch
trajectory (:func:`demoforge.lib.perception.hand_model.hand_from_pinch`), renders the scene from the head camera
(:mod:`demoforge.lib.synth.render`) and writes::

    <out_dir>/
      rgb/000000.png ...      RGB frames (8-bit PNG)
      depth/000000.npy ...    float32 depth along the camera z, m; 0.0 = invalid (sensor noise, holes)
      rgb.mp4                 the RGB frames as a video (mp4v), at fps
      camera.json             {"K": 3x3, "width": 640, "height": 480, "T_world_camera": 4x4 (camera to
                               world, OpenCV camera axes), "fps": 30.0, "depth_unit": "m"}
      annotations.json        what a person annotates on a real take (format below)
      take.json               task, seed, mirror, n_frames, fps, generator + version, provenance, ...
      ground_truth/           parquet tables of schemas/synthetic.py: gt_hand_joints.parquet,
                              gt_gripper.parquet, gt_objects.parquet, gt_object_keypoints.parquet,
                              gt_segments.parquet

``annotations.json`` format (the same file a person writes for a real take)::

    {
      "object_keypoints_2d": {
        "frame": 0,                        # frame the points are clicked on (the first)
        "names": ["...", ...],             # the task's 11 keypoint names, in order
        "uv": [[u, v], ...]                # pixel coordinates (OpenCV: top-left pixel centre = 0, 0)
      },
      "gripper_closed_ranges": {           # frames where each hand's gripper is closed
        "left":  [[start, end], ...],      # [start, end): end exclusive, 0-based frame indices
        "right": [[start, end], ...]
      },
      "range_convention": "[start, end) 0-based frame indices, end exclusive"
    }

The synthetic annotation is exact: the uv are the projections of the world keypoints of frame 0
with K (they may lie outside the image or behind an occluder), and the ranges are the runs of
``demo.closed``.
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, is_dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

import demoforge.schemas.synthetic  # noqa: F401  (registers the gt_* tables)
from demoforge.lib.geometry import transform_to_pose8
from demoforge.lib.perception.hand_model import HandStyle, hand_from_pinch, sample_style
from demoforge.lib.synth.render import (
    DEFAULT_HAND_STYLE, HEIGHT, WIDTH, Frame, SceneRenderer, add_depth_noise, board_xml, camera_K,
    camera_T_world_camera, extra_worldbody_xml, hands_assets_xml, joint_visibility, project, world_to_camera,
)
from demoforge.lib.task_library import get_task
from demoforge.schemas.core import write_table_file

GENERATOR = "demoforge.synth"
GENERATOR_VERSION = "1.2.0"  # 1.2: skinned hands with forearm and sleeve (hand_style)
PROVENANCE = "ground truth (synthetic)"
SIDES = ("left", "right")
PNG_COMPRESSION = 1


@dataclass
class TakeSummary:
    take_id: str
    out_dir: str
    task: str
    seed: int
    mirror: bool
    n_frames: int
    fps: float
    seconds: float                    # wall time of the whole generation
    frames_per_second: float          # n_frames / seconds
    visible_fraction: list[float]     # per hand: mean fraction of joints visible
    files: dict[str, str] = field(default_factory=dict)


def take_id(task_name: str, seed: int, mirror: bool) -> str:
    return f"synth_{task_name}_s{int(seed):04d}" + ("_m" if mirror else "")


def closed_ranges(closed: np.ndarray) -> list[list[int]]:
    """Runs of True in a (T,) bool array as [[start, end), ...] (end exclusive)."""
    c = np.concatenate([[False], np.asarray(closed, bool), [False]]).astype(np.int8)
    d = np.diff(c)
    starts, ends = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]
    return [[int(s), int(e)] for s, e in zip(starts, ends)]


def _jsonable(x: Any) -> Any:
    if is_dataclass(x) and not isinstance(x, type):
        return _jsonable(asdict(x))
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if x is None or isinstance(x, (str, int, float, bool)):
        return x
    return repr(x)


def _write_json(path: Path, obj: Any) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(_jsonable(obj), indent=2))
    os.replace(tmp, path)


def _object_name(obj: Any, object_names: Sequence[str]) -> str | None:
    if obj is None:
        return None
    if isinstance(obj, (int, np.integer)):
        return object_names[int(obj)] if 0 <= int(obj) < len(object_names) else None
    return str(obj)


def hand_styles_for(seed: int) -> tuple[HandStyle, HandStyle]:
    """One demonstrator per take: the same skin and size for both hands, drawn from the seed."""
    st = sample_style(np.random.default_rng([int(seed), 7]))
    return st, st


def _render_and_write(out: Path, renderer: SceneRenderer, joints: np.ndarray, obj_poses: np.ndarray,
                      drawn: tuple[bool, ...], K: np.ndarray, T_wc: np.ndarray, fps: float,
                      noise_rng: np.random.Generator | None, video: bool, write_queue: int,
                      progress: Callable[[int, int], None] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render every frame and write its PNG, depth (noised with ``noise_rng`` when given) and video frame
    on a writer thread; -> per frame and joint: visible (T, 2, 21), pixels (T, 2, 21, 2), camera (T, 2, 21, 3)."""
    import cv2

    n = joints.shape[0]
    writer = None
    if video:
        writer = cv2.VideoWriter(str(out / "rgb.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), fps, (WIDTH, HEIGHT))
    visible = np.zeros((n, 2, 21), bool)
    px = np.zeros((n, 2, 21, 2))
    cam = np.zeros((n, 2, 21, 3))

    write_failed = threading.Event()

    def write_frame(t: int, fr: Frame) -> None:
        # one writer thread, frames in order: the noise generator and the video see the same sequence
        # as a serial loop, so the files are identical; PNG/MP4 encoding and the noise (NumPy, OpenCV:
        # both release the GIL) overlap the next frame's rendering, about a third of a frame's time
        if write_failed.is_set():
            return  # a frame before this one failed: write nothing after it (the take is abandoned)
        try:
            depth = add_depth_noise(fr.depth, noise_rng) if noise_rng is not None else fr.depth
            bgr = np.ascontiguousarray(fr.rgb[..., ::-1])
            cv2.imwrite(str(out / "rgb" / f"{t:06d}.png"), bgr, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
            np.save(out / "depth" / f"{t:06d}.npy", depth.astype(np.float32))
            if writer is not None:
                writer.write(bgr)
        except BaseException:
            write_failed.set()
            raise

    pending: deque = deque()
    written = 0

    def finish_oldest() -> None:
        nonlocal written
        pending.popleft().result()  # re-raises a write error here
        written += 1
        if progress is not None:
            progress(written, n)

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="take-writer")
    try:
        for t in range(n):
            renderer.set_state(obj_poses[t], joints[t], hand_present=drawn)
            fr = renderer.render()
            vis, p, c = joint_visibility(joints[t], fr.depth, K, T_wc, renderer.joint_radii)
            vis &= np.asarray(drawn)[:, None]
            visible[t], px[t], cam[t] = vis, p, c
            pending.append(pool.submit(write_frame, t, fr))
            while pending and (len(pending) > write_queue or pending[0].done()):
                finish_oldest()
        while pending:
            finish_oldest()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)  # an error: drop queued frames, let the running one end
        renderer.close()
        if writer is not None:
            writer.release()
    return visible, px, cam


def _write_ground_truth(gt: Path, tid: str, task_name: str, demo: Any, object_names: Sequence[str],
                        joints: np.ndarray, cam: np.ndarray, px: np.ndarray, visible: np.ndarray,
                        drawn: tuple[bool, ...], kp_world: np.ndarray, K: np.ndarray, T_wc: np.ndarray,
                        fps: float) -> dict[str, str]:
    """The take's ground-truth tables (schemas/synthetic.py) under ``gt``; -> {table: file}."""
    pinch = np.asarray(demo.pinch_poses, float)
    aperture = np.asarray(demo.aperture, float)
    closed = np.asarray(demo.closed, bool)
    held = np.asarray(demo.held_object)
    obj_poses = np.asarray(demo.object_poses, float)
    n = pinch.shape[0]
    frames = np.arange(n)
    time_s = frames / fps
    inside = np.isfinite(px).all(-1) & (cam[..., 2] > 0) & (px[..., 0] >= -0.5) & (px[..., 0] < WIDTH - 0.5) \
        & (px[..., 1] >= -0.5) & (px[..., 1] < HEIGHT - 0.5) & np.asarray(drawn)[None, :, None]
    rows = n * 2
    rep = lambda v: np.repeat(v, 2)  # noqa: E731  (frame-major, hand-minor rows)
    hands = np.tile(np.array(SIDES), n)
    common = {"take": [tid] * rows, "task": [task_name] * rows, "frame": rep(frames).astype(np.int32),
              "time_s": rep(time_s), "hand": hands}
    files = {}
    files["gt_hand_joints"] = write_table_file("gt_hand_joints", {
        **common,
        "joints_world": joints.reshape(rows, 21, 3),
        "joints_camera": cam.reshape(rows, 21, 3),
        "joints_px": np.nan_to_num(px.reshape(rows, 21, 2), nan=-1e6, posinf=1e6, neginf=-1e6),
        "visible": visible.reshape(rows, 21),
        "present": inside.any(-1).reshape(rows),
    }, gt / "gt_hand_joints.parquet").path

    g = np.where(closed, 0.0, 1.0)
    pose8 = transform_to_pose8(pinch, g)                                 # (T, 2, 8)
    held_names = [_object_name(h if h >= 0 else None, object_names) for h in held.reshape(-1)]
    files["gt_gripper"] = write_table_file("gt_gripper", {
        **common,
        "pose": pose8.reshape(rows, 8),
        "aperture": aperture.reshape(rows),
        "closed": closed.reshape(rows),
        "held_object": held_names,
    }, gt / "gt_gripper.parquet").path

    n_obj = obj_poses.shape[1]
    files["gt_objects"] = write_table_file("gt_objects", {
        "take": [tid] * (n * n_obj), "task": [task_name] * (n * n_obj),
        "frame": np.repeat(frames, n_obj).astype(np.int32), "time_s": np.repeat(time_s, n_obj),
        "object": np.tile(np.array(list(object_names)), n), "object_index": np.tile(np.arange(n_obj), n).astype(np.int32),
        "pose": obj_poses.reshape(n * n_obj, 4, 4),
    }, gt / "gt_objects.parquet").path

    kp_px, _ = project(kp_world, K, T_wc)
    files["gt_object_keypoints"] = write_table_file("gt_object_keypoints", {
        "take": [tid] * n, "task": [task_name] * n, "frame": frames.astype(np.int32), "time_s": time_s,
        "keypoints_world": kp_world, "keypoints_camera": world_to_camera(kp_world, T_wc),
        "keypoints_px": kp_px,
    }, gt / "gt_object_keypoints.parquet").path

    segs = list(demo.segments)
    files["gt_segments"] = write_table_file("gt_segments", {
        "take": [tid] * len(segs), "task": [task_name] * len(segs),
        "hand": [SIDES[int(s.arm)] for s in segs], "kind": [str(s.kind) for s in segs],
        "start": np.array([int(s.start) for s in segs], np.int32),
        "end": np.array([int(s.end) for s in segs], np.int32),
        "object": [_object_name(s.object, object_names) for s in segs],
    }, gt / "gt_segments.parquet").path
    return files


def write_take(
    out_dir: str | os.PathLike,
    *,
    task_name: str,
    seed: int,
    mirror: bool,
    scene_xml: str,
    object_names: Sequence[str],
    keypoint_names: Sequence[str],
    demo: Any,
    styles: Sequence[HandStyle] | None = None,
    depth_noise: bool = True,
    video: bool = True,
    blur_sigma: float = 0.6,
    progress: Callable[[int, int], None] | None = None,
    extra_meta: dict | None = None,
    write_queue: int = 4,
    hand_style: str = DEFAULT_HAND_STYLE,
    hands: Sequence[str] = SIDES,
) -> TakeSummary:
    """Render ``demo`` in ``scene_xml`` and write the take layout (see the module docstring).

    ``demo`` follows the task library's contract (fps, pinch_poses (T, 2, 4, 4), aperture (T, 2),
    closed (T, 2), held_object (T, 2), object_poses (T, n, 4, 4), segments, keypoints()).
    ``scene_xml`` must contain the free-joint bodies ``object_names``; the head camera and the hands
    are added unless present. ``progress(done, total)`` is called after every frame written.
    ``write_queue``: rendered frames that may wait for the writer thread while the next frame renders
    (0: each frame is written before the next renders, the serial baseline of ``make bench``).
    ``hand_style``: "skin" (palm, forearm, sleeve) or "capsule" (demoforge.lib.synth.render.HAND_STYLES).
    ``hands``: the hands in the picture; a hand left out is not drawn (its held object moves on its
    own) and its ground truth is ``present = false`` in every frame (a one-hand recording).
    """
    t_start = time.perf_counter()
    out = Path(out_dir)
    for sub in ("rgb", "depth", "ground_truth"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    styles = tuple(styles) if styles is not None else hand_styles_for(seed)
    drawn = tuple(side in hands for side in SIDES)
    if not any(drawn) or set(hands) - set(SIDES):
        raise ValueError(f"hands must name one or both of {', '.join(SIDES)}, got {list(hands)}")
    tid = take_id(task_name, seed, mirror)
    fps = float(demo.fps)
    pinch = np.asarray(demo.pinch_poses, float)
    aperture = np.asarray(demo.aperture, float)
    closed = np.asarray(demo.closed, bool)
    obj_poses = np.asarray(demo.object_poses, float)
    kp_world = np.asarray(demo.keypoints(), float)
    n = pinch.shape[0]

    K = camera_K()
    T_wc = camera_T_world_camera()
    # Hands for every frame at once (vectorised): (T, 2, 21, 3).
    joints = np.stack(
        [hand_from_pinch(pinch[:, h], aperture[:, h], SIDES[h], styles[h])[0] for h in range(2)], axis=1
    )

    _write_json(out / "camera.json", {
        "K": K, "width": WIDTH, "height": HEIGHT, "T_world_camera": T_wc, "fps": fps, "depth_unit": "m",
    })

    renderer = SceneRenderer(scene_xml, object_names, styles, T_world_camera=T_wc, blur_sigma=blur_sigma,
                             hand_style=hand_style)
    visible, px, cam = _render_and_write(out, renderer, joints, obj_poses, drawn, K, T_wc, fps,
                                         np.random.default_rng([int(seed), 11]) if depth_noise else None,
                                         video, write_queue, progress)

    files = _write_ground_truth(out / "ground_truth", tid, task_name, demo, object_names, joints, cam, px, visible,
                                drawn, kp_world, K, T_wc, fps)
    kp_px, _ = project(kp_world, K, T_wc)
    _write_json(out / "annotations.json", {
        "object_keypoints_2d": {"frame": 0, "names": list(keypoint_names), "uv": kp_px[0]},
        "gripper_closed_ranges": {SIDES[h]: closed_ranges(closed[:, h]) for h in range(2)},
        "range_convention": "[start, end) 0-based frame indices, end exclusive",
    })
    seconds = time.perf_counter() - t_start
    _write_json(out / "take.json", {
        "take": tid, "task": task_name, "seed": int(seed), "mirror": bool(mirror), "n_frames": n,
        "fps": fps, "generator": GENERATOR, "generator_version": GENERATOR_VERSION,
        "detector_provenance": PROVENANCE, "depth_noise": bool(depth_noise),
        "object_names": list(object_names), "keypoint_names": list(keypoint_names),
        "hand_styles": {SIDES[h]: styles[h] for h in range(2)}, "hand_style": hand_style,
        "hands": [side for side, on in zip(SIDES, drawn) if on],
        "camera": {"pos": T_wc[:3, 3], "T_world_camera": T_wc},
        "generation_seconds": seconds, **(extra_meta or {}),
    })
    files.update({k: str(out / k) for k in ("camera.json", "annotations.json", "take.json")})
    if video:
        files["rgb.mp4"] = str(out / "rgb.mp4")
    return TakeSummary(
        take_id=tid, out_dir=str(out), task=task_name, seed=int(seed), mirror=bool(mirror), n_frames=n,
        fps=fps, seconds=seconds, frames_per_second=n / max(seconds, 1e-9),
        visible_fraction=[float(visible[:, h].mean()) for h in range(2)], files=files,
    )


def generate_take(task_name: str, seed: int, mirror: bool, out_dir: str | os.PathLike,
                  depth_noise: bool = True, video: bool = True,
                  progress: Callable[[int, int], None] | None = None,
                  max_frames: int | None = None, write_queue: int = 4,
                  hand_style: str = DEFAULT_HAND_STYLE, hands: Sequence[str] = SIDES, board: Any = None,
                  board_origin: Sequence[float] = (0.0, 0.0)) -> TakeSummary:
    """Script ``task_name``'s demo for ``seed`` (mirrored: hands' roles swapped), render and write it.

    ``max_frames`` keeps only the first frames (tests, previews); ``hands`` the hands drawn (one for a
    one-hand take). ``board``: a ChArUco board (demoforge.lib.calibration.board.BoardSpec) printed on
    the table, centred at ``board_origin`` (recorded in take.json as ``calibration_board``), to measure
    ``demoforge calibrate`` against the known pose. See :func:`write_take`.
    """
    if board is not None:
        import tempfile

        import cv2

        with tempfile.TemporaryDirectory(prefix="demoforge_board_") as d:
            png = os.path.join(d, "board.png")
            cv2.imwrite(png, board.image(px_per_m=4000))  # 4 px per mm: sharper than the camera sees it
            extra = board_xml(board, png, board_origin)
            meta = {"calibration_board": {**board.to_json(), "origin_xy": [float(x) for x in board_origin]}}
            return _generate(task_name, seed, mirror, out_dir, depth_noise, video, progress, max_frames,
                             write_queue, hand_style, hands, extra, meta)
    return _generate(task_name, seed, mirror, out_dir, depth_noise, video, progress, max_frames, write_queue,
                     hand_style, hands, ("", ""), {})


def _generate(task_name, seed, mirror, out_dir, depth_noise, video, progress, max_frames, write_queue, hand_style,
              hands: Sequence[str], extra_xml: tuple[str, str], extra_meta: dict) -> TakeSummary:
    task = get_task(task_name)
    demo = task.scripted_demo(seed, mirror=mirror)
    if max_frames is not None:
        demo = _TruncatedDemo(demo, int(max_frames))
    styles = hand_styles_for(seed)
    scene = task.scene_xml(demo.placement, extra_worldbody=extra_worldbody_xml(styles, hand_style=hand_style)
                           + extra_xml[1], extra_assets=hands_assets_xml(styles, hand_style) + extra_xml[0])
    return write_take(
        out_dir, task_name=task_name, seed=seed, mirror=mirror, scene_xml=scene,
        object_names=list(task.object_names), keypoint_names=list(task.keypoint_names), demo=demo,
        styles=styles, depth_noise=depth_noise, video=video, progress=progress,
        extra_meta={"placement": demo.placement, **extra_meta}, write_queue=write_queue, hand_style=hand_style,
        hands=hands,
    )


class _TruncatedDemo:
    """The first ``n`` frames of a demo (segments clipped)."""

    def __init__(self, demo: Any, n: int):
        self._d, self._n = demo, min(n, len(demo.pinch_poses))
        self.fps = demo.fps
        self.placement = getattr(demo, "placement", None)
        for k in ("pinch_poses", "aperture", "closed", "held_object", "object_poses"):
            setattr(self, k, np.asarray(getattr(demo, k))[: self._n])
        segs = []
        for s in demo.segments:
            if s.start < self._n:
                try:
                    from dataclasses import replace

                    segs.append(replace(s, end=min(s.end, self._n)))
                except TypeError:
                    segs.append(s)
        self.segments = segs

    def keypoints(self) -> np.ndarray:
        return np.asarray(self._d.keypoints())[: self._n]
