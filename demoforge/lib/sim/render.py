"""Offscreen MP4 of a robot executing an episode (mujoco.Renderer, shadows off, cv2 'mp4v')."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .executor import SimOptions, SimResult, execute
from .scene import get_scene


def render_episode(task_name: str, object_poses, actions, out_mp4, fps: float = 30.0, width: int = 640,
                   height: int = 480, options: SimOptions | None = None,
                   camera: dict | None = None) -> SimResult:
    """Execute the episode, then replay the recorded per-frame state (grippers, fingers, objects,
    liquid) into the model and render one image per action frame.  Returns the SimResult."""
    import cv2
    import mujoco

    opt = options or SimOptions(stop_on_hard_failure=False)  # show the whole episode, past a failure
    states, res = _resimulate_states(task_name, object_poses, actions, fps, opt)
    out_mp4 = Path(out_mp4)
    out_mp4.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(out_mp4), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (width, height))
    if res.failure == "invalid_action" or res.n_frames == 0:
        frame = np.zeros((height, width, 3), np.uint8)
        cv2.putText(frame, f"invalid action: {res.detail[:60]}", (10, height // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (255, 255, 255), 1)
        writer.write(frame)
        writer.release()
        return res
    sc = get_scene(task_name, opt.robot, opt.physics)
    m = sc.model
    d = mujoco.MjData(m)  # separate data: the scene's own data belongs to the executor
    cam = mujoco.MjvCamera()
    c = camera or {"lookat": (0.0, 0.25, 0.1), "distance": 1.25, "azimuth": 90.0, "elevation": -35.0}
    cam.lookat[:] = c["lookat"]
    cam.distance, cam.azimuth, cam.elevation = c["distance"], c["azimuth"], c["elevation"]
    with mujoco.Renderer(m, height=height, width=width) as r:
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        for qpos in states:
            d.qpos[:] = qpos
            mujoco.mj_forward(m, d)
            r.update_scene(d, camera=cam)
            writer.write(cv2.cvtColor(r.render(), cv2.COLOR_RGB2BGR))
    writer.release()
    return res


def _resimulate_states(task_name, obj0, actions, fps, opt):
    """(qpos per recorded frame, SimResult): execute, keeping the state of every recorded frame."""
    states: list[np.ndarray] = []
    res = execute(task_name, obj0, actions, fps, opt, on_frame=lambda d: states.append(d.qpos.copy()))
    return states, res


def pinhole_gl_camera(glcam, K: np.ndarray, T_world_camera: np.ndarray, width: int, height: int,
                      near: float = 0.01, far: float = 50.0) -> None:
    """Set a MuJoCo scene camera (mjvGLCamera) to an OpenCV pinhole camera: K (3, 3) for an image
    of ``width`` x ``height`` px, T_world_camera (4, 4) camera-to-world (x right, y down, z forward).

    MuJoCo draws with glFrustum(center - width, center + width, bottom, top, near, far) on the
    near plane, looking along ``forward`` with ``up`` up; the principal point shifts the frustum.
    """
    K = np.asarray(K, float)
    R, t = np.asarray(T_world_camera, float)[:3, :3], np.asarray(T_world_camera, float)[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    left, right = -cx / fx * near, (width - cx) / fx * near
    top, bottom = cy / fy * near, -(height - cy) / fy * near  # image rows grow downwards, GL's y upwards
    glcam.pos[:] = t
    glcam.forward[:] = R[:, 2]
    glcam.up[:] = -R[:, 1]
    glcam.frustum_center = 0.5 * (left + right)
    glcam.frustum_width = 0.5 * (right - left)
    glcam.frustum_bottom, glcam.frustum_top = bottom, top
    glcam.frustum_near, glcam.frustum_far = near, far
    glcam.orthographic = 0


def episode_frames(task_name: str, object_keypoints, actions, K: np.ndarray, T_world_camera: np.ndarray,
                   width: int, height: int, fps: float = 30.0, options: SimOptions | None = None):
    """Yield one RGB uint8 (height, width, 3) image per executed action frame of the episode (for an arm
    robot the frames it runs: its ready-pose start and time-scaling included, as its joint-space export
    writes them): the robot executes it in MuJoCo (past any failure, as render_episode) and each
    recorded frame's state is drawn from the given pinhole camera (shadows off). An episode the
    executor refuses (invalid actions) raises ValueError with its reason."""
    import mujoco

    opt = options or SimOptions(stop_on_hard_failure=False, stop_when_settled=True)
    actions = np.asarray(actions, float)
    states, res = _resimulate_states(task_name, object_keypoints, actions, fps, opt)
    if res.failure == "invalid_action" or not states:
        raise ValueError(f"cannot render the episode: {res.detail}")
    sc = get_scene(task_name, opt.robot, opt.physics)
    m = sc.model
    d = mujoco.MjData(m)
    with mujoco.Renderer(m, height=height, width=width) as r:
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        # the executed action frames (an arm robot's own start and time-scaling included); the settle frames
        # after them are not steps
        for i in range(res.n_frames):
            d.qpos[:] = states[min(i, len(states) - 1)]
            mujoco.mj_forward(m, d)
            r.update_scene(d)
            for c in r.scene.camera:
                pinhole_gl_camera(c, K, T_world_camera, width, height)
            yield r.render()
