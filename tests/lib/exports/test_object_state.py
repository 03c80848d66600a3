"""The objects' state in the exports (demoforge.lib.exports.object_state): the carried keypoints, rebuilt from an
episode's gripper poses, equal the task library's scenes and the per-episode segmentation rule."""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib.exports import ExportError
from tests.support.episodes import TASK


@pytest.mark.parametrize("mirror", [False, True])
def test_carried_object_keypoints_match_the_task_library_scenes(mirror):
    """The environment state's keypoints, rebuilt from an episode's gripper poses and its first
    scene only, equal the task library's own per-frame object keypoints for every task's scripted
    demonstration (plain and mirrored: the arms' roles swap)."""
    from demoforge.lib.exports.object_state import episode_object_keypoints
    from demoforge.lib.task_library import TASK_NAMES, get_task

    demos, moved = [], 0
    for name in TASK_NAMES:
        spec = get_task(name)
        d = spec.scripted_demo(0, mirror=mirror)
        demos.append((spec, d.gripper_actions(), d.keypoints()))
    poses = np.concatenate([a for _, a, _ in demos])
    lengths = np.array([len(a) for _, a, _ in demos])
    # all six in one call: concatenated episodes of different lengths (every task has 11 keypoints)
    got = episode_object_keypoints(poses, lengths, np.stack([k[0] for _, _, k in demos]), demos[0][0].keypoint_object)
    for (spec, a, kp), part in zip(demos, np.split(got, np.cumsum(lengths)[:-1])):
        assert (spec.keypoint_object == demos[0][0].keypoint_object).all()
        np.testing.assert_allclose(part, kp, atol=1e-9, err_msg=spec.name)
        moved += np.abs(kp - kp[0]).max() > 0.1  # the manipulated object travels
    assert moved == len(TASK_NAMES)
    with pytest.raises(ExportError, match="object keypoints must be"):
        episode_object_keypoints(poses, lengths, np.zeros((len(lengths), 10, 3)), demos[0][0].keypoint_object)


def test_carried_keypoints_vectorised_equal_the_per_episode_segmentation_rule(episode_wh):
    """Over a real augmented database (translated and mirrored episodes, one call), the vectorised
    carry equals demoforge.lib.trajectories.segmentation's per-episode functions (infer_object_arm + object_keypoints_over_time)."""
    from demoforge.schemas.reads.episodes import load_episodes
    from demoforge.lib.exports.object_state import episode_object_keypoints, object_arms
    from demoforge.lib.trajectories.segmentation import infer_object_arm, object_keypoints_over_time
    from demoforge.lib.task_library import get_task

    wh, _ = episode_wh
    sel = load_episodes(str(wh), TASK, include_invalid=True)
    ko = get_task(TASK).keypoint_object
    got = episode_object_keypoints(sel.poses, sel.lengths, sel.keypoints, ko)
    arms = object_arms(sel.poses.astype(float), sel.lengths, sel.keypoints, ko)
    start = 0
    for i, L in enumerate(sel.lengths.tolist()):
        traj = sel.poses[start:start + L].astype(float)
        arm_of = infer_object_arm(traj, sel.keypoints[i], ko)
        assert arms[i].tolist() == arm_of.tolist()
        held = np.stack([np.where(traj[:, a, 7] < 0.5, np.flatnonzero(arm_of == a)[0], -1) for a in (0, 1)], axis=1)
        want = object_keypoints_over_time(traj, sel.keypoints[i], ko, held)
        np.testing.assert_allclose(got[start:start + L], want, atol=1e-9)
        start += L
    mirrored = sel.kind == "mirrored"
    assert mirrored.any() and (arms[mirrored] == 1 - arms[~mirrored][0]).all()  # the roles swap
