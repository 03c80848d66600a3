"""The picture of where the ALOHA arms stand at each task's table (docs/aloha_placement.png).

For each of the six tasks: its scene at the reference placement with the two ViperX arms on their bases
(lib/sim/robots/aloha/placement.py), posed by the IK at the scripted demonstration's first grasp, drawn
by MuJoCo from behind and above the demonstrator's side; the synthetic takes' head camera is the red
sphere (0, -0.40, 0.90) with a line to the point it looks at (0, 0.25, 0).

    .venv/bin/python scripts/aloha_placement_picture.py [--out docs/aloha_placement.png] [--hand aloha]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _marker(scene, kind, size, pos, rgba, mat=None) -> None:
    import mujoco

    if scene.ngeom >= scene.maxgeom:
        return
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, kind, np.asarray(size, float), np.asarray(pos, float),
                        (np.eye(3) if mat is None else mat).ravel(), np.asarray(rgba, np.float32))
    scene.ngeom += 1


def render_task(task: str, hand: str, width: int = 560, height: int = 420) -> np.ndarray:
    import mujoco

    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.sim.scene import get_scene
    from demoforge.lib.synth.render import CAMERA_POS, CAMERA_TARGET
    from demoforge.lib.task_library import get_task

    robot = get_robot("aloha", hand)
    demo = get_task(task).scripted_demo(0)
    acts = demo.gripper_actions()
    grasp = int(np.argmax((acts[:, :, 7] < 0.5).any(axis=1)))
    q = robot.ik(task).solve(acts[:grasp + 1]).q[-1]
    sc = get_scene(task, robot)
    m = sc.model
    d = mujoco.MjData(m)
    obj = demo.placement.object_poses
    sc.reset(obj, acts[grasp, :, :7], np.full(2, robot.gripper.opening), SimpleNamespace(q0=q))  # the arms at q
    d.qpos[:] = sc.data.qpos
    mujoco.mj_forward(m, d)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = (0.0, 0.1, 0.3)
    cam.distance, cam.azimuth, cam.elevation = 2.3, 235.0, -24.0
    with mujoco.Renderer(m, height=height, width=width) as r:
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        r.update_scene(d, camera=cam)
        _marker(r.scene, mujoco.mjtGeom.mjGEOM_SPHERE, [0.03, 0, 0], CAMERA_POS, [0.9, 0.1, 0.1, 1])
        a, b = np.asarray(CAMERA_POS, float), np.asarray(CAMERA_TARGET, float)
        g = r.scene.geoms[r.scene.ngeom] if r.scene.ngeom < r.scene.maxgeom else None
        if g is not None:
            mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(),
                                np.array([0.9, 0.1, 0.1, 1], np.float32))
            mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, 3.0, a, b)
            r.scene.ngeom += 1
        return r.render()


def main() -> None:
    import cv2

    from demoforge.lib.evaluation.visualize import montage
    from demoforge.lib.sim.robots.aloha.placement import bases_for
    from demoforge.lib.task_library import TASK_NAMES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("docs/aloha_placement.png"))
    ap.add_argument("--hand", default="aloha", choices=("aloha", "2f140"))
    a = ap.parse_args()
    tiles, captions = [], []
    for task in TASK_NAMES:
        left, _ = bases_for(task)
        tiles.append(render_task(task, a.hand))
        captions.append(f"{task}: bases (+-{-left.x:.2f}, {left.y:+.2f}, {left.z:.2f}) m")
    grid = montage(tiles, columns=3, captions=captions)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(a.out)


if __name__ == "__main__":
    main()
