"""Object-centric dual-arm demonstration augmentation (thesis 3.2) and mirror flipping (thesis 3.3).

One demonstration (gripper trajectory (T, 2, 8), object keypoints at frame 0 (11, 3), motion/skill
segments per arm) -> thousands of episodes in new scenes, vectorised over the whole batch.

Scene transform.  Every object o gets a rigid planar transform
    D_o = [Rz(dyaw), c_o + (dx, dy, 0) - Rz(dyaw) c_o]        (yaw about the pivot c_o, then shift)
so that the new object pose is T_o' = D_o T_o (thesis: T_obj' = T_move T_obj) and a gripper pose
re-projected through the object frame is T_o' T_o^-1 T_ee = D_o T_ee.  independent=False (the
thesis's setting): one (dx, dy, dyaw) for the whole scene, pivot = centroid of all keypoints, so
the whole scene moves rigidly.  independent=True: one (dx, dy, dyaw) per object *group*, pivot = the
group's keypoint centroid; objects whose initial xy centres are closer than `stack_radius` (a lid on
its container, flowers in their vase) form one group and move together.

Which transform a segment follows (Segment.object of the task library, DESIGN: "skill: the object
the hand acts on / relative to; motion: the object of the next skill"):
  * a skill segment follows its object exactly: T_new(t) = D_obj T_ee(t), so the gripper pose
    relative to that object is preserved (the pour follows the cup, which the other hand holds and
    which itself moves with D_cup; the holder's skill follows the cup too, so both agree);
  * mode "object" (default, ours): original timing is kept for both arms (so the arms stay as
    synchronised as in the human take, no waiting needed); a motion segment blends smoothly from
    the transform of where it starts (the previous skill's object; identity at frame 0, i.e. the
    robot's start pose is not moved) to the transform of where it ends (the next skill's object;
    identity for a final return-home segment), with a cubic ease e(u) = 3u^2 - 2u^3.  The blend of
    two planar transforms of the same pose is exact slerp/lerp: yaw and translation interpolated.
    With identity transforms this reproduces the original exactly.
  * mode "thesis": the thesis's schedule.  P0: cubic transition (n_transition frames) from the
    initial pose to the transformed start of the first motion segment; both arms wait for each
    other.  P1: first motion segment transformed (by its object's transform); the faster arm waits
    (holds its pose) until both are done.  P2: first skill segment transformed; wait.  P3: cubic
    transition from the end of the first skill back to the start of the second motion segment; P4:
    the rest of the original.  follow_objects=False (literal thesis): P4 is replayed in the world
    frame unchanged; follow_objects=True: P4 segments follow their objects as in mode "object".
    Caveat found on the six tasks: the receiving hand's first skill (grasp-hold-release) spans the
    other hand's whole task, so the P2 barrier makes the acting hand wait until the holder has
    released; the literal schedule is kept for comparison, "object" is the default.

Mirroring (thesis 3.3, task library base.py): points p -> M p (x -> -x); gripper poses by
demoforge.lib.geometry.reflect_pose8 (reflect rows, negate the gripper y column: det +1, thumb stays thumb,
identical to the task library's P' = M P D); arms swapped; object keypoints reflected and permuted by
`mirror_permutation` (keypoint i of the mirrored scene = reflection of keypoint perm[i], perm swaps
the left/right pairs mirror-symmetric in the object's local x), which is exactly how the task library
builds its mirrored takes: the mirrored scripted demo of seed s is mirror_source(plain demo of seed s).

Episodes: the original demo is episode 0 (kind "original", identity transform), followed by
n - n_mirrored "translated" and n_mirrored "mirrored" (mirrored, then transformed) episodes, ids 0..n.
actions[i, :lengths[i]] is the full sequence including frame 0; initial = actions[:, 0].  Padding
(only when plans differ in length) repeats the final pose.
"""

from demoforge.lib.trajectories.augmentation.source import (  # noqa: F401
    DemoSource, estimate_object_poses, from_scripted_demo, object_groups,
)
from demoforge.lib.trajectories.augmentation.mirror import mirror_keypoints, mirror_permutation  # noqa: F401
from demoforge.lib.trajectories.augmentation.source import mirror_source  # noqa: F401
from demoforge.lib.trajectories.augmentation.plan import (  # noqa: F401
    Plan, Run, execute_plan, make_plan, plan_object, plan_thesis, transform_demo, transform_keypoints,
    transform_matrices, transform_tables,
)
from demoforge.lib.trajectories.augmentation.generate import (  # noqa: F401
    EpisodeBatch, REJECT_REASONS, check_episodes, generate_episodes, sample_params, transform_demo_loop,
)
