"""The report's sections and every report view: each section of reports/REPORT.md declared once
(demoforge.schemas.report_section), with the SQL of the DuckDB view it shows, in report order.

Each view becomes a view in `warehouse/catalog.duckdb` (``SELECT * FROM report_takes``), and the report
(`make evaluate`, demoforge.report) is written from these same views, so what a person reads in
reports/REPORT.md and what they query in SQL are one and the same. The sections of the tables whose
contracts carry their report SQL are declared there, beside it (table3.py, closed_loop.py,
variations.py, ingested_demos.py); the others here. ``REPORT`` lists them all in report order,
``SQL_ONLY`` the views for SQL alone; ``REPORT_VIEWS`` (every report view's SQL: the catalog's) and
``SHOWN_VIEWS`` follow from the two.

Adding a report table takes three files: its contract (schemas/<table>.py), its stage (tasks/), and its
section declared here and placed in ``REPORT`` (or declared beside its contract); the report writer
(demoforge.report) needs no change.
"""

from __future__ import annotations

from demoforge.schemas.closed_loop import REPORT_DATA_SCALING
from demoforge.schemas.ingested_demos import REPORT_INGESTED_DEMOS
from demoforge.schemas.report_section import FigureSection, PerDataset, ReportEntry, ReportSection, SqlView
from demoforge.schemas.table3 import REPORT_TABLE3_FAILURES, REPORT_TABLE3_GRID, REPORT_TABLE3_INTERVALS
from demoforge.schemas.variations import REPORT_TABLE4, REPORT_TABLE4_FAILURES


# Views over the tables that are not report sections (the report views may use them).
TABLE_VIEWS: dict[str, str] = {
    # One robot check per episode and robot: an episode that several runs (selections) checked with the
    # same robot keeps the row of the whole-database run (`all`) if there is one, else of the first
    # selection by name.
    "sim_outcomes": """
        SELECT * EXCLUDE (pick) FROM (
            SELECT *, row_number() OVER (PARTITION BY task, take, robot, gripper, episode_id
                                         ORDER BY selection <> 'all', selection, chunk) AS pick
            FROM sim_results)
        WHERE pick = 1
    """,
}


def _wavg(metric: str, weight: str) -> str:
    """Frame-weighted mean over takes, skipping NaN (the thesis's eq. 4 pooled over all frames)."""
    ok = f"NOT isnan({metric}) AND {weight} > 0"
    return f"sum({metric} * {weight}) FILTER (WHERE {ok}) / sum({weight}) FILTER (WHERE {ok})"


def _nanavg(expr: str) -> str:
    """The mean over rows where ``expr`` is a number (NaN: nothing could be measured)."""
    return f"avg({expr}) FILTER (WHERE NOT isnan({expr}))"


# ------------------------------------------------------------------------------- the synthetic takes

SYNTHETIC_TAKES = FigureSection(
    "The synthetic demonstrations", figure="synthetic_takes",
    intro=("One frame per task at its first grasp, rendered by MuJoCo from the head camera (640x480, fx = fy = "
           "570.3422), with the ground-truth hand skeletons (filled dots: joint visible in the depth test, "
           "hollow: occluded) and the 11 object keypoints (crosses)."),
)

# One line per take: what was generated and whether its scripted demo passes in physics.
TAKES = ReportSection(
    "report_takes", "Takes",
    computed_from=("takes",),
    intro=("Every generated take; `replay_success` is the task's success predicate after replaying the scripted "
           "demonstration in MuJoCo physics."),
    sql="""
        SELECT task, take, mirror, seed, n_frames, round(duration_s, 2) AS duration_s,
               round(visible_left, 3) AS visible_left, round(visible_right, 3) AS visible_right,
               replay_success, replay_reason,
               round(generate_seconds, 1) AS generate_s,
               round(n_frames / generate_seconds, 1) AS frames_per_s,
               round(replay_seconds, 2) AS replay_s
        FROM takes ORDER BY task, mirror, seed
    """,
)

# Physics replay success of the scripted demonstrations, per task.
REPLAY_BY_TASK = ReportSection(
    "report_replay_by_task", "Scripted demonstrations in physics, per task",
    computed_from=("takes",),
    sql="""
        SELECT task, count(*) AS takes,
               count(*) FILTER (WHERE replay_success) AS succeeded,
               round(avg(CASE WHEN replay_success THEN 1.0 ELSE 0.0 END), 3) AS success_rate
        FROM takes WHERE replay_success IS NOT NULL GROUP BY task ORDER BY task
    """,
)

# Ground-truth joint visibility (depth test) per task and hand.
VISIBILITY = ReportSection(
    "report_visibility", "Ground-truth joint visibility",
    computed_from=("gt_hand_joints",),
    intro="Mean fraction of the 21 joints that pass the depth test, per task and hand.",
    sql="""
        SELECT task, hand, count(*) AS frames,
               round(avg(len(list_filter(visible::BOOLEAN[], lambda v: v)) / 21.0), 3) AS mean_visible_fraction,
               round(avg(CASE WHEN present THEN 1.0 ELSE 0.0 END), 3) AS in_view_fraction
        FROM gt_hand_joints GROUP BY task, hand ORDER BY task, hand
    """,
)

# ------------------------------------------------------------------------------------------- the ingest

# The same, averaged per task and detector (the goals: aligned within 5 mm of PA-MPJPE, auto open/close
# >= 95 %); a hand a detector never found (NaN errors) is counted in hands_without_pose, not averaged.
INGEST_BY_TASK = ReportSection(
    "report_ingest_by_task", "Ingest accuracy per task and detector",
    computed_from=("ingest_metrics",),
    stamp="detectors",
    intro=("Hand keypoints from each detector, corrected with the rendered depth, then mapped to grippers; the "
           "`detector` column puts them side by side. `simulated`: the HaMeR-like error model applied to the "
           "ground truth (not a real detector; every later section builds on its ingest); `mediapipe`: the real "
           "MediaPipe hand landmarker run on the rendered frames (video mode, with the hand tracker). Goals: "
           "aligned MPJPE within 5 mm of PA-MPJPE; automatic open/close >= 95 %."),
    sql=f"""
        SELECT task, detector, count(*) AS hands,
               count(*) FILTER (WHERE isnan(gripper_position_error_mm)) AS hands_without_pose,
               round(avg(detected_fraction), 3) AS detected_fraction,
               round(1000 * {_nanavg("mpjpe_aligned_m")}, 1) AS mpjpe_aligned_mm,
               round(1000 * {_nanavg("pa_mpjpe_m")}, 1) AS pa_mpjpe_mm,
               round(1000 * {_nanavg("mpjpe_aligned_m - pa_mpjpe_m")}, 1) AS aligned_minus_pa_mm,
               round({_nanavg("gripper_position_error_mm")}, 1) AS gripper_pos_mm,
               round({_nanavg("gripper_orientation_error_deg")}, 1) AS gripper_rot_deg,
               round(avg(open_close_acc_auto), 3) AS mean_oc_auto,
               round(min(open_close_acc_threshold), 3) AS worst_oc_threshold,
               round(min(open_close_acc_auto), 3) AS worst_oc_auto
        FROM ingest_metrics GROUP BY task, detector
        ORDER BY task, CASE detector WHEN 'simulated' THEN 0 ELSE 1 END, detector
    """,
)

# Ingest accuracy against the synthetic ground truth (thesis Table 1/2 quantities + gripper).
INGEST_ACCURACY = ReportSection(
    "report_ingest_accuracy", "Ingest accuracy per take and hand",
    computed_from=("ingest_metrics",),
    stamp="detectors",
    intro=("MPJPE before (m) and after depth alignment (mm), PA-MPJPE, 2D error and PCK, gripper "
           "position/rotation/approach-axis error, open/close accuracy of the thesis's fixed threshold (0.06 "
           "m), the automatic per-take method and the labelled ranges, and the left/right swaps injected by the "
           "detector and repaired."),
    sql="""
        SELECT task, take, hand, detector,
               round(mpjpe_raw_m, 3) AS mpjpe_raw_m,
               round(1000 * mpjpe_aligned_m, 1) AS mpjpe_aligned_mm,
               round(1000 * pa_mpjpe_m, 1) AS pa_mpjpe_mm,
               round(mpjpe_2d_px, 1) AS mpjpe_2d_px, round(pck_005, 3) AS pck_005, round(pck_015, 3) AS pck_015,
               round(gripper_position_error_mm, 1) AS gripper_pos_mm,
               round(gripper_orientation_error_deg, 1) AS gripper_rot_deg,
               round(approach_axis_error_deg, 1) AS approach_deg,
               round(open_close_acc_threshold, 3) AS oc_threshold, round(open_close_acc_auto, 3) AS oc_auto,
               round(open_close_acc_manual, 3) AS oc_manual,
               swap_frames_injected AS swaps_injected, swap_frames_repaired_correctly AS swaps_repaired
        FROM ingest_metrics ORDER BY task, take, hand, CASE detector WHEN 'simulated' THEN 0 ELSE 1 END, detector
    """,
)

# ------------------------------------------------------------------------------------ hand keypoints

# Thesis Table 1: MPJPE / PA-MPJPE per hand, raw and depth-aligned (m), pooled over frames.
TABLE1 = ReportSection(
    "report_table1", "Table 1: MPJPE and PA-MPJPE (m)",
    computed_from=("keypoint_metrics",),
    stamp="dataset",
    sql=f"""
        SELECT dataset, detector,
               CASE hand WHEN 'left' THEN 'Left Hand' ELSE 'Right Hand' END AS method, hand, false AS aligned,
               round({_wavg("mpjpe_m", "n_eval")}, 4) AS mpjpe_m,
               round({_wavg("pa_mpjpe_m", "n_eval")}, 4) AS pa_mpjpe_m,
               count(*) AS takes
        FROM keypoint_metrics GROUP BY dataset, detector, hand
        UNION ALL
        SELECT dataset, detector,
               CASE hand WHEN 'left' THEN 'Left Hand (Aligned)' ELSE 'Right Hand (Aligned)' END, hand, true,
               round({_wavg("mpjpe_aligned_m", "n_eval_aligned")}, 4),
               round({_wavg("pa_mpjpe_aligned_m", "n_eval_aligned")}, 4),
               count(*)
        FROM keypoint_metrics GROUP BY dataset, detector, hand
        ORDER BY dataset, detector, hand, aligned
    """,
)

# Thesis Table 2: 2D MPJPE (px) and PCK@0.05 / PCK@0.15 per hand (the 3D prediction projected with K).
TABLE2 = ReportSection(
    "report_table2", "Table 2: 2D MPJPE (px) and PCK",
    computed_from=("keypoint_metrics",),
    stamp="dataset",
    sql=f"""
        SELECT dataset, detector, CASE hand WHEN 'left' THEN 'Left Hand' ELSE 'Right Hand' END AS hand,
               round({_wavg("mpjpe_2d_px", "n_eval")}, 2) AS mpjpe_2d_px,
               round({_wavg("pck05", "n_eval")}, 4) AS pck05,
               round({_wavg("pck15", "n_eval")}, 4) AS pck15,
               round({_wavg("mpjpe_2d_pred_px", "n_eval")}, 2) AS detector_2d_mpjpe_px,
               round({_wavg("pck05_pred", "n_eval")}, 4) AS detector_2d_pck05,
               count(*) AS takes
        FROM keypoint_metrics GROUP BY dataset, detector, hand ORDER BY dataset, detector, hand
    """,
)

# Thesis Appendix B: every take, both hands.
APPENDIX_B = ReportSection(
    "report_appendix_b", "Appendix B: per take",
    computed_from=("keypoint_metrics",),
    stamp="dataset",
    sql="""
        SELECT l.dataset, l.detector, l.take, l.object,
               round(l.mpjpe_m, 4) AS mpjpe_left, round(l.mpjpe_aligned_m, 4) AS mpjpe_left_aligned,
               round(r.mpjpe_m, 4) AS mpjpe_right, round(r.mpjpe_aligned_m, 4) AS mpjpe_right_aligned,
               round(l.pa_mpjpe_m, 4) AS pa_mpjpe_left, round(r.pa_mpjpe_m, 4) AS pa_mpjpe_right,
               round(l.mpjpe_2d_px, 2) AS mpjpe_2d_left_px, round(r.mpjpe_2d_px, 2) AS mpjpe_2d_right_px,
               round(l.pck05, 4) AS pck05_l, round(l.pck15, 4) AS pck15_l,
               round(r.pck05, 4) AS pck05_r, round(r.pck15, 4) AS pck15_r
        FROM keypoint_metrics l JOIN keypoint_metrics r
          ON l.dataset = r.dataset AND l.detector = r.detector AND l.take = r.take
         AND l.hand = 'left' AND r.hand = 'right'
        ORDER BY l.dataset, l.detector, l.take
    """,
)

# Thesis Tables 1, 2 and Appendix B once per dataset of keypoint_metrics, the detectors side by side.
KEYPOINTS = PerDataset(
    "keypoint_metrics", (TABLE1, TABLE2, APPENDIX_B), figure="keypoints",
    labels={"arctic": "ARCTIC (egocentric view; anchor depth from ground truth: ARCTIC has no depth camera)",
            "synthetic": "synthetic renders (depth alignment on the rendered depth)"},
)

# The thesis's big vs small objects (Figure 21), both hands pooled.
BIG_VS_SMALL = SqlView(
    "report_big_vs_small",
    computed_from=("keypoint_metrics",),
    why=("The report draws it per detector (keypoints_big_vs_small_<dataset>_<detector>.png, from "
         "keypoint_metrics) after the dataset's tables instead of showing the table."),
    sql=f"""
        SELECT dataset, detector, size_group, count(DISTINCT take) AS takes,
               round({_wavg("mpjpe_aligned_m", "n_eval_aligned")}, 4) AS mpjpe_aligned_m,
               round({_wavg("pa_mpjpe_m", "n_eval")}, 4) AS pa_mpjpe_m,
               round({_wavg("pck05", "n_eval")}, 4) AS pck05,
               round({_wavg("pck15", "n_eval")}, 4) AS pck15
        FROM keypoint_metrics WHERE size_group <> '' GROUP BY dataset, detector, size_group
        ORDER BY dataset, detector, size_group
    """,
)

# A real detector on labelled real photos.
REAL_PHOTOS = ReportSection(
    "report_real_photos", "A real detector on labelled real photos",
    computed_from=("real_photo_metrics",),
    stamp="real_photos",
    intro=("MediaPipe on FreiHAND, OneHand10K, CMU Panoptic and COCO-WholeBody samples: PCK by the labelled box "
           "size over the hands it found; `pck20_all_hands` counts the joints of missed hands as wrong."),
    sql="""
        SELECT detector, dataset, images, hands, detected, round(detection_rate, 3) AS detection_rate,
               handedness_known, round(handedness_acc, 3) AS handedness_acc,
               round(mpjpe_2d_px, 1) AS mpjpe_2d_px, round(pck05, 3) AS pck05, round(pck15, 3) AS pck15,
               round(pck20, 3) AS pck20, round(pck20_all, 3) AS pck20_all_hands
        FROM real_photo_metrics
        ORDER BY detector, CASE WHEN dataset = 'all' THEN 1 ELSE 0 END, dataset
    """,
)

# ----------------------------------------------------------------------- segmentation and augmentation

# Segment boundaries found on the ingested takes against the scripted ones.
SEGMENTATION = ReportSection(
    "report_segmentation", "Segmentation against the scripted boundaries",
    computed_from=("segmentation_metrics",),
    intro="Boundaries matched within 30 frames; errors in frames (30 fps).",
    sql="""
        SELECT task, take, arm, boundaries_true, boundaries_found, matched,
               round(mean_error_frames, 1) AS mean_error_frames, max_error_frames
        FROM segmentation_metrics ORDER BY task, take, arm
    """,
)

# Validity of the augmented episodes per task and kind, with the reasons for rejections.
AUGMENTATION = ReportSection(
    "report_augmentation", "Augmented episodes",
    computed_from=("episodes",),
    intro=("The task databases: episode 0 is the ingested demonstration, then translated and "
           "mirrored-and-translated episodes; invalid ones are kept and flagged with the reason."),
    sql="""
        SELECT task, take, kind, count(*) AS episodes, count(*) FILTER (WHERE valid) AS valid,
               round(avg(CASE WHEN valid THEN 1.0 ELSE 0.0 END), 3) AS valid_rate,
               count(*) FILTER (WHERE reject_reason = 'left_workspace') AS left_workspace,
               count(*) FILTER (WHERE reject_reason = 'grippers_too_close') AS grippers_too_close,
               count(*) FILTER (WHERE reject_reason = 'objects_overlap') AS objects_overlap,
               round(min(min_gripper_distance), 3) AS min_gripper_distance_m
        FROM episodes GROUP BY task, take, kind ORDER BY task, take, kind
    """,
)

# ------------------------------------------------------------------------------------- LLM and policy

# Thesis Table 3: successes per take and strategy (of the trials), with the average rate.
LLM_TRIALS = SqlView(
    "report_table3",
    computed_from=("llm_trials",),
    why=("`demoforge llm-eval`'s prompting trials on placement scenes: the report shows the Table 3 grid in the "
         "thesis's layout instead (report_table3_grid)."),
    sql="""
        SELECT task, take, strategy, backend, model, count(*) AS trials,
               count(*) FILTER (WHERE success) AS successes,
               round(avg(CASE WHEN success THEN 1.0 ELSE 0.0 END), 3) AS success_rate,
               count(*) FILTER (WHERE parse_status NOT IN ('ok', 'truncated')) AS unparsable,
               round(avg(prompt_tokens), 0) AS mean_prompt_tokens, round(avg(answer_tokens), 0) AS mean_answer_tokens,
               round(avg(latency_s), 2) AS mean_latency_s
        FROM llm_trials GROUP BY task, take, strategy, backend, model
        ORDER BY task, take, CASE strategy WHEN 'single' THEN 0 WHEN 'random' THEN 1 WHEN 'retrieval' THEN 2
                                   WHEN 'replay_top1' THEN 3 ELSE 4 END
    """,
)

# Why trials failed, per strategy.
LLM_FAILURES = SqlView(
    "report_llm_failures",
    computed_from=("llm_trials",),
    why=("Why `demoforge llm-eval`'s trials failed: the report shows the Table 3 grid's failures instead "
         "(report_table3_failures)."),
    sql="""
        SELECT task, strategy, backend, CASE WHEN success THEN 'success' ELSE failure_reason END AS outcome,
               count(*) AS trials
        FROM llm_trials GROUP BY ALL ORDER BY task, strategy, trials DESC, backend, outcome
    """,
)

# The learned keypoint policy: success per scene kind, inference latency, the checkpoint's validation errors.
POLICY = ReportSection(
    "report_policy", "Learned keypoint policy",
    computed_from=("policy_trials", "policy_checkpoints"),
    stamp="policy",
    intro=("A small Transformer trained on the task's augmented episodes (`demoforge train-policy`), judged by "
           "the same MuJoCo check: in_distribution = the prompting evaluation's query scenes (also the `policy` "
           "row of Table 3), mirrored = their mirror images, out_of_distribution = the demo's placement shifted "
           "beyond the augmentation's translation range, held_out = validation placements of the database. "
           "Latency: one forward pass per scene on the CPU (Table 3 has the LLM's). The query scenes move each "
           "object independently and turn it, which the default database (both objects translated together, no "
           "yaw) does not cover; held_out shows the policy on placements the database does cover. Predictions "
           "are uniform waypoints upsampled to 30 Hz: at 20 most of a database's own successful episodes fail "
           "the check once resampled (the LLM prompts write keyframes instead), at 40 they pass, so the default "
           "policy uses 40."),
    sql="""
        SELECT t.task, t.checkpoint_id, c.n_waypoints, t.scene_kind, count(*) AS trials,
               count(*) FILTER (WHERE t.success) AS successes,
               round(avg(CASE WHEN t.success THEN 1.0 ELSE 0.0 END), 3) AS success_rate,
               count(*) FILTER (WHERE t.in_augmented_region) AS in_aug_region,
               round(median(t.latency_ms), 2) AS median_latency_ms,
               any_value(c.epochs_run) AS epochs, round(any_value(c.train_seconds), 0) AS train_s,
               any_value(c.threads) AS threads, round(any_value(c.val_pos_err_mm), 1) AS val_pos_mm,
               round(any_value(c.val_rot_err_deg), 2) AS val_rot_deg
        FROM policy_trials t JOIN policy_checkpoints c USING (task, take, checkpoint_id)
        GROUP BY t.task, t.checkpoint_id, c.n_waypoints, t.scene_kind
        ORDER BY t.task, t.checkpoint_id, CASE t.scene_kind WHEN 'in_distribution' THEN 0 WHEN 'mirrored' THEN 1
                                                        WHEN 'out_of_distribution' THEN 2 ELSE 3 END
    """,
)

POLICY_FAILURES = ReportSection(
    "report_policy_failures", "Why policy trials failed",
    computed_from=("policy_trials",),
    stamp="policy",
    sql="""
        SELECT task, checkpoint_id, scene_kind, CASE WHEN success THEN 'success' ELSE failure_reason END AS outcome,
               count(*) AS trials
        FROM policy_trials GROUP BY ALL ORDER BY task, checkpoint_id, scene_kind, trials DESC, outcome
    """,
)

# ---------------------------------------------------------------------------------------- robot checks

# The robots side by side, per task: success, reachable fraction, the arms' IK residual and time-scale
# (executed over demonstrated duration) and the failure classes with counts.
SIM_ROBOTS = ReportSection(
    "report_sim_robots", "The robots side by side",
    computed_from=("sim_outcomes",),
    stamp="robots",
    intro=("The same sample of each task's episodes (the original demonstration first) executed by each robot "
           "with real contacts, friction and gravity: `grippers`, two free-floating Robotiq 2F-140-class "
           "grippers (every pose reachable, only the hands collide); `aloha`, two ViperX 300 6-DOF arms driven "
           "in joint space from inverse kinematics (mink), with ALOHA's own fingers (`gripper` aloha: 69 mm "
           "between the pads) or the 2F-140 on the wrists. `reachable_fraction`: the episodes whose every step "
           "the arms reach within 1 cm and 5 degrees; `failures`: each failure class with its count "
           "(`unreachable`, `joint_limit`: a pose beyond reach or a joint at its range's end or speed limit; "
           "`link_collision`: an arm link on the table, an object or the other arm; `wider_than_stroke`: an "
           "object the hand cannot open around). docs/robot-checks.md says where the arms stand and why they "
           "fail."),
    sql="""
        WITH f AS (
            SELECT task, robot, gripper, string_agg(failure || ' ' || n, ', ' ORDER BY n DESC, failure) AS failures
            FROM (SELECT task, robot, gripper, failure, count(*) AS n FROM sim_outcomes WHERE NOT success
                  GROUP BY ALL)
            GROUP BY ALL)
        SELECT task, robot, gripper, count(*) AS episodes,
               round(avg(CASE WHEN success THEN 1.0 ELSE 0.0 END), 3) AS success_rate,
               round(avg(CASE WHEN reachable THEN 1.0 WHEN NOT reachable THEN 0.0 END), 3) AS reachable_fraction,
               round(1000 * median(ik_position_error_m), 1) AS median_ik_error_mm,
               round(median(ik_rotation_error_deg), 1) AS median_ik_error_deg,
               round(median(time_scale), 2) AS median_time_scale, round(max(time_scale), 2) AS max_time_scale,
               any_value(f.failures) AS failures
        FROM sim_outcomes LEFT JOIN f USING (task, robot, gripper)
        GROUP BY task, robot, gripper ORDER BY task, robot <> 'grippers', robot, gripper
    """,
)

# Each task database's screening for the arms per take and robot: the share screened in, why the others
# were not, and how the physics check judged the screened-in and screened-out episodes it also ran.
SCREENING = ReportSection(
    "report_screening", "The databases screened for the arms",
    computed_from=("episode_screening", "sim_outcomes"),
    intro=("Every episode of each task's database checked for the arms without physics (`demoforge screen`; "
           "lib/sim/robots/aloha/screening.py): reach, joint ranges, the grasps the planner would choose, the "
           "fingers above the table and the forearms apart, with the arms' closed-form inverse kinematics. "
           "Retrieval, `knn_blend`, the policy and the exports for an arm robot use only the screened-in "
           "episodes. `physics_passes_screened_in` / `_screened_out`: of the episodes the physics check also "
           "ran with that robot, the share it passed, among those the screening let through and those it did "
           "not."),
    sql="""
        WITH r AS (
            SELECT task, take, robot, string_agg(reason || ' ' || n, ', ' ORDER BY n DESC, reason) AS reasons
            FROM (SELECT task, take, robot, reason, count(*) AS n FROM episode_screening WHERE NOT executable
                  GROUP BY ALL)
            GROUP BY ALL),
        checked AS (  -- the screened episodes the physics check also ran, with the same robot and hand
            SELECT s.task, s.take, s.robot, s.executable, o.success
            FROM episode_screening s JOIN sim_outcomes o
              ON o.task = s.task AND o.take = s.take AND o.episode_id = s.episode_id
             AND o.robot = split_part(s.robot, '+', 1) AND o.gripper = s.gripper)
        SELECT s.task, s.take, s.robot, count(*) AS episodes, count(*) FILTER (WHERE executable) AS screened_in,
               round(avg(CASE WHEN executable THEN 1.0 ELSE 0.0 END), 3) AS screened_share,
               (SELECT count(*) FROM checked c WHERE c.task = s.task AND c.take = s.take AND c.robot = s.robot
                  AND c.executable) AS simulated_screened_in,
               (SELECT round(avg(CASE WHEN c.success THEN 1.0 ELSE 0.0 END), 3) FROM checked c
                WHERE c.task = s.task AND c.take = s.take AND c.robot = s.robot AND c.executable) AS physics_passes_screened_in,
               (SELECT round(avg(CASE WHEN c.success THEN 1.0 ELSE 0.0 END), 3) FROM checked c
                WHERE c.task = s.task AND c.take = s.take AND c.robot = s.robot AND NOT c.executable) AS physics_passes_screened_out,
               any_value(r.reasons) AS screened_out_reasons
        FROM episode_screening s LEFT JOIN r USING (task, take, robot)
        GROUP BY s.task, s.take, s.robot ORDER BY s.task, s.take, s.robot
    """,
)

# Robot success checks of the augmented episodes, per task, robot and kind; `reachable_fraction`:
# the share whose every step the arms' inverse kinematics reaches (empty for the floating grippers).
SIM = ReportSection(
    "report_sim", "Robot success checks in MuJoCo physics, per episode kind",
    computed_from=("sim_outcomes",),
    stamp="robots",
    intro="The robots replay what the ingest recovered from the video, not the script.",
    sql="""
        SELECT task, take, robot, gripper, kind, count(*) AS episodes, count(*) FILTER (WHERE success) AS successes,
               round(avg(CASE WHEN success THEN 1.0 ELSE 0.0 END), 3) AS success_rate,
               round(avg(CASE WHEN reachable THEN 1.0 WHEN NOT reachable THEN 0.0 END), 3) AS reachable_fraction,
               round(avg(wall_s), 2) AS mean_wall_s
        FROM sim_outcomes GROUP BY task, take, robot, gripper, kind
        ORDER BY task, take, robot <> 'grippers', robot, gripper, kind
    """,
)

# Why episodes failed in physics.
SIM_FAILURES = ReportSection(
    "report_sim_failures", "Why episodes failed in physics",
    computed_from=("sim_outcomes",),
    stamp="robots",
    sql="""
        SELECT task, robot, gripper, CASE WHEN success THEN 'success' ELSE failure END AS outcome, count(*) AS episodes
        FROM sim_outcomes GROUP BY task, robot, gripper, outcome
        ORDER BY task, robot <> 'grippers', robot, gripper, episodes DESC, outcome
    """,
)

# Outcome stability per task and stability run: how many episodes keep their verdict when the
# scene is shifted by a fraction of a millimetre (always / never succeed) and how many flip. Repeats
# are counted once each: the same run re-chunked leaves older chunk files holding the same rows.
SIM_STABILITY = ReportSection(
    "report_sim_stability", "How stable the robot check's verdicts are",
    computed_from=("sim_stability",),
    intro=("Episodes of the sample executed again with the whole scene (objects and gripper poses) shifted "
           "rigidly along the table by about 0.1 mm: physically nothing changes, only the simulation's "
           "rounding. `flipping` episodes change outcome under that shift: their single verdict is decided by "
           "numerical chaos, and `success_rate` over all repeats estimates their success as a probability "
           "(`demoforge stability` for more episodes and repeats)."),
    sql="""
        SELECT task, take, robot, gripper, run, count(*) AS episodes, max(repeats) AS repeats,
               count(*) FILTER (WHERE ok = repeats) AS always_succeed,
               count(*) FILTER (WHERE ok = 0) AS never_succeed,
               count(*) FILTER (WHERE ok > 0 AND ok < repeats) AS flipping,
               round(avg(first_ok), 3) AS first_run_success_rate,
               round(sum(ok) / sum(repeats), 3) AS success_rate
        FROM (SELECT task, take, robot, gripper, run, episode_id, count(DISTINCT repeat) AS repeats,
                     count(DISTINCT repeat) FILTER (WHERE success) AS ok,
                     max(CASE WHEN repeat = 0 AND success THEN 1.0 ELSE 0.0 END) AS first_ok
              FROM sim_stability GROUP BY ALL)
        GROUP BY task, take, robot, gripper, run ORDER BY task, take, robot <> 'grippers', robot, gripper, run
    """,
)

EPISODE_DATABASES = FigureSection("Episode databases in pictures", figure="episode_databases")

# Latest benchmark run, one row per case.
BENCHMARKS = ReportSection(
    "report_benchmarks", "Benchmarks (latest `make bench` run)",
    computed_from=("benchmarks",),
    stamp="machine",
    if_empty="_No benchmark run in this warehouse yet: `make bench`._",
    empty_title="Benchmarks",
    sql="""
        SELECT stage, case_name, size, unit, round(seconds, 4) AS seconds,
               round(baseline_seconds, 4) AS baseline_seconds, round(ratio, 1) AS ratio,
               round(items_per_second, 0) AS items_per_second, baseline, machine, git_commit
        FROM benchmarks
        WHERE run_id = (SELECT max(run_id) FROM benchmarks)
        ORDER BY stage, case_name
    """,
)

# ------------------------------------------------------------------------------------------ the report

#: The report's sections, in report order.
REPORT: tuple[ReportEntry, ...] = (
    SYNTHETIC_TAKES, TAKES, REPLAY_BY_TASK, VISIBILITY, INGEST_BY_TASK, REPORT_INGESTED_DEMOS, INGEST_ACCURACY,
    KEYPOINTS, REAL_PHOTOS, SEGMENTATION, AUGMENTATION,
    REPORT_TABLE3_GRID, REPORT_TABLE3_INTERVALS, REPORT_TABLE3_FAILURES, POLICY, POLICY_FAILURES, REPORT_DATA_SCALING,
    REPORT_TABLE4, REPORT_TABLE4_FAILURES, SIM_ROBOTS, SCREENING, SIM, SIM_FAILURES, SIM_STABILITY,
    EPISODE_DATABASES, BENCHMARKS,
)

#: The report views for SQL only.
SQL_ONLY: tuple[SqlView, ...] = (BIG_VS_SMALL, LLM_TRIALS, LLM_FAILURES)


def shown_sections(entries: tuple[ReportEntry, ...] = REPORT) -> list[ReportSection]:
    """Every section with a view among ``entries``, in report order (a PerDataset's sections in its place)."""
    out: list[ReportSection] = []
    for e in entries:
        out += list(e.sections) if isinstance(e, PerDataset) else [e] if isinstance(e, ReportSection) else []
    return out


def _views(declared: list[ReportSection | SqlView]) -> dict[str, str]:
    views: dict[str, str] = {}
    for d in declared:
        if d.view in views:
            raise ValueError(f"report view {d.view!r} is declared twice")
        views[d.view] = d.sql
    return views


#: Every report view's SQL: the shown sections' and the SQL-only views'.
REPORT_VIEWS: dict[str, str] = _views([*shown_sections(), *SQL_ONLY])
#: The views the report shows.
SHOWN_VIEWS = frozenset(s.view for s in shown_sections())
