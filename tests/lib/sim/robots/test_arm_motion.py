"""The arms' motion around a window (lib/sim/robots/arm_motion.py): the transit out of a window."""

import numpy as np

from demoforge.lib.sim.robots import arm_motion
from demoforge.lib.sim.robots.aloha.model import REST
from demoforge.lib.sim.robots.ik import IKSolution
from tests.support.aloha import ARMS_2F140

# the left arm stretched out over the table with its gripper pointing down (a release in paper_in_case)
STRETCHED = (-1.48, 0.87, -0.91, 0.24, 1.77, -1.4)


def _stretched():
    ik = ARMS_2F140.ik("paper_in_case")
    rest = np.array(REST * 2)
    q = rest.copy()
    q[:6] = STRETCHED
    return ik, rest, q


def test_a_stretched_arm_draws_back_towards_its_base_where_it_cannot_lift():
    """Out of reach straight up with its orientation kept, the released hand's waypoint is drawn back
    towards the arm's base instead: the pinch pose moved horizontally by `back` towards the base and up by
    `lift`, its orientation the same."""
    ik, rest, q = _stretched()
    assert all(arm_motion._lifted(ik, 0, q, lift) is None for lift in arm_motion.LIFTS)
    (p0,), (R0,) = (x[:, 0] for x in ik.fk(q[None]))
    for back, lift in arm_motion.RETREATS:
        via = arm_motion._lifted(ik, 0, q, lift, back)
        assert via is not None
        qv = q.copy()
        qv[:6] = via
        (p,), (R,) = (x[:, 0] for x in ik.fk(qv[None]))
        to_base = np.linalg.norm(ik.base_xy[0] - p0[:2]) - np.linalg.norm(ik.base_xy[0] - p[:2])
        assert abs(to_base - back) < 2e-3 and abs(p[2] - p0[2] - lift) < 2e-3, (to_base, p[2] - p0[2])
        assert np.degrees(np.arccos(np.clip((np.trace(R0.T @ R) - 1) / 2, -1, 1))) < 1.0


def test_the_way_out_of_a_window_avoids_what_the_direct_way_passes_through():
    """An obstacle (the other hand, still working) in the middle of the joint-space way from the release
    to the ready pose: the transit out of the window goes round it over a drawn-back waypoint and still
    ends at the ready pose."""
    ik, rest, q = _stretched()
    n, w1 = 40, 10
    sol = IKSolution(np.tile(q, (n, 1)), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2), bool), 0)
    direct = np.tile(q, (n - w1 + 1, 1))
    direct[:, :6] = arm_motion._legs(q[:6], rest[:6], n - w1)
    obstacle = ik.fk(direct)[0][len(direct) // 2, 0]

    def collides(rows):
        near = np.linalg.norm(ik.fk(rows)[0][:, 0] - obstacle, axis=-1) < 0.08
        return np.stack([near, np.zeros_like(near)], axis=1)

    assert collides(direct).any()
    Q = arm_motion._with_transits(ik, sol, np.array([[0, w1], [0, 0]]), rest, collides)
    assert not collides(Q[w1:]).any()
    assert np.allclose(Q[-1], rest) and np.allclose(Q[w1], q)


def test_a_transit_through_waypoints_stops_at_each_of_them():
    points = [np.zeros(6), np.full(6, 1.0), np.array([1.0, 2, 0, 0, 0, 0]), np.full(6, -1.0)]
    path = arm_motion._through(points, 30)
    assert path.shape == (31, 6)
    for i, p in zip((0, 10, 20, 30), points):
        assert np.allclose(path[i], p)
        speed = np.abs(np.diff(path, axis=0))
        assert i == 0 or np.abs(path[i] - path[i - 1]).max() < speed.max() / 5  # at rest there


def test_the_hand_passes_over_the_bottle_on_its_way_to_the_grasp():
    """pouring's seed-2 demonstration: every joint-space way into the left window, over a lifted waypoint
    or not, sweeps the open fingers through the bottle's top (the ready pose lies beyond the bottle); the
    way with the waist turned first at the ready pose's height passes over it, so the bottle stands
    still until the hand closes on it, and the pour succeeds."""
    from demoforge.lib.sim import SimOptions, execute
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task

    demo = get_task("pouring").scripted_demo(2)
    r = execute("pouring", demo.placement.object_poses, demo.gripper_actions(),
                options=SimOptions(robot=get_robot("aloha", "2f140"), keep_trajectory=True))
    assert r.success, (r.failure, r.detail)
    closed = int(np.argmax(r.command_g[:, 0] < 0.5))
    bottle = r.object_poses[:closed, 0, :3, 3]
    assert np.linalg.norm(bottle - bottle[0], axis=-1).max() < 0.005
