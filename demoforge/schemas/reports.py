"""Report tables as named DuckDB views over the warehouse tables.

Each entry becomes a view in `warehouse/catalog.duckdb` (``SELECT * FROM report_takes``), and the
report (`make evaluate`) is written from these same views, so what a person reads in
reports/REPORT.md and what they query in SQL are one and the same.
"""

from demoforge.schemas.closed_loop import REPORT_DATA_SCALING_SQL
from demoforge.schemas.ingested_demos import REPORT_INGESTED_DEMOS_SQL
from demoforge.schemas.table3 import (
    REPORT_TABLE3_FAILURES_SQL, REPORT_TABLE3_GRID_SQL, REPORT_TABLE3_INTERVALS_SQL,
)
from demoforge.schemas.variations import REPORT_TABLE4_FAILURES_SQL, REPORT_TABLE4_SQL

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


REPORT_VIEWS: dict[str, str] = {
    # One line per take: what was generated and whether its scripted demo passes in physics.
    "report_takes": """
        SELECT task, take, mirror, seed, n_frames, round(duration_s, 2) AS duration_s,
               round(visible_left, 3) AS visible_left, round(visible_right, 3) AS visible_right,
               replay_success, replay_reason,
               round(generate_seconds, 1) AS generate_s,
               round(n_frames / generate_seconds, 1) AS frames_per_s,
               round(replay_seconds, 2) AS replay_s
        FROM takes ORDER BY task, mirror, seed
    """,
    # Physics replay success of the scripted demonstrations, per task.
    "report_replay_by_task": """
        SELECT task, count(*) AS takes,
               count(*) FILTER (WHERE replay_success) AS succeeded,
               round(avg(CASE WHEN replay_success THEN 1.0 ELSE 0.0 END), 3) AS success_rate
        FROM takes WHERE replay_success IS NOT NULL GROUP BY task ORDER BY task
    """,
    # Ground-truth joint visibility (depth test) per task and hand.
    "report_visibility": """
        SELECT task, hand, count(*) AS frames,
               round(avg(len(list_filter(visible::BOOLEAN[], lambda v: v)) / 21.0), 3) AS mean_visible_fraction,
               round(avg(CASE WHEN present THEN 1.0 ELSE 0.0 END), 3) AS in_view_fraction
        FROM gt_hand_joints GROUP BY task, hand ORDER BY task, hand
    """,
    # Ingest accuracy against the synthetic ground truth (thesis Table 1/2 quantities + gripper).
    "report_ingest_accuracy": """
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
    # The same, averaged per task and detector (the goals: aligned within 5 mm of PA-MPJPE, auto open/close
    # >= 95 %); a hand a detector never found (NaN errors) is counted in hands_without_pose, not averaged.
    "report_ingest_by_task": f"""
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
    # The robot executing each take's ingested demonstration, per task and hand detector.
    "report_ingested_demos": REPORT_INGESTED_DEMOS_SQL,
    # Segment boundaries found on the ingested takes against the scripted ones.
    "report_segmentation": """
        SELECT task, take, arm, boundaries_true, boundaries_found, matched,
               round(mean_error_frames, 1) AS mean_error_frames, max_error_frames
        FROM segmentation_metrics ORDER BY task, take, arm
    """,
    # Validity of the augmented episodes per task and kind, with the reasons for rejections.
    "report_augmentation": """
        SELECT task, take, kind, count(*) AS episodes, count(*) FILTER (WHERE valid) AS valid,
               round(avg(CASE WHEN valid THEN 1.0 ELSE 0.0 END), 3) AS valid_rate,
               count(*) FILTER (WHERE reject_reason = 'left_workspace') AS left_workspace,
               count(*) FILTER (WHERE reject_reason = 'grippers_too_close') AS grippers_too_close,
               count(*) FILTER (WHERE reject_reason = 'objects_overlap') AS objects_overlap,
               round(min(min_gripper_distance), 3) AS min_gripper_distance_m
        FROM episodes GROUP BY task, take, kind ORDER BY task, take, kind
    """,
    # Thesis Table 1: MPJPE / PA-MPJPE per hand, raw and depth-aligned (m), pooled over frames.
    "report_table1": f"""
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
    # Thesis Table 2: 2D MPJPE (px) and PCK@0.05 / PCK@0.15 per hand (the 3D prediction projected with K).
    "report_table2": f"""
        SELECT dataset, detector, CASE hand WHEN 'left' THEN 'Left Hand' ELSE 'Right Hand' END AS hand,
               round({_wavg("mpjpe_2d_px", "n_eval")}, 2) AS mpjpe_2d_px,
               round({_wavg("pck05", "n_eval")}, 4) AS pck05,
               round({_wavg("pck15", "n_eval")}, 4) AS pck15,
               round({_wavg("mpjpe_2d_pred_px", "n_eval")}, 2) AS detector_2d_mpjpe_px,
               round({_wavg("pck05_pred", "n_eval")}, 4) AS detector_2d_pck05,
               count(*) AS takes
        FROM keypoint_metrics GROUP BY dataset, detector, hand ORDER BY dataset, detector, hand
    """,
    # Thesis Appendix B: every take, both hands.
    "report_appendix_b": """
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
    # The thesis's big vs small objects (Figure 21), both hands pooled.
    "report_big_vs_small": f"""
        SELECT dataset, detector, size_group, count(DISTINCT take) AS takes,
               round({_wavg("mpjpe_aligned_m", "n_eval_aligned")}, 4) AS mpjpe_aligned_m,
               round({_wavg("pa_mpjpe_m", "n_eval")}, 4) AS pa_mpjpe_m,
               round({_wavg("pck05", "n_eval")}, 4) AS pck05,
               round({_wavg("pck15", "n_eval")}, 4) AS pck15
        FROM keypoint_metrics WHERE size_group <> '' GROUP BY dataset, detector, size_group
        ORDER BY dataset, detector, size_group
    """,
    # A real detector on labelled real photos.
    "report_real_photos": """
        SELECT detector, dataset, images, hands, detected, round(detection_rate, 3) AS detection_rate,
               handedness_known, round(handedness_acc, 3) AS handedness_acc,
               round(mpjpe_2d_px, 1) AS mpjpe_2d_px, round(pck05, 3) AS pck05, round(pck15, 3) AS pck15,
               round(pck20, 3) AS pck20, round(pck20_all, 3) AS pck20_all_hands
        FROM real_photo_metrics
        ORDER BY detector, CASE WHEN dataset = 'all' THEN 1 ELSE 0 END, dataset
    """,
    # Thesis Table 3: successes per take and strategy (of the trials), with the average rate.
    "report_table3": """
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
    # Thesis Table 3 in its layout (per protocol: takes x strategies), Wilson intervals, failure reasons.
    "report_table3_grid": REPORT_TABLE3_GRID_SQL,
    "report_table3_intervals": REPORT_TABLE3_INTERVALS_SQL,
    # The data-scaling table: closed-loop policy success against training episodes, beside the baselines.
    "report_data_scaling": REPORT_DATA_SCALING_SQL,
    "report_table3_failures": REPORT_TABLE3_FAILURES_SQL,
    # Why trials failed, per strategy.
    "report_llm_failures": """
        SELECT task, strategy, backend, CASE WHEN success THEN 'success' ELSE failure_reason END AS outcome,
               count(*) AS trials
        FROM llm_trials GROUP BY ALL ORDER BY task, strategy, trials DESC, backend, outcome
    """,
    # Thesis Table 4 analogue: success under simulated scene variations, per task and strategy.
    "report_table4": REPORT_TABLE4_SQL,
    "report_table4_failures": REPORT_TABLE4_FAILURES_SQL,
    # The learned keypoint policy: success per scene kind, inference latency, the checkpoint's validation errors.
    "report_policy": """
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
    "report_policy_failures": """
        SELECT task, checkpoint_id, scene_kind, CASE WHEN success THEN 'success' ELSE failure_reason END AS outcome,
               count(*) AS trials
        FROM policy_trials GROUP BY ALL ORDER BY task, checkpoint_id, scene_kind, trials DESC, outcome
    """,
    # Robot success checks of the augmented episodes, per task, robot and kind; `reachable_fraction`:
    # the share whose every step the arms' inverse kinematics reaches (empty for the floating grippers).
    "report_sim": """
        SELECT task, take, robot, gripper, kind, count(*) AS episodes, count(*) FILTER (WHERE success) AS successes,
               round(avg(CASE WHEN success THEN 1.0 ELSE 0.0 END), 3) AS success_rate,
               round(avg(CASE WHEN reachable THEN 1.0 WHEN NOT reachable THEN 0.0 END), 3) AS reachable_fraction,
               round(avg(wall_s), 2) AS mean_wall_s
        FROM sim_outcomes GROUP BY task, take, robot, gripper, kind
        ORDER BY task, take, robot <> 'grippers', robot, gripper, kind
    """,
    # The robots side by side, per task: success, reachable fraction, the arms' IK residual and time-scale
    # (executed over demonstrated duration) and the failure classes with counts.
    "report_screening": """
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
    "report_sim_robots": """
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
    # Why episodes failed in physics.
    "report_sim_failures": """
        SELECT task, robot, gripper, CASE WHEN success THEN 'success' ELSE failure END AS outcome, count(*) AS episodes
        FROM sim_outcomes GROUP BY task, robot, gripper, outcome
        ORDER BY task, robot <> 'grippers', robot, gripper, episodes DESC, outcome
    """,
    # Outcome stability per task and stability run: how many episodes keep their verdict when the
    # scene is shifted by a fraction of a millimetre (always / never succeed) and how many flip. Repeats
    # are counted once each: the same run re-chunked leaves older chunk files holding the same rows.
    "report_sim_stability": """
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
    # Latest benchmark run, one row per case.
    "report_benchmarks": """
        SELECT stage, case_name, size, unit, round(seconds, 4) AS seconds,
               round(baseline_seconds, 4) AS baseline_seconds, round(ratio, 1) AS ratio,
               round(items_per_second, 0) AS items_per_second, baseline, machine, git_commit
        FROM benchmarks
        WHERE run_id = (SELECT max(run_id) FROM benchmarks)
        ORDER BY stage, case_name
    """,
}
