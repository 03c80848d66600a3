"""The `episode_screening` table: whether a robot's arms can execute each episode of a task database,
kinematically (lib/sim/robots/aloha/screening.py: reach, joint ranges, the grasps the planner would choose,
the fingers above the table, the two forearms apart), without physics. One row per episode and robot; join
it with `sim_results` on (task, take, episode_id, gripper) and `robot = 'aloha'` there to see how often the
physics check passes what the screening lets through."""

import pyarrow as pa

from demoforge.schemas.core import Column, table

EPISODE_SCREENING = table(
    "episode_screening",
    version=1,
    doc=("One row per episode of a task database and robot: whether the robot's arms can execute the episode "
         "kinematically, by the same windows, grasps and rules its motion planner uses, screened for all episodes "
         "at once with the arms' closed-form inverse kinematics (no physics, no collision model but the two "
         "forearms' distance)."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
        Column("episode_id", pa.int64(), "Episode (see `episodes`)."),
        Column("robot", pa.string(), "The robot screened, by its label: `aloha` (the ViperX arms with ALOHA's fingers) "
               "or `aloha+2f140` (with the Robotiq 2F-140)."),
        Column("gripper", pa.string(), "Its hands: `aloha` or `2f140` (as in `sim_results`)."),
        Column("executable", pa.bool_(), "Both arms can follow their windows (some grasp meets every rule at every "
               "sampled step) and their forearms stay apart."),
        Column("reason", pa.string(), "Empty when executable, else the first cause (by step): `unreachable` (a pose "
               "beyond the arm's reach), `wrist_in_table` / `fingers_in_table` (the wrist or the fingertips would "
               "have to go below the table top), `joint_limit` (a joint within 0.05 rad of its range's end), "
               "`branch_jump` (a joint would jump between two sampled steps, by 1 rad, or by 0.2 rad per step between "
               "them if less: a wrist roll through its range's end or its singularity), `forearms_meet` (the two "
               "arms' forearms or hands closer than 0.12 m, or than the demonstrated hands less 1 cm, and no other "
               "grasp of either arm keeps them apart)."),
        Column("min_margin_rad", pa.float64(), "The smallest distance of a joint to its range's end along the arms' "
               "screened joint paths over their windows, rad (negative: outside; null: no arm moves).", nullable=True),
        Column("turn_left_rad", pa.float64(), "The left arm's grasp turn about its held object's axis at its window's "
               "start, rad (0: the demonstrated grasp; null: the arm cannot follow its window or has none).",
               nullable=True),
        Column("turn_right_rad", pa.float64(), "The same for the right arm, rad.", nullable=True),
        Column("screen_version", pa.string(), "Version of the screening's rules (lib/sim/robots/aloha/screening.py "
               "SCREEN_VERSION)."),
    ],
    partition_by=("task", "take", "gripper"),
)
