"""Where the two ViperX bases stand at each task's table.

World frame (docs/architecture.md): origin on the table top's front part, z up, y away from the
demonstrator, x to the right; the table top spans x in [-0.75, 0.75], y in [-0.15, 0.75] at z = 0; the
synthetic takes' camera is at (0, -0.40, 0.90), looking at (0, 0.25, 0). The arms replace the
demonstrator's hands: both bases stand on the table near its front edge (most on a 15 cm riser: the
arm then reaches the demonstrator's hands at rest, 15-20 cm above the table, without its wrist at the
end of its range), left and right of the camera, which is above and between them (0.7 to 0.9 m
apart; the camera 0.35 to 0.55 m behind them and 0.75 m above).
The left arm's base is given; the right arm's is its mirror image across x = 0 (every task is done
plain and mirrored, with the arms' roles swapped).

The positions were chosen by `scripts/place_aloha_bases.py`: for each candidate base position (x in
-0.35 .. -0.55 m, y in -0.15 .. 0.25 m, 0.1 m apart, on the table or a 15 cm riser; earlier runs
covered x to -0.65 and y from -0.45 with lower scores) it tracks every step of the scripted
demonstrations (seeds 0-1, plain and mirrored) with the IK as the simulator does, and keeps the one
with the most steps within 1 cm and 5 degrees, averaged over both hands. docs/robot-checks.md ("The
ALOHA arms") has the table and a picture.
"""

from __future__ import annotations

import math

from .model import BasePose

#: the left arm's base per task (the right arm's: BasePose.mirrored()); yaw pi/2 = facing +y. The yaw
#: only moves where the waist's +-180 degrees end, so the search keeps it fixed. Chosen by
#: `scripts/place_aloha_bases.py --seeds 2` (both hands; the best mean share of reachable steps), except
#: open_container's and empty_vase's, chosen in physics (`--physics`, then a sample of each database:
#: docs/robot-checks.md, "Where the arms stand"). At the reachable-steps choice open_container's right
#: arm held the container low beside its riser, its shoulder at its limit, and empty_vase's left hand laid
#: the flowers down over its own shoulder.
PLACEMENTS: dict[str, BasePose] = {
    "pouring": BasePose(-0.45, 0.05, 0.15, math.pi / 2),
    "trash_in_bin": BasePose(-0.35, -0.05, 0.15, math.pi / 2),
    "paper_in_case": BasePose(-0.45, 0.05, 0.15, math.pi / 2),
    "mix_bowl": BasePose(-0.45, 0.05, 0.15, math.pi / 2),
    "open_container": BasePose(-0.35, -0.05, 0.15, math.pi / 2),
    "empty_vase": BasePose(-0.45, 0.05, 0.15, math.pi / 2),
}
DEFAULT = BasePose(-0.45, 0.05, 0.15, math.pi / 2)  # a task the table does not list (custom tasks)


def bases_for(task_name: str) -> tuple[BasePose, BasePose]:
    """(left, right) base poses at a task's table (a task the table does not list: the default)."""
    left = PLACEMENTS.get(task_name, DEFAULT)
    return left, left.mirrored()
