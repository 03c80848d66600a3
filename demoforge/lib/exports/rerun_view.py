"""Offline Rerun recordings (.rrd) of an ingested take or of one episode; no viewer is started.

Open one with ``rerun out.rrd``. Entities (world = table frame, z up, m):

- ``world/camera`` (take only): the camera pose and pinhole; ``world/camera/image/rgb`` and
  ``.../depth`` per frame;
- ``world/points`` (take only): the RGB-D point cloud of the frame, back-projected to the world;
- ``world/hands/{left,right}``: the 21 aligned hand joints and their bones (``.../bones``);
- ``world/grippers/{left,right}``: the gripper frame (Transform3D) with its x/y/z axes as arrows
  (red/green/blue: closing direction, y, approach); ``.../open`` the gripper state as a scalar;
- ``world/trajectory/{left,right}``: the path so far (``.../full`` the whole path, static);
- ``world/reference/{left,right}`` (episode only): the original demonstration's path, static;
- ``world/object_keypoints``: the task's object keypoints with their names, static.

Timelines: ``frame`` (sequence) and ``time`` (seconds since the start).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from demoforge.lib.exports import ARMS, ExportError, atomic_file
from demoforge.lib.joints import FINGER_JOINTS

# Bones as line strips: wrist to each fingertip, and the palm across the MCPs.
HAND_STRIPS = tuple((0,) + f for f in FINGER_JOINTS) + ((5, 9, 13, 17),)
ARM_COLORS = {"left": (40, 120, 255), "right": (255, 120, 40)}
AXIS_COLORS = np.array([(230, 40, 40), (40, 200, 40), (40, 80, 230)], np.uint8)
AXIS_LENGTH = 0.05  # m: gripper axes drawn 5 cm long


@dataclass
class TakeFrame:
    index: int
    time_s: float
    rgb: np.ndarray | None    # (H, W, 3) uint8
    depth: np.ndarray | None  # (H, W) float32 m, 0 / NaN invalid


def backproject(depth: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray, stride: int = 4,
                rgb: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """World points (n, 3) of the valid depth pixels on a ``stride`` grid, and their colours (n, 3)."""
    d = np.asarray(depth, np.float64)[::stride, ::stride]
    v, u = np.mgrid[0:depth.shape[0]:stride, 0:depth.shape[1]:stride]
    ok = np.isfinite(d) & (d > 0)
    z = d[ok]
    x = (u[ok] - K[0, 2]) * z / K[0, 0]
    y = (v[ok] - K[1, 2]) * z / K[1, 1]
    pc = np.stack([x, y, z], axis=1)
    pw = pc @ T_world_camera[:3, :3].T + T_world_camera[:3, 3]
    col = None if rgb is None else np.asarray(rgb)[::stride, ::stride][ok]
    return pw, col


def _open(out: str | os.PathLike, application_id: str, recording_id: str):
    import rerun as rr

    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    return rec


def _log_static_scene(rec, keypoints: np.ndarray | None, keypoint_names: Iterable[str] | None) -> None:
    import rerun as rr

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if keypoints is not None and len(keypoints):
        kp = np.asarray(keypoints, np.float64)
        ok = np.isfinite(kp).all(axis=1)
        names = list(keypoint_names) if keypoint_names is not None else [str(i) for i in range(len(kp))]
        rec.log("world/object_keypoints", rr.Points3D(kp[ok], radii=0.006, colors=(255, 220, 0),
                                                       labels=[n for n, o in zip(names, ok) if o]), static=True)


def _log_paths(rec, root: str, poses: np.ndarray) -> None:
    """Whole-path line strips per arm (static)."""
    import rerun as rr

    for arm, name in enumerate(ARMS):
        p = poses[:, arm, :3]
        p = p[np.isfinite(p).all(axis=1)]
        if len(p) > 1:
            rec.log(f"{root}/{name}", rr.LineStrips3D([p], colors=ARM_COLORS[name], radii=0.002), static=True)


def _log_grippers_static(rec) -> None:
    import rerun as rr

    for name in ARMS:
        rec.log(f"world/grippers/{name}/axes", rr.Arrows3D(origins=np.zeros((3, 3)), vectors=np.eye(3) * AXIS_LENGTH,
                                                           colors=AXIS_COLORS), static=True)


def _log_step(rec, poses: np.ndarray, t: int, time_s: float, trail_from: int = 0) -> None:
    """Gripper frames, open state and the trail up to step t."""
    import rerun as rr

    rec.set_time("frame", sequence=int(t))
    rec.set_time("time", duration=float(time_s))
    for arm, name in enumerate(ARMS):
        p = poses[t, arm]
        if not np.isfinite(p).all():
            rec.log(f"world/grippers/{name}", rr.Clear(recursive=False))
            continue
        rec.log(f"world/grippers/{name}", rr.Transform3D(translation=p[:3], quaternion=rr.Quaternion(xyzw=p[3:7])))
        rec.log(f"world/grippers/{name}/open", rr.Scalars([float(p[7])]))
        trail = poses[trail_from:t + 1, arm, :3]
        trail = trail[np.isfinite(trail).all(axis=1)]
        if len(trail) > 1:
            rec.log(f"world/trajectory/{name}", rr.LineStrips3D([trail], colors=ARM_COLORS[name], radii=0.003))


def _save(rec, out: str | os.PathLike, overwrite: bool, log: callable) -> None:
    """Stream everything ``log`` writes into a temporary .rrd, then rename it onto ``out``."""
    with atomic_file(out, overwrite=overwrite) as tmp:
        rec.save(str(tmp))
        try:
            log()
        finally:
            rec.flush()
            rec.disconnect()


def write_take_recording(
    out: str | os.PathLike,
    *,
    take_id: str,
    K: np.ndarray,
    T_world_camera: np.ndarray,
    width: int,
    height: int,
    frames: Iterator[TakeFrame],
    hands_world: np.ndarray,
    hands_present: np.ndarray,
    gripper_poses: np.ndarray,
    object_keypoints: np.ndarray | None = None,
    keypoint_names: Iterable[str] | None = None,
    point_stride: int = 8,
    log_images: bool = True,
    log_depth_images: bool = False,
    overwrite: bool = False,
) -> dict:
    """A take as an .rrd: camera, RGB-D and its point cloud, hand skeletons, gripper frames, keypoints.

    hands_world: (T, 2, 21, 3) aligned joints (world); hands_present: (T, 2); gripper_poses: (T, 2, 8).
    ``frames`` yields the decoded frames (any subset, increasing); ``point_stride`` keeps every n-th
    pixel of the depth both ways for the cloud. RGB goes in as JPEG; the raw depth images only with
    ``log_depth_images``. Returns counts of what was logged.
    """
    import rerun as rr

    hands_world = np.asarray(hands_world, np.float64)
    gripper_poses = np.asarray(gripper_poses, np.float64)
    T = len(gripper_poses)
    if hands_world.shape != (T, 2, 21, 3) or np.shape(hands_present) != (T, 2) or gripper_poses.shape != (T, 2, 8):
        raise ExportError(f"take arrays disagree: hands {hands_world.shape}, present {np.shape(hands_present)}, "
                          f"grippers {gripper_poses.shape}; expected (T, 2, 21, 3), (T, 2), (T, 2, 8)")
    if point_stride < 1:
        raise ExportError(f"--point-stride must be at least 1, got {point_stride}")
    K = np.asarray(K, np.float64)
    Twc = np.asarray(T_world_camera, np.float64)
    rec = _open(out, "demoforge", f"take:{take_id}")
    counts = {"frames": 0, "points": 0, "hand_frames": 0}

    def log():
        _log_static_scene(rec, object_keypoints, keypoint_names)
        rec.log("world/camera", rr.Transform3D(translation=Twc[:3, 3], mat3x3=Twc[:3, :3]), static=True)
        rec.log("world/camera/image", rr.Pinhole(image_from_camera=K, width=width, height=height,
                                                 camera_xyz=rr.ViewCoordinates.RDF), static=True)
        _log_paths(rec, "world/trajectory_full", gripper_poses)
        _log_grippers_static(rec)
        for fr in frames:
            t = fr.index
            if not 0 <= t < T:
                raise ExportError(f"frame {t} is outside the take's {T} gripper frames")
            _log_step(rec, gripper_poses, t, fr.time_s)
            for arm, name in enumerate(ARMS):
                if hands_present[t, arm] and np.isfinite(hands_world[t, arm]).all():
                    j = hands_world[t, arm]
                    rec.log(f"world/hands/{name}", rr.Points3D(j, radii=0.004, colors=ARM_COLORS[name]))
                    rec.log(f"world/hands/{name}/bones", rr.LineStrips3D([j[list(s)] for s in HAND_STRIPS],
                                                                         colors=ARM_COLORS[name], radii=0.0015))
                    counts["hand_frames"] += 1
                else:
                    rec.log(f"world/hands/{name}", rr.Clear(recursive=True))
            if fr.depth is not None:
                pts, col = backproject(fr.depth, K, Twc, point_stride, fr.rgb)
                rec.log("world/points", rr.Points3D(pts, colors=col, radii=0.0015))
                counts["points"] += len(pts)
                if log_depth_images:  # 1.2 MB a frame uncompressed: the point cloud shows the same
                    rec.log("world/camera/image/depth", rr.DepthImage(fr.depth, meter=1.0))
            if log_images and fr.rgb is not None:
                rec.log("world/camera/image/rgb", rr.Image(fr.rgb).compress(jpeg_quality=85))
            counts["frames"] += 1

    _save(rec, out, overwrite, log)
    return counts


def write_episode_recording(
    out: str | os.PathLike,
    *,
    name: str,
    poses: np.ndarray,
    object_keypoints: np.ndarray | None = None,
    keypoint_names: Iterable[str] | None = None,
    reference: np.ndarray | None = None,
    fps: float = 30.0,
    overwrite: bool = False,
) -> dict:
    """One episode as an .rrd: gripper frames and trails over time, the object keypoints, and the
    original demonstration's path (``reference``, (T0, 2, 8)) for comparison."""
    poses = np.asarray(poses, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (2, 8) or len(poses) == 0:
        raise ExportError(f"episode poses must be (steps, 2, 8), got {poses.shape}")
    rec = _open(out, "demoforge", f"episode:{name}")

    def log():
        _log_static_scene(rec, object_keypoints, keypoint_names)
        _log_paths(rec, "world/trajectory_full", poses)
        if reference is not None:
            _log_paths(rec, "world/reference", np.asarray(reference, np.float64))
        _log_grippers_static(rec)
        for t in range(len(poses)):
            _log_step(rec, poses, t, t / fps)

    _save(rec, out, overwrite, log)
    return {"frames": len(poses)}


def read_recording(path: str | os.PathLike) -> dict[str, list]:
    """The chunks of an .rrd grouped by entity path: {entity: [pyarrow RecordBatch, ...]} (for checks)."""
    from rerun.chunk import RrdReader

    if not os.path.isfile(path):
        raise ExportError(f"{path}: no such recording")
    out: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return out
