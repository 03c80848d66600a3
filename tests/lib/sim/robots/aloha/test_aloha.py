"""The ALOHA arms (lib/sim/robots/aloha): inverse kinematics with mink, execution through joint position
actuators, the arm verdicts (unreachable, joint_limit, link_collision, wider_than_stroke)."""

import functools

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

import demoforge.lib  # noqa: F401
from demoforge.lib.sim import SimOptions, execute, planned_execution
from demoforge.lib.sim.robots import RobotError, available_robots, get_robot, gripper_choices
from demoforge.lib.sim.robots.aloha.model import REST
from demoforge.lib.sim.robots.arm_motion import quintic
from demoforge.lib.sim.robots.retiming import at, max_speed_ratio
from demoforge.lib.task_library import get_task
from tests.support.aloha import ARMS, ARMS_2F140, fk as _fk

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


PATH_STEPS = 6
STRETCHED_ELBOW = -1.375  # rad: the ViperX's elbow with the upper arm and forearm in line (seeds.py: alpha - pi / 2)
AWAY = 0.3  # rad the drawn paths keep from the wrist's and the elbow's singular angles


def _joint_path(ik, u, v, c) -> np.ndarray:
    """(PATH_STEPS, 12) joints q0 + v t + c t^2 (t the step) of both arms, inside the ranges by 0.25 rad all along,
    the wrist angle at least AWAY from 0 (where the two wrist rolls' axes meet) and the elbow at least AWAY from
    stretched; u (12,) in [0, 1] places q0 in what is left of each range."""
    t = np.arange(PATH_STEPS)[:, None]
    v, c = np.asarray(v, float), np.asarray(c, float)
    span = np.abs(v) * (PATH_STEPS - 1) + np.abs(c) * (PATH_STEPS - 1) ** 2  # the farthest the path gets from q0
    lo, hi = ik.lower + 0.25 + span, ik.upper - 0.25 - span
    elbow, wrist = [2, 8], [4, 10]
    lo[elbow] = np.maximum(lo[elbow], STRETCHED_ELBOW + AWAY + span[elbow])
    u = np.array(u, float)
    neg = u[wrist] < 0.5  # the wrist angle below -AWAY or above AWAY
    u[wrist] = np.where(neg, 2 * u[wrist], 2 * u[wrist] - 1)
    hi[wrist] = np.where(neg, -AWAY - span[wrist], hi[wrist])
    lo[wrist] = np.where(neg, lo[wrist], AWAY + span[wrist])
    assert (lo < hi).all()
    return lo + u * (hi - lo) + v * t + c * t * t


def _wrist_reach(ik, q: np.ndarray) -> np.ndarray:
    """(n, 2) m: each arm's wrist centre from its waist axis (0: the shoulder singularity, the waist and the
    forearm roll turn the hand alike) at joints q (n, 12)."""
    m, d = ik.model, ik.cfg.data
    out = np.zeros((len(q), 2))
    for i, qi in enumerate(q):
        ik.cfg.update(qi)
        for a, side in enumerate(("left", "right")):
            wrist, shoulder = d.xpos[m.body(f"{side}_wrist_link").id], d.xpos[m.body(f"{side}_shoulder_link").id]
            out[i, a] = np.linalg.norm((wrist - shoulder)[:2])
    return out


def _off_by(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    """(n, 2) the larger of position / 1 mm and rotation / 0.5 degrees between pinch poses (n, 2, 8): above 1,
    outside the IK's convergence (ik.CONVERGED_POSITION, CONVERGED_ROTATION)."""
    pe = np.linalg.norm(got[..., :3] - want[..., :3], axis=-1)
    re = np.array([[_angle_deg(g[3:7], w[3:7]) for g, w in zip(gt, wt)] for gt, wt in zip(got, want)])
    return np.maximum(pe / 1e-3, re / 0.5)


def _clearance(robot, q: np.ndarray) -> float:
    """The smallest distance (m) of the collision limits' geom pairs over the joint path q (steps, 12)."""
    import mujoco

    ik = robot.ik("pouring")
    m, d = ik.model, ik.cfg.data
    pairs = [(a, b) for lim in ik.limits for a, b in getattr(lim, "geom_id_pairs", [])]
    out = np.inf
    for qt in q:
        ik.cfg.update(qt)
        out = min(out, min(mujoco.mj_geomDistance(m, d, int(a), int(b), 0.2, None) for a, b in pairs))
    return float(out)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=12, max_size=12),
       st.lists(st.floats(-0.04, 0.04), min_size=12, max_size=12),
       st.lists(st.floats(0.005, 0.01), min_size=12, max_size=12),
       st.lists(st.sampled_from([-1.0, 1.0]), min_size=12, max_size=12),
       st.sampled_from([ARMS, ARMS_2F140]))
def test_fk_of_the_ik_answer_is_the_pose(u, v, c, sign, robot):
    """Both arms (the right one on the mirrored base: joints q[6:12]) follow a reachable path (the FK of a
    curved joint-space path inside the ranges, 0.25 rad from their ends, away from the singular
    configurations) from its first configuration: at every step the FK of the IK's answer is the pose
    within 1 mm and 0.5 degrees, for either hand. (From the path's first configuration, not from rest: the
    candidate nearest rest may be another branch, e.g. the wrist's other one, which the margins above do
    not keep away from the ranges' ends and the singular angles.)

    The poses are ones the IK must solve for: the closed-form seeds (aloha/seeds.py) answer any reachable
    pose exactly (the first step: within 1e-12 m over 1200 drawn poses), but every later step starts
    from joints that miss it, the previous step's (the second step) or their constant-velocity
    extrapolation (the later ones), and the path is drawn so that these miss each pose by more than twice
    the bound: without mink's refinement (ArmsIK._iterate) the answers would be off by that much."""
    ik = robot.ik("pouring")
    q = _joint_path(ik, u, v, np.asarray(c) * np.asarray(sign))
    assume(_wrist_reach(ik, q).min() > 0.05)  # away from the shoulder singularity too
    # clear of the table and of each other: mink's collision limits keep the links 1 cm off the table top and
    # the two forearms 2 cm apart (aloha/__init__.py COLLISION_PAIRS), so a pose that puts them closer is not
    # reached exactly, by design
    assume(_clearance(robot, q) > 0.06)
    target = _fk(robot, q)
    unsolved = np.concatenate([q[:1], q[:1], 2 * q[1:-1] - q[:-2]])  # the joints each step starts from
    assume(_off_by(_fk(robot, unsolved)[1:], target[1:]).min() > 2.0)
    sol = ik.follow(target, np.array([[0, PATH_STEPS], [0, PATH_STEPS]]), reference=q[0], symmetric=False)
    back = _fk(robot, sol.q)
    assert sol.q.shape == (PATH_STEPS, 12) and sol.followed.all()
    for a in range(2):
        assert np.linalg.norm(back[:, a, :3] - target[:, a, :3], axis=1).max() < 1e-3, a
        assert max(_angle_deg(back[t, a, 3:7], target[t, a, 3:7]) for t in range(PATH_STEPS)) < 0.5, a
    assert sol.position_error.max() < 1e-3 and sol.rotation_error.max() < 0.5 and not sol.failed_steps().any()


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
    link (forearm or wrist) is in the table while the hand is still above it (a joint-space path; its poses through FK are
    what the episode commands): the IK follows it, the physics stops the wrist link on the table top."""
    rest = np.array(REST * 2)
    down = rest.copy()
    down[1], down[2], down[4] = 0.8, 0.6, -1.8
    w = np.clip(np.arange(90) / 60.0, 0.0, 1.0)[:, None]
    q = (1 - w) * rest + w * down
    act = _fk(ARMS_2F140, q)
    act[:, 0, 7] = 0.0  # the left gripper closed throughout: the arm follows the whole episode (its window)
    d = get_task("open_container").scripted_demo(0)
    r = execute("open_container", d.placement.object_poses, act, options=SimOptions(robot=ARMS_2F140))
    assert not r.success and r.failure == "link_collision", r.detail
    assert "table_top/left_" in r.detail and "finger" not in r.detail and r.robot["reachable"] is True


@functools.lru_cache(maxsize=1)
def _pouring_execution():
    """What the arms (2F-140) execute of the seed-1 pouring demonstration, without physics."""
    d = get_task("pouring").scripted_demo(1)
    return planned_execution("pouring", d.placement.object_poses, d.gripper_actions(),
                             options=SimOptions(robot=get_robot("aloha", "2f140")))


@pytest.fixture(scope="module")
def pouring_with_arms():
    """The seed-1 pouring demonstration executed by the arms with the 2F-140 at the task's own bases."""
    d = get_task("pouring").scripted_demo(1)
    act = d.gripper_actions()
    return act, execute("pouring", d.placement.object_poses, act, options=SimOptions(robot=get_robot("aloha", "2f140")))


def test_joint_targets_are_tracked_in_physics(pouring_with_arms):
    """A reachable episode (the seed-1 pouring demonstration with the 2F-140 on the arms): every step within
    the IK's tolerance, and the position actuators hold the pinch points within a few millimetres of the
    poses the arms execute (their ready-pose start, transits and time-scaling; median under 2 mm): the arms
    move the grippers, no weld does."""
    act, r = pouring_with_arms
    assert r.robot["reachable"] is True and r.robot["ik_position_error_m"] < 0.01, r.robot
    executed = _pouring_execution().actions
    assert r.n_frames == len(executed)
    err = np.linalg.norm(r.gripper_poses[:len(executed), :, :3] - executed[:, :, :3], axis=-1)
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
# placement: the arms follow the objects' demonstrated motion with grasps of their own
# (aloha/retargeting.py), from their ready pose, slowed where a servo is too slow, and every task succeeds.
# Before the retargeting paper_in_case ended `joint_limit` and empty_vase `missed_grasp`.
SCRIPTED = {
    "pouring": (None, "10/10 liquid spheres in the cup"),
    "trash_in_bin": (None, "can centre in bin frame"),
    "paper_in_case": (None, "paper ball centre in case frame"),
    "mix_bowl": (None, "whisk head circled"),
    "open_container": (None, "lid centre in container frame"),
    "empty_vase": (None, "out of the vase: True"),
}


def test_the_scripted_demonstrations_with_the_arms_end_as_the_docs_say(pouring_with_arms):
    tasks = [t for t in SCRIPTED if t != "pouring"]
    eps = {t: get_task(t).scripted_demo(1) for t in tasks}
    got = {t: execute(t, eps[t].placement.object_poses, eps[t].gripper_actions(),
                      options=SimOptions(robot=get_robot("aloha", "2f140"))) for t in tasks}
    got["pouring"] = pouring_with_arms[1]
    for t, (failure, why) in SCRIPTED.items():
        r = got[t]
        assert r.failure == failure and why in r.detail, (t, r.failure, r.detail)
        assert r.robot["reachable"] is (failure != "joint_limit"), (t, r.robot)
        assert 1.0 < r.robot["time_scale"] < 1.2, (t, r.robot)  # the ready-pose start and a few slowed steps


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
        # the arms run one frame more: their ready pose before the demonstration's first
        assert ok and frames[name].shape == (72, 96, 3) and r.n_frames == (21 if name == "arms" else 20), r.n_frames
    differ = np.abs(frames["arms"].astype(int) - frames["grippers"].astype(int)).max(axis=2) > 40
    assert differ.mean() > 0.01, differ.mean()


def test_a_too_fast_trajectory_is_retimed_on_its_path():
    """The left arm swings from its ready pose to a reach over 10 frames (about three times faster than its
    servos turn), gripper closed throughout (the whole episode is its window): the arms run it slower
    instead of failing it: time-scale > 1.5 (the poses are smoothed first), no joint above its speed limit, every executed pinch point on
    the path the arm follows (the demonstration smoothed and retargeted: within 2 mm of its polyline), the
    last executed pose that path's last, and no verdict."""
    rest = np.array(REST * 2)
    reach = rest.copy()
    # the wrist stays bent (-0.3 -> -0.9 rad): through a straight wrist (its singularity) the rolls spin and
    # no joint-space interpolation stays within 2 mm of the path; that is not what this test is about
    reach[0], reach[1], reach[2], reach[4] = 1.0, 0.3, 0.1, -0.9
    w = quintic(np.arange(11) / 10.0)[:, None]
    act = _fk(ARMS_2F140, (1 - w) * rest + w * reach)
    act[:, 0, 7] = 0.0
    d = get_task("pouring").scripted_demo(1)
    motion = ARMS_2F140.motion("pouring", act, get_task("pouring").keypoints_world(d.placement.object_poses), fps=30.0)
    ik = ARMS_2F140.ik("pouring")
    assert max_speed_ratio(act_joints := ik.solve(act).q, 30.0, ik.speed) > 2.0  # the demonstration is too fast
    assert motion.first_failure() is None and motion.summary()["reachable"], motion.first_failure()
    assert motion.time_scale > 1.5 and max_speed_ratio(motion.q, 30.0, ik.speed) <= 1.0 + 1e-6  # smoothed first
    assert np.linalg.norm(motion.poses[-1, 0, :3] - motion.targets[-1, 0, :3]) < 1e-3
    assert _angle_deg(motion.poses[-1, 0, 3:7], motion.targets[-1, 0, 3:7]) < 0.5
    path = motion.targets[:, 0, :3]
    a, b = path[:-1], path[1:]
    run = motion.poses[motion.s >= 0, None, 0, :3]  # the demonstrated frames (not the ready pose before them)
    u = np.clip(np.einsum("mki,ki->mk", run - a, b - a) / np.maximum(np.einsum("ki,ki->k", b - a, b - a), 1e-12), 0, 1)
    off = np.linalg.norm(run - (a + u[..., None] * (b - a)), axis=-1).min(axis=1)
    assert off.max() < 0.002, off.max()


def test_the_arms_start_at_their_ready_pose_and_reach_the_first_skill_segment():
    """The seed-1 pouring demonstration: the arms start at their ready pose (not the demonstrator's hand at
    rest), move in joint space into each arm's window, which begins before that arm's first skill segment,
    and from there every executed demonstrated step is the recorded pose (within 1 cm and 5 degrees)."""
    from demoforge.lib.trajectories.segmentation import segment_trajectory

    d = get_task("pouring").scripted_demo(1)
    act = d.gripper_actions()
    execution = _pouring_execution()
    motion = execution.state
    assert np.allclose(motion.q[0], np.array(REST * 2)) and motion.s[0] == -1.0
    task = get_task("pouring")
    segs = segment_trajectory(act, task.keypoints_world(d.placement.object_poses), task.keypoint_object)
    for arm in range(2):
        first_skill = min(s.start for s in segs if s.arm == arm and s.kind == "skill")
        w0, w1 = motion.windows[arm]
        assert 0 < w0 <= first_skill < w1
        # the window as executed: on its recorded path (each frame at its place between two demonstrated steps)
        rows = np.flatnonzero((motion.s >= w0) & (motion.s <= w1 - 1))
        assert len(rows) >= w1 - w0 - 1  # at least a frame per demonstrated step
        pe = np.linalg.norm(execution.actions[rows, arm, :3] - at(act[:, arm, :3], motion.s[rows]), axis=-1)
        assert pe.max() < 0.01, pe.max()
        # before the window: the transit from the ready pose, not the demonstrator's hand coming from rest
        before = motion.s < w0
        assert np.linalg.norm(execution.actions[before, arm, :3][1:w0 // 2] - act[1:w0 // 2][:len(
            execution.actions[before][1:w0 // 2]), arm, :3], axis=-1).max() > 0.02


def test_a_grasp_turned_half_a_turn_is_followed_with_the_nearest_wrist():
    """A parallel gripper turned 180 degrees about its approach axis grasps the same way: a window whose
    poses are a reachable path near the ready pose, turned half a turn, is followed with the same joints
    as the path itself (flipped), not with the wrist rotated by half a turn."""
    from scipy.spatial.transform import Rotation

    rest = np.array(REST * 2)
    near = rest.copy()
    near[0], near[1], near[4] = 0.2, 0.2, 0.3
    w = np.linspace(0.0, 1.0, 5)[:, None]
    q = (1 - w) * rest + w * near
    act = _fk(ARMS_2F140, q)
    turned = act.copy()
    turned[:, 0, 3:7] = (Rotation.from_quat(act[:, 0, 3:7]) * Rotation.from_euler("z", np.pi)).as_quat()
    ik = ARMS_2F140.ik("pouring")
    windows = np.array([[0, 5], [5, 5]])
    sol = ik.follow(turned, windows, reference=rest, symmetric=True)
    assert sol.flipped[0] and np.abs(sol.q[:, :6] - q[:, :6]).max() < 0.02, sol.q[:, :6] - q[:, :6]
    direct = ik.follow(turned, windows, reference=rest, symmetric=False)
    assert not direct.flipped[0] and abs(direct.q[0, 5] - rest[5]) > 2.5  # the wrist half a turn away


def test_the_transit_check_flags_a_hand_raised_out_of_the_workspace():
    """The transits' check (AlohaBinding.collision_check) flags an arm whose pinch point leaves the task's
    workspace by more than the arms' slack, as the physics check would fail it (`left_workspace`): the
    planner then takes another way. The ready pose is inside; the left forearm pointing up is not."""
    from demoforge.lib.sim.executor import as_object_poses, get_scene

    opt = SimOptions(robot=get_robot("aloha", "2f140"))
    sc = get_scene("trash_in_bin", opt.robot, opt.physics)
    demo = get_task("trash_in_bin").scripted_demo(1)
    collides = sc.binding.collision_check(sc, as_object_poses(sc.task, demo.placement.object_poses))
    rest = np.array(REST * 2)
    up = rest.copy()
    up[1], up[2] = 0.0, -1.5  # shoulder upright, elbow bent up: the hand over a metre high
    assert collides(np.stack([rest, up])).tolist() == [[False, False], [True, False]]
