"""The robot simulator on a varied scene (demoforge.lib.sim.variations): resized objects, distractor bodies, moved placements.

    from demoforge.lib.sim.variations import make_variation
    from demoforge.lib.sim.variation_scene import VariationScene
    vs = VariationScene(make_variation("pouring", "clutter", seed=0, trial=0))
    r = vs.execute(actions)            # SimResult, as demoforge.lib.sim.execute
    vs.last_distractor_shift           # how far each distractor was pushed, m

Composition, not a copy of SimScene: the variation registers a task library variant (demoforge.lib.task_library.
register_variant) whose objects carry the new dimensions and whose scene holds the distractors as
extra free bodies; the ordinary scene cache (get_scene) compiles it once per process like any task,
and SimScene resets the distractors with every episode (they are extra bodies of the task's scene).
Distractor geoms are solid (objects.SOLID_BITS): they rest on the table and collide with the grippers
and the task objects; the failure classifier counts touching them as neither a grasp nor a table
collision, so a gripper that pushes one over fails only through what follows (a missed grasp, a
knocked task object).
"""

from __future__ import annotations

import numpy as np

from demoforge.lib.sim.variations import SceneVariation

from .executor import SimOptions, SimResult, execute
from .scene import SimScene, get_scene


class VariationScene:
    def __init__(self, variation: SceneVariation, options: SimOptions | None = None):
        self.variation = variation
        self.options = options or SimOptions()
        self.task_key = variation.register()
        self.scene: SimScene = get_scene(self.task_key, self.options.robot, self.options.physics)
        self.task = self.scene.task
        m, mj = self.scene.model, self.scene.mj
        self.distractor_body = np.array([mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, d.name)
                                         for d in variation.distractors], int)
        if (self.distractor_body < 0).any():
            raise RuntimeError(f"{self.task_key}: distractor bodies missing from the compiled scene")
        self.distractor_start = np.array([[d.x, d.y] for d in variation.distractors], float).reshape(-1, 2)
        self.last_distractor_shift = np.zeros(len(variation.distractors))

    @property
    def object_poses(self) -> np.ndarray:
        return self.variation.object_poses

    @property
    def keypoints(self) -> np.ndarray:
        return self.task.keypoints_world(self.variation.object_poses)

    def execute(self, actions, fps: float = 30.0) -> SimResult:
        """Execute one action sequence (n, 2, 8) on the varied scene (objects at the variation's placement).
        Afterwards last_distractor_shift holds each distractor's horizontal displacement, m (read from
        the scene's final state; zeros if the actions were rejected before simulating)."""
        r = execute(self.task_key, self.variation.object_poses, actions, fps, self.options)
        self.last_distractor_shift = np.zeros(len(self.distractor_body))
        if len(self.distractor_body) and r.physics_steps > 0:
            xy = self.scene.data.xpos[self.distractor_body, :2]
            self.last_distractor_shift = np.linalg.norm(xy - self.distractor_start, axis=1)
        return r


__all__ = ["VariationScene"]
