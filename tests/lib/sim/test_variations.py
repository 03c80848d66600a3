"""Simulated scene variations (Table 4 analogue; demoforge.lib.sim.variations): resized objects, distractors, moved
placements. (The flow: tests/flows/test_variations.py.)"""

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.spatial.transform import Rotation

from demoforge.lib.task_library import get_task
from demoforge.lib.task_library import objects as ob
from demoforge.lib.sim.variations import (
    TABLE4_TASKS, VARIATION_KINDS, Distractor, VariationRanges, footprint_groups, make_variation,
    object_footprints,
)

SLOW = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
RESIZABLE = [(t, o) for t in TABLE4_TASKS for o in get_task(t).resizable]


def _object_geometry(task, obj: str):
    """(max |x|, max |y|, top z, total mass) of object `obj`'s compiled geometry in its own frame (the
    object placed upright at the origin), from MuJoCo's per-geom bounding boxes."""
    import mujoco

    from demoforge.lib.task_library import Placement

    poses = np.tile(np.eye(4), (len(task.objects), 1, 1))
    poses[:, 0, 3] = np.arange(len(task.objects)) * 0.5  # apart; `obj` at its own origin below
    k = task.object_names.index(obj)
    poses[k, :3, 3] = 0.0
    m = mujoco.MjModel.from_xml_string(task.scene_xml(Placement(poses)))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, obj)
    g = np.flatnonzero(m.geom_bodyid == b)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    corners = m.geom_aabb[g, None, :3] + signs[None] * m.geom_aabb[g, None, 3:]
    world = np.einsum("gij,gkj->gki", d.geom_xmat[g].reshape(-1, 3, 3), corners) + d.geom_xpos[g][:, None]
    p = world.reshape(-1, 3)
    return np.abs(p[:, 0]).max(), np.abs(p[:, 1]).max(), p[:, 2].max(), float(m.body_mass[b])


@pytest.mark.parametrize("task_name,obj", RESIZABLE)
@given(s_xy=st.floats(0.8, 1.25), s_z=st.floats(0.8, 1.25))
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_resized_object_changes_geometry_and_keypoints_together(task_name, obj, s_xy, s_z):
    base = get_task(task_name)
    attr = base.resizable[obj][0]
    d0 = getattr(base, attr)
    var = base.variant({obj: ob.scale_dims(obj, d0, s_xy, s_z)})
    k = base.object_names.index(obj)
    kp0 = base.keypoints_local[base.keypoint_object == k]
    kp1 = var.keypoints_local[var.keypoint_object == k]
    x0, y0, top0, mass0 = _object_geometry(base, obj)
    x1, y1, top1, mass1 = _object_geometry(var, obj)
    tol = d0.get("t", 0.0) + 0.0015  # walls keep their thickness; keypoints sit on one face of a wall
    # the keypoints still lie on the compiled geometry (top, and the side where a keypoint marks one)
    assert abs(kp1[:, 2].max() - top1) <= tol
    if np.abs(kp0[:, 0]).max() > 0:
        assert abs(np.abs(kp1[:, 0]).max() - x1) <= tol
    # ... and geometry and keypoints moved together: the heights by s_z, the widths by s_xy
    assert top1 - top0 == pytest.approx(kp1[:, 2].max() - kp0[:, 2].max(), abs=tol)
    lo, hi = sorted((s_z - 1, s_xy - 1))  # a top made of heights and radii (a whisk's head) moves in between
    assert lo * top0 - tol <= top1 - top0 <= hi * top0 + tol
    assert x1 - x0 == pytest.approx((s_xy - 1) * x0, abs=tol)
    assert mass1 == pytest.approx(mass0 * s_xy * s_xy * s_z, rel=1e-4)
    # the grasp width follows a resized grasp (a bottle's diameter, not a bin's wall)
    w0, w1 = base.grasp_widths[k], var.grasp_widths[k]
    assert w1 == pytest.approx(base.resizable[obj][2](var.__dict__[attr]))
    # the base task is untouched
    assert np.array_equal(get_task(task_name).keypoints_local, base.keypoints_local) and w0 == base.grasp_widths[k]


def test_variant_without_changes_is_the_task():
    for name in TABLE4_TASKS:
        t = get_task(name)
        p = t.sample_placement(np.random.default_rng(4))
        v = t.variant()
        assert v.scene_xml(p) == t.scene_xml(p) and np.array_equal(v.keypoints_local, t.keypoints_local)
    with pytest.raises(ValueError, match="cannot resize"):
        get_task("pouring").variant({"bin": dict(ob.BIN)})
    with pytest.raises(ValueError, match="no resize rule"):
        ob.scale_dims("cup", {**ob.CUP, "lip": 0.01}, 1.1, 1.0)


@given(task=st.sampled_from(TABLE4_TASKS), seed=st.integers(0, 10_000), trial=st.integers(0, 5))
@SLOW
def test_variations_are_paired_deterministic_and_valid(task, seed, trial):
    r = VariationRanges()
    vs = {k: make_variation(task, k, seed, trial) for k in VARIATION_KINDS}
    again = make_variation(task, "clutter", seed, trial)
    assert again.params == vs["clutter"].params and again.tag == vs["clutter"].tag
    nominal = vs["nominal"].object_poses
    for k in ("nominal", "clutter", "spatial"):
        assert np.array_equal(vs[k].nominal_poses, nominal)
    assert np.array_equal(vs["clutter"].object_poses, nominal)
    base = get_task(task)
    c0, r0 = object_footprints(base, nominal)
    # clutter: solid distractors clear of every task object's footprint
    ds = vs["clutter"].distractors
    assert r.n_distractors[0] <= len(ds) <= r.n_distractors[1]
    for d in ds:
        assert (np.linalg.norm(c0 - [d.x, d.y], axis=1) >= r0 + d.radius + r.distractor_clearance - 1e-9).all()
    # spatial: every object moved and turned within the ranges, still upright, footprints apart
    sp = vs["spatial"]
    for k, name in enumerate(base.object_names):
        dx, dy, dyaw = sp.moves[name]
        assert r.shift[0] - 1e-9 <= np.hypot(dx, dy) <= r.shift[1] + 1e-9
        assert r.turn[0] - 1e-9 <= abs(dyaw) <= r.turn[1] + 1e-9
        rel = Rotation.from_matrix(sp.object_poses[k, :3, :3] @ nominal[k, :3, :3].T).as_rotvec()
        assert np.allclose(rel[:2], 0, atol=1e-9) and rel[2] == pytest.approx(dyaw, abs=1e-9)
        assert sp.object_poses[k, 2, 3] == pytest.approx(nominal[k, 2, 3])
    c1, r1 = object_footprints(base, sp.object_poses)
    groups = footprint_groups(c0, r0)
    for a in range(len(r1)):
        for b in range(a + 1, len(r1)):
            if not any(a in g and b in g for g in groups):
                assert np.linalg.norm(c1[a] - c1[b]) >= r1[a] + r1[b] + r.object_gap - 1e-9
    # object: the keypoints a strategy sees are those of the resized objects
    ov = vs["object"]
    assert set(ov.scales) == set(base.resizable)
    assert np.allclose(ov.keypoints, ov.task().keypoints_world(ov.object_poses))
    assert not np.allclose(ov.keypoints, base.keypoints_world(ov.object_poses))
    json.dumps(ov.params)  # stored as a JSON column


def _sweep_actions(x0, x1, y, z, n=90):
    """Arm 0 closed, pointing down, sweeping along x; arm 1 parked at its home."""
    q_down = Rotation.from_matrix([[1, 0, 0], [0, -1, 0], [0, 0, -1]]).as_quat()
    a = np.zeros((n, 2, 8))
    a[:, 0, 0] = np.linspace(x0, x1, n)
    a[:, 0, 1:3] = [y, z]
    a[:, 1, :3] = [0.27, -0.14, 0.25]
    a[:, :, 3:7] = q_down
    a[:, :, 7] = 0.0
    return a


def test_distractor_is_a_solid_body_the_gripper_pushes():
    from demoforge.lib.sim.variation_scene import VariationScene

    box = Distractor("distractor_0", "box", (0.03, 0.03, 0.04), -0.05, 0.02, 0.0, 0.15, "1 0 0 1")
    v = replace(make_variation("trash_in_bin", "clutter", 0, 0), distractors=(box,))
    scene = VariationScene(v)
    m, mj = scene.scene.model, scene.scene.mj
    b = int(scene.distractor_body[0])
    assert m.body_jntnum[b] == 1 and m.jnt_type[m.body_jntadr[b]] == mj.mjtJoint.mjJNT_FREE
    assert m.body_mass[b] == pytest.approx(0.15)
    # passing above it leaves it resting on the table ...
    above = scene.execute(_sweep_actions(-0.25, 0.1, 0.02, 0.2))
    assert above.physics_steps > 0
    assert scene.last_distractor_shift[0] < 0.002
    assert scene.scene.data.xpos[b, 2] == pytest.approx(0.0, abs=0.003)  # on the table top, not through it
    table = mj.mj_name2id(m, mj.mjtObj.mjOBJ_GEOM, "table_top")
    geoms = set(np.flatnonzero(m.geom_bodyid == b).tolist())
    con = scene.scene.data.contact.geom[:scene.scene.data.ncon]
    assert any((g0 == table and g1 in geoms) or (g1 == table and g0 in geoms) for g0, g1 in con)
    # ... sweeping the gripper through it pushes it away
    scene.execute(_sweep_actions(-0.25, 0.1, 0.02, 0.05))
    assert scene.last_distractor_shift[0] > 0.03


@pytest.mark.parametrize("task_name", TABLE4_TASKS)
def test_scripted_demo_transformed_to_a_moved_placement_succeeds(task_name):
    """The transform keeps the scripted demonstration valid on a shifted and turned placement (so the
    spatial column measures the strategies, not a broken scene)."""
    from demoforge.lib.trajectories.augmentation import (
        estimate_object_poses, from_scripted_demo, transform_demo,
    )
    from demoforge.lib.sim.variation_scene import VariationScene

    task = get_task(task_name)
    src = from_scripted_demo(task, task.scripted_demo(0))
    v = make_variation(task_name, "spatial", 0, 0)
    assert all(np.hypot(m[0], m[1]) >= 0.04 and abs(m[2]) >= 0.3 for m in v.moves.values())
    poses = estimate_object_poses(v.keypoints, task.keypoints_local, task.keypoint_object)
    r = VariationScene(v).execute(transform_demo(src, poses))
    assert r.success, r.detail
    # the untransformed demonstration on the moved placement does not do the task
    r0 = VariationScene(v).execute(src.trajectory)
    assert not r0.success
