"""The scripted replay (lib/sim/replay.py): the demonstrator's hands through the simulator's frame loop.

Its verdicts are pinned here as the task library's own replay gave them before it ran through the loop
(seed 0 of each task; the same object poses to the bit); tests/lib/task_library/test_task_library.py checks that every
scripted take succeeds and that every fault fails for its reason."""

import numpy as np
import pytest

import demoforge.lib  # noqa: F401  (sets MUJOCO_GL before mujoco is imported)
import mujoco

from demoforge.lib.sim.replay import HANDS, replay
from demoforge.lib.sim.scene import SimScene
from demoforge.lib.task_library import TASK_NAMES, get_task

PINNED = {  # seed 0, not mirrored: the reason strings of the task library's replay before issue 44
    "pouring": "10/10 liquid spheres in the cup, max cup tilt 0 deg",
    "trash_in_bin": "can centre in bin frame (-0.021, -0.019, 0.066); bin tilt 0 deg",
    "paper_in_case": "paper ball centre in case frame (-0.035, -0.008, 0.036)",
    "mix_bowl": "whisk head circled 725 deg inside the bowl; max bowl tilt 0 deg",
    "open_container": "lid centre in container frame (-0.220, -0.034, 0.015); off if |x|>0.156 or |y|>0.116",
    "empty_vase": "flower base in vase frame (0.401, 0.085, 0.015); out of the vase: True",
}


@pytest.mark.parametrize("name", TASK_NAMES)
def test_the_verdicts_are_the_task_librarys(name):
    r = replay(get_task(name).scripted_demo(0))
    assert (r.success, r.reason) == (True, PINNED[name])


def test_trace_and_final_poses():
    """extra['trace'] records the named bodies at the demonstration's frames: a task object where the
    object poses have it, the left hand exactly at its pinch frames; extra['final_object_poses'] the settled state."""
    task = get_task("trash_in_bin")
    demo = task.scripted_demo(1, mirror=True)
    r = replay(demo, settle_s=0.5, trace_bodies=(task.object_names[0], "pinch_0"))
    T = demo.n_frames
    assert r.extra["trace"].shape == (T, 2, 3) and r.object_poses.shape == (T, 2, 4, 4)
    np.testing.assert_array_equal(r.extra["trace"][:, 0], r.object_poses[:, 0, :3, 3])
    np.testing.assert_array_equal(r.extra["trace"][:, 1], demo.pinch_poses[:, 0, :3, 3])
    assert r.extra["final_object_poses"].shape == (2, 4, 4)
    assert replay(demo).extra["trace"].shape == (T, 0, 3)


def test_the_replay_keeps_its_mjcfs_physics():
    """The hands' scene is the task's MJCF at the demonstration's placement with the MJCF's own solver
    options and step (physics None): what the task library's replay compiled, so its numbers stay."""
    task = get_task("pouring")
    demo = task.scripted_demo(0)
    sc = SimScene(task, HANDS, None, placement=demo.placement)
    plain = mujoco.MjModel.from_xml_string(task.scene_xml(demo.placement))
    for f in ("timestep", "iterations", "ls_iterations", "tolerance", "noslip_iterations", "integrator",
              "disableflags", "enableflags"):
        assert getattr(sc.model.opt, f) == getattr(plain.opt, f), f
    np.testing.assert_array_equal(sc.model.qpos0, plain.qpos0)  # the objects where that MJCF puts them


def test_a_variant_replays_as_itself():
    """task=: a variant (the same name as its task) replays with its own objects, not the registered task's."""
    from demoforge.lib.task_library import objects as ob

    base = get_task("pouring")
    wide = base.variant({"bottle": ob.scale_dims("bottle", base.B, 1.15, 1.0)})
    demo = wide.scripted_demo(0)
    assert demo.task == base.name
    r = replay(demo, task=wide)
    assert r.success, r.reason
    assert not np.array_equal(r.object_poses, replay(demo).object_poses)  # the registered task's bottle differs


def test_the_hands_are_not_a_robot_a_run_may_name():
    from demoforge.lib.sim.robots import available_robots

    assert HANDS.name not in available_robots()
