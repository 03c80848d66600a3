"""Out-of-distribution scenes for the policy (demoforge.lib.policy.scenes): placements outside the database's
translation box, on the table."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.episodes import scripted_policy_data


@pytest.fixture(scope="module")
def scripted():
    return scripted_policy_data()


def test_out_of_distribution_placements_leave_the_translation_box_and_stay_on_the_table(scripted):
    from demoforge.lib.policy.scenes import in_box, ood_placement, placement_offsets, translation_box
    from demoforge.lib.sim.executor import object_poses_from_keypoints
    from demoforge.lib.task_library import get_task

    spec = get_task("pouring")
    box = translation_box(scripted.placement[1:])
    assert np.all(box[0] < 0) and np.all(box[1] > 0)
    original = object_poses_from_keypoints(spec, scripted.keypoints[0])
    # the database's own translated episodes are inside the box
    for i in np.flatnonzero(scripted.kind == "translated")[:5]:
        assert in_box(placement_offsets(original, object_poses_from_keypoints(spec, scripted.keypoints[i])), box, 1e-6)
    for s in range(10):
        poses = ood_placement(original, box, np.random.default_rng(s), spec.keypoints_world, spec.workspace)
        assert not in_box(placement_offsets(original, poses), box)
        kp = spec.keypoints_world(poses)
        assert np.all(kp[:, :2] >= spec.workspace[0, :2]) and np.all(kp[:, :2] <= spec.workspace[1, :2])
        np.testing.assert_allclose(poses[:, :3, :3], original[:, :3, :3])  # translation only
    with pytest.raises(ValueError, match="workspace"):
        ood_placement(original, box, np.random.default_rng(0), spec.keypoints_world,
                      np.array([[-0.01, -0.01, 0], [0.01, 0.01, 1]]), tries=50)
