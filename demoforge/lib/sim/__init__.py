"""Robot execution of gripper action sequences in MuJoCo physics, by a robot of lib/sim/robots: two
floating parallel-jaw grippers, or ALOHA's two ViperX 300 arms (inverse kinematics, retiming, transits).

    from demoforge.lib.sim import execute, execute_many, render_episode, SimOptions, GripperSpec
    r = execute("pouring", object_poses_or_keypoints, actions)   # actions (n, 2, 8), 30 fps
    r.success, r.failure, r.detail

robots/: the robot interface and registry (grippers, aloha); gripper.py: the parallel gripper (MJCF,
parameters, g -> finger command mapping); scene.py: compiled scene cache; loop.py: the one frame loop
(control steps, records, settle) that executor.py (execute / execute_many), stepper.py (a frame at a time,
for demoforge.envs) and replay.py (a scripted human demonstration: robots/hands.py's welded mocap hands)
run; options.py: sim_options (a robot's options by name); failures.py: failure
classification; render.py: MP4; stability.py: verdicts under micrometre shifts; variations.py,
variation_scene.py: the Table 4 analogue's varied scenes.
"""

from .executor import (SimOptions, SimResult, as_object_poses, execute, execute_many, planned_execution,
                       scene_fingerprint, validate_actions)
from .failures import FAILURES
from .gripper import GripperSpec
from .options import sim_options
from .render import render_episode as _r
from .scene import PhysicsOptions, get_scene


def render_episode(*args, **kwargs):
    return _r(*args, **kwargs)


__all__ = ["execute", "execute_many", "render_episode", "SimOptions", "SimResult", "GripperSpec", "PhysicsOptions",
           "FAILURES", "as_object_poses", "planned_execution", "validate_actions", "get_scene", "scene_fingerprint",
           "sim_options"]
