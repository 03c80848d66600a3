"""The augmentation's plans (demoforge.lib.trajectories.augmentation.plan): the thesis's schedule keeps every
original frame in order, and a skill segment keeps the gripper's pose relative to its object under any scene
transform."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demoforge.lib import geometry as geo
from demoforge.lib.task_library import TASK_NAMES
from demoforge.lib.trajectories import augmentation as au
from tests.support.episodes import scripted_source


@pytest.mark.parametrize("follow", [False, True])
def test_thesis_mode_identity_keeps_original_frames(follow):
    src = scripted_source("pouring")
    plan = au.make_plan(src, "thesis", n_transition=10, follow_objects=follow)
    out = au.execute_plan(src, plan, np.zeros((1, 2, 3)), np.zeros((1, 2, 2)))[0]
    for arm in range(2):
        keep = ~plan.inserted[:, arm]
        np.testing.assert_allclose(out[keep, arm], src.trajectory[plan.src[keep, arm], arm], atol=1e-12)
        # every original frame appears, in order
        assert np.array_equal(np.unique(plan.src[:, arm]), np.arange(src.n_frames))
        assert np.all(np.diff(plan.src[:, arm]) >= 0)


@settings(max_examples=25, deadline=None)
@given(dx=st.floats(-0.2, 0.2), dy=st.floats(-0.2, 0.2), dyaw=st.floats(-np.pi, np.pi),
       dx2=st.floats(-0.2, 0.2), dy2=st.floats(-0.2, 0.2), dyaw2=st.floats(-np.pi, np.pi),
       name=st.sampled_from(TASK_NAMES), mirror=st.booleans())
def test_skill_relative_pose_preserved(dx, dy, dyaw, dx2, dy2, dyaw2, name, mirror):
    src = scripted_source(name)
    if mirror:
        src = au.mirror_source(src)
    params = np.array([[[dx, dy, dyaw], [dx2, dy2, dyaw2]]])
    pivots = np.array([[[0.1, 0.2], [-0.1, 0.3]]])
    out = au.execute_plan(src, au.make_plan(src), params, pivots)[0]
    D = au.transform_matrices(params, pivots)[0]
    P0 = au.estimate_object_poses(src.keypoints, src.keypoints_local, src.keypoint_object)
    P1 = D @ P0
    # the new object poses estimated from the new keypoints agree with D @ P0
    kp_new = au.transform_keypoints(src, params, pivots)[0]
    np.testing.assert_allclose(au.estimate_object_poses(kp_new, src.keypoints_local, src.keypoint_object), P1, atol=1e-9)
    T_old = geo.pose7_to_transform(src.trajectory[..., :7])
    T_new = geo.pose7_to_transform(out[..., :7])
    for s in src.segments:
        if s.kind != "skill" or s.object < 0:
            continue
        rel_old = geo.transform_inverse(P0[s.object]) @ T_old[s.start:s.end, s.arm]
        rel_new = geo.transform_inverse(P1[s.object]) @ T_new[s.start:s.end, s.arm]
        np.testing.assert_allclose(rel_new, rel_old, atol=1e-9)
