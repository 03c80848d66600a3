"""The ALOHA arms (lib/sim/robots/aloha): inverse kinematics with mink, execution through joint position
actuators, the arm verdicts (unreachable, joint_limit, link_collision, wider_than_stroke)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import demoforge.lib  # noqa: F401
from demoforge.lib.sim import SimOptions, execute
from demoforge.lib.sim.robots import RobotError, available_robots, get_robot, gripper_choices
from demoforge.lib.sim.robots.aloha import AlohaRobot
from demoforge.lib.sim.robots.aloha.model import REST, BasePose
from demoforge.lib.task_library import get_task

# fixed bases, so these tests do not move when the per-task placement (aloha/placement.py) is retuned
BASE = BasePose(-0.35, -0.05, 0.0, math.pi / 2)
ARMS = AlohaRobot(hand="aloha", bases=(BASE, BASE.mirrored()))
ARMS_2F140 = AlohaRobot(hand="2f140", bases=(BASE, BASE.mirrored()))


def _fk(robot, q: np.ndarray) -> np.ndarray:
    """(n, 2, 8) pinch poses [x y z qx qy qz qw g=1] of joint configurations q (n, 12), from the IK's model."""
    from scipy.spatial.transform import Rotation

    ik = robot.ik("pouring")
    out = np.ones((len(q), 2, 8))
    for t, qt in enumerate(q):
        ik.cfg.update(qt)
        d = ik.cfg.data
        out[t, :, :3] = d.site_xpos[ik.sites]
        out[t, :, 3:7] = Rotation.from_matrix(d.site_xmat[ik.sites].reshape(2, 3, 3)).as_quat()
    return out


def _angle_deg(a_xyzw, b_xyzw):
    from scipy.spatial.transform import Rotation

    return np.degrees((Rotation.from_quat(a_xyzw).inv() * Rotation.from_quat(b_xyzw)).magnitude())


def test_registry_and_choices():
    assert available_robots()[:2] == ("grippers", "aloha")
    assert gripper_choices("aloha") == ("aloha", "2f140") and gripper_choices("grippers") == ("2f140",)
    assert get_robot("aloha", "2f140").gripper.stroke == pytest.approx(0.14)
    assert get_robot("aloha").gripper.opening == pytest.approx(0.069)  # ALOHA's fingers: 69 mm between the pads
    with pytest.raises(RobotError, match="aloha or 2f140"):
        get_robot("aloha", "robotiq")
    with pytest.raises(RobotError, match="grippers, aloha"):
        get_robot("ur5")


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6), st.sampled_from([ARMS, ARMS_2F140]))
def test_fk_of_the_ik_answer_is_the_pose(u, robot):
    """A reachable pose (the FK of joint angles inside the ranges, 0.25 rad from their ends) comes back
    from the IK within 1 mm and 0.5 degrees, for either hand."""
    ik = robot.ik("pouring")
    lo, hi = ik.lower[:6] + 0.25, ik.upper[:6] - 0.25
    q = np.concatenate([lo + np.asarray(u) * (hi - lo), REST])
    target = _fk(robot, q[None])
    sol = ik.solve(target)
    back = _fk(robot, sol.q)
    assert np.linalg.norm(back[0, 0, :3] - target[0, 0, :3]) < 1e-3
    assert _angle_deg(back[0, 0, 3:7], target[0, 0, 3:7]) < 0.5
    assert sol.position_error[0, 0] < 1e-3 and not sol.failed_steps().any()


def test_a_pose_a_metre_outside_the_workspace_is_unreachable():
    d = get_task("open_container").scripted_demo(0)
    act = d.gripper_actions().copy()
    act[:, 1, 0] += 1.0  # the right hand a metre to the right, beyond the table
    r = execute("open_container", d.placement.object_poses, act, options=SimOptions(robot=ARMS))
    assert not r.success and r.failure == "unreachable", r.detail
    assert "arm 1" in r.detail and "beyond the arm's reach" in r.detail
    assert r.robot["reachable"] is False and r.robot["ik_position_error_m"] > 0.1
    assert r.physics_steps < 400  # decided at the first step: nothing after it is simulated


def test_an_arm_driven_into_the_table_is_link_collision():
    """The left arm's shoulder swings forward, its elbow opens and its wrist bends back until the wrist
    link is in the table while the hand is still above it (a joint-space path; its poses through FK are
    what the episode commands): the IK follows it, the physics stops the wrist link on the table top."""
    rest = np.array(REST * 2)
    down = rest.copy()
    down[1], down[2], down[4] = 0.8, 0.6, -1.8
    w = np.clip(np.arange(90) / 60.0, 0.0, 1.0)[:, None]
    q = (1 - w) * rest + w * down
    act = _fk(ARMS, q)
    d = get_task("open_container").scripted_demo(0)
    r = execute("open_container", d.placement.object_poses, act, options=SimOptions(robot=ARMS))
    assert not r.success and r.failure == "link_collision", r.detail
    assert "table_top" in r.detail and "left_6_wrist" in r.detail and r.robot["reachable"] is True


@pytest.fixture(scope="module")
def pouring_with_arms():
    """The seed-1 pouring demonstration executed by the arms with the 2F-140 at the task's own bases."""
    d = get_task("pouring").scripted_demo(1)
    act = d.gripper_actions()
    return act, execute("pouring", d.placement.object_poses, act, options=SimOptions(robot=get_robot("aloha", "2f140")))


def test_joint_targets_are_tracked_in_physics(pouring_with_arms):
    """A reachable episode (the seed-1 pouring demonstration with the 2F-140 on the arms): every step within
    the IK's tolerance, and the position actuators hold the pinch points within a few millimetres of the
    commanded poses (median under 2 mm): the arms move the grippers, no weld does."""
    act, r = pouring_with_arms
    assert r.robot["reachable"] is True and r.robot["ik_position_error_m"] < 0.01, r.robot
    err = np.linalg.norm(r.gripper_poses[:len(act), :, :3] - act[:len(r.gripper_poses), :, :3], axis=-1)
    assert np.median(err) < 0.002 and err.max() < 0.02, (np.median(err), err.max())
    assert r.success, r.detail


def test_the_aloha_hand_cannot_open_around_the_bottle(pouring_with_arms):
    """ALOHA's fingers open 69 mm; the pouring bottle is 70 mm and the cup 90 mm wide where the hands grasp
    them: a hard failure at the moment each hand closes (found before physics, like the IK's), whatever
    else happens. The 2F-140 on the same arms opens 110 mm: no such failure."""
    d = get_task("pouring").scripted_demo(1)
    act = d.gripper_actions()
    r = execute("pouring", d.placement.object_poses, act, options=SimOptions(robot=get_robot("aloha")))
    assert r.failure == "wider_than_stroke" and r.robot["reachable"] is True, r.detail
    stroke = sorted((e for e in r.events if e[1] == "wider_than_stroke"), key=lambda e: e[2])
    assert len(stroke) == 2 and not r.success, r.events
    for (t, _, detail), arm, name, width in zip(stroke, (0, 1), ("bottle", "cup"), (70, 90)):
        assert f"arm {arm} closes on the {name}" in detail and f"{width} mm wide" in detail and "opens 69 mm" in detail
        close = int(np.argmax(act[:, arm, 7] < 0.5))  # the hand's g switches to closed here ...
        assert close / 30.0 - 0.35 < t < close / 30.0  # ... and the close command goes out 0.3 s before
    assert "wider_than_stroke" not in [e[1] for e in pouring_with_arms[1].events]


# The scripted demonstrations (seed 1, plain) executed by the arms with the 2F-140 at each task's base
# placement, as docs/robot-checks.md ("Why the arms fail more often than the grippers") reports them:
# pouring succeeds; the other tasks' arm cannot follow the demonstrator's hands at rest or their fast
# reach from rest to the objects (the servos' 3.14 rad/s).
SCRIPTED = {
    "pouring": (None, ""),
    "trash_in_bin": ("joint_limit", "a joint at its speed limit"),
    "paper_in_case": ("joint_limit", "a joint at its speed limit"),
    "mix_bowl": ("joint_limit", "a joint at its speed limit"),
    "open_container": ("joint_limit", "a joint at its speed limit"),
    "empty_vase": ("joint_limit", "from its pose at step 0 (a joint at the end of its range"),
}


def test_the_scripted_demonstrations_with_the_arms_fail_where_the_docs_say(pouring_with_arms):
    tasks = [t for t in SCRIPTED if t != "pouring"]
    eps = {t: get_task(t).scripted_demo(1) for t in tasks}
    got = {t: execute(t, eps[t].placement.object_poses, eps[t].gripper_actions(),
                      options=SimOptions(robot=get_robot("aloha", "2f140"))) for t in tasks}
    got["pouring"] = pouring_with_arms[1]
    for t, (failure, why) in SCRIPTED.items():
        r = got[t]
        assert r.failure == failure and why in r.detail, (t, r.failure, r.detail)
        assert r.robot["reachable"] is (failure is None), (t, r.robot)


def test_the_arms_are_rendered_executing_an_episode(tmp_path):
    """render_episode with the arms: the MP4 shows the arms (their links cover pixels the grippers' scene
    leaves empty) and the result is the simulation's."""
    import cv2

    from demoforge.lib.sim.render import render_episode

    d = get_task("pouring").scripted_demo(1)
    act = d.gripper_actions()[:20]
    frames = {}
    for name, robot in (("arms", get_robot("aloha", "2f140")), ("grippers", get_robot("grippers"))):
        out = tmp_path / f"{name}.mp4"
        r = render_episode("pouring", d.placement.object_poses, act, out, width=96, height=72,
                           options=SimOptions(robot=robot, stop_on_hard_failure=False))
        cap = cv2.VideoCapture(str(out))
        ok, frames[name] = cap.read()
        cap.release()
        assert ok and frames[name].shape == (72, 96, 3) and r.n_frames == 20
    differ = np.abs(frames["arms"].astype(int) - frames["grippers"].astype(int)).max(axis=2) > 40
    assert differ.mean() > 0.01, differ.mean()
