"""The `ingested_demo_checks` table: each take's ingested demonstration executed by the robot in MuJoCo,
per hand detector, so the detectors' ingests are judged by what matters in the end (does the robot
succeed), side by side (demoforge.flows.ingest.ingest_side_by_side)."""

import pyarrow as pa

from demoforge.schemas.core import Column, table
from demoforge.schemas.report_section import ReportSection

INGESTED_DEMO_CHECKS = table(
    "ingested_demo_checks",
    version=1,
    doc=("Per take and hand detector: the gripper trajectory the ingest recovered (undetected frames held at "
         "the nearest detected pose, as the episode database's episode 0) executed by the dual-gripper robot "
         "with the take's object keypoints in MuJoCo physics, with why it failed. A detector whose ingest "
         "failed has a row with status `ingest_failed` and the reason."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Take identifier."),
        Column("detector", pa.string(), "Hand detector of the ingest (`simulated` reads the ground truth plus noise; `mediapipe` is a real detector)."),
        Column("status", pa.string(), "`executed`, `no_trajectory` (a hand's gripper pose is never valid: nothing to execute) or `ingest_failed` (the ingest stopped; see `detail`)."),
        Column("success", pa.bool_(), "The robot executed the demonstration and the task's success predicate held (false unless `executed`)."),
        Column("failure", pa.string(), "Empty on success, else the robot check's failure (`missed_grasp`, `object_dropped`, ...) or the status."),
        Column("detail", pa.string(), "The failure in words."),
        Column("frames", pa.int32(), "Frames of the trajectory (0 when nothing was executed)."),
        Column("valid_left", pa.float64(), "Fraction of frames with a valid left gripper pose (detected, filled or frozen).", nullable=True),
        Column("valid_right", pa.float64(), "Fraction of frames with a valid right gripper pose.", nullable=True),
        Column("trusted_hands", pa.int32(), "Hands (0-2) the `hand_presence` table trusts.", nullable=True),
        Column("wall_s", pa.float64(), "Wall time of the robot check, s."),
    ],
    partition_by=("detector", "task", "take"),
)

# Robot success on ingested demonstrations per task and detector (the report's side-by-side rows).
REPORT_INGESTED_DEMOS_SQL = """
    SELECT task, detector, count(*) AS takes,
           count(*) FILTER (WHERE status = 'executed') AS executed,
           count(*) FILTER (WHERE success) AS successes,
           round(avg(CASE WHEN success THEN 1.0 ELSE 0.0 END), 3) AS success_rate,
           string_agg(DISTINCT CASE WHEN success THEN NULL ELSE failure END, ', '
                      ORDER BY CASE WHEN success THEN NULL ELSE failure END) AS failures,  -- sorted: the same every run
           round(avg(valid_left), 3) AS valid_left, round(avg(valid_right), 3) AS valid_right
    FROM ingested_demo_checks GROUP BY task, detector
    ORDER BY task, CASE detector WHEN 'simulated' THEN 0 ELSE 1 END, detector
"""

REPORT_INGESTED_DEMOS = ReportSection(
    "report_ingested_demos", "Robot success on the ingested demonstrations, per detector",
    computed_from=("ingested_demo_checks",),
    stamp="detectors",
    intro=("Each take's ingested gripper trajectory (undetected frames held at the nearest detected pose) "
           "executed by the robot in MuJoCo with the take's object keypoints, per detector "
           "(`ingested_demo_checks`; `failures`: why the others failed). Goal: the MediaPipe ingests succeed at "
           "least 90 % as often as the simulated detector's."),
    sql=REPORT_INGESTED_DEMOS_SQL,
)
