"""Where the two ViperX bases stand at each task's table.

World frame (docs/architecture.md): origin on the table top's front part, z up, y away from the
demonstrator, x to the right; the table top spans x in [-0.75, 0.75], y in [-0.15, 0.75] at z = 0; the
synthetic takes' camera is at (0, -0.40, 0.90), looking at (0, 0.25, 0). The arms replace the
demonstrator's hands, so their bases stand where a person's shoulders would be: on the table top at
its front edge, left and right of the camera, which is above and between them. The left arm's base is
given; the right arm's is its mirror image across x = 0 (every task is done plain and mirrored, with
the arms' roles swapped).

The positions were chosen by `scripts/place_aloha_bases.py`, which solves the IK for every step of the
scripted demonstrations (seeds 0-3, plain and mirrored) at each candidate base position and keeps the
one with the most steps within 1 cm and 5 degrees (docs/robot-checks.md, "The ALOHA arms", has its
table and a picture).
"""

from __future__ import annotations

import math

from .model import BasePose

#: the left arm's base per task (the right arm's: BasePose.mirrored()); yaw pi/2 = reaching along +y
PLACEMENTS: dict[str, BasePose] = {
    "pouring": BasePose(-0.25, -0.10, 0.0, math.pi / 2),
    "trash_in_bin": BasePose(-0.25, -0.10, 0.0, math.pi / 2),
    "paper_in_case": BasePose(-0.25, -0.10, 0.0, math.pi / 2),
    "mix_bowl": BasePose(-0.25, -0.10, 0.0, math.pi / 2),
    "open_container": BasePose(-0.25, -0.10, 0.0, math.pi / 2),
    "empty_vase": BasePose(-0.25, -0.10, 0.0, math.pi / 2),
}
DEFAULT = BasePose(-0.25, -0.10, 0.0, math.pi / 2)


def bases_for(task_name: str) -> tuple[BasePose, BasePose]:
    """(left, right) base poses at a task's table (a task the table does not list: the default)."""
    left = PLACEMENTS.get(task_name, DEFAULT)
    return left, left.mirrored()
