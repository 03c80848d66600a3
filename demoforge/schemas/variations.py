"""The `variation_trials` table: success under simulated scene variations (the thesis's Table 4 analogue)."""

import pyarrow as pa

from demoforge.schemas.core import Column, keypoints3d, table
from demoforge.schemas.report_section import ReportSection

VARIATION_TRIALS = table(
    "variation_trials",
    version=1,
    doc=("One trajectory executed by the robot in MuJoCo on one varied scene: a task's nominal placement "
         "with distractors (`clutter`), other object instances (`object`: resized or reshaped within the "
         "category) or a moved placement (`spatial`), and the strategy that produced the trajectory."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "The take whose episode database / demonstration the strategy used."),
        Column("variation", pa.string(), "`nominal` (the task's own placement distribution), `clutter`, `object` or `spatial`."),
        Column("variation_params", pa.string(), "JSON: object scales {object: [s_xy, s_z]}, distractors [{shape, size, xy, yaw, mass}], moves {object: [dx, dy, dyaw]} (m, rad)."),
        Column("variation_summary", pa.string(), "The variation in words."),
        Column("trial", pa.int32(), "Scene number; all variations of one (task, seed, trial) start from the same nominal placement."),
        Column("seed", pa.int64(), "Seed of the scenes."),
        Column("strategy", pa.string(), "`replay_top1` (the top-1 database episode by keypoint MSE, replayed), `transform_demo` (the ingested demonstration transformed to the scene), `transform_scripted` (the take's ground-truth scripted demonstration transformed: no ingest error)."),
        Column("query_keypoints", keypoints3d(11), "The varied scene's 11 object keypoints (they follow resized objects), world frame, m."),
        Column("retrieved_episode_id", pa.int64(), "The replayed episode (replay_top1); -1 otherwise."),
        Column("retrieval_mse", pa.float64(), "Keypoint MSE of the replayed episode to the scene, m^2 (replay_top1).", nullable=True),
        Column("n_distractors", pa.int32(), "Distractor bodies on the table."),
        Column("distractor_max_shift_m", pa.float64(), "Largest horizontal displacement of a distractor by the end of the run, m (0 without distractors)."),
        Column("success", pa.bool_(), "The task's success predicate held and no hard failure occurred (robot_sim)."),
        Column("failure_reason", pa.string(), "The simulator's failure class (robot_sim FAILURES) or `error`; empty on success."),
        Column("detail", pa.string(), "The simulator's explanation (task predicate, collisions), or the error."),
        Column("sim_wall_s", pa.float64(), "Wall time of the MuJoCo execution, s."),
        Column("wall_s", pa.float64(), "Wall time of the whole trial (scene, trajectory, execution), s."),
    ],
    # one file per cell of Table 4: a run of some kinds / strategies replaces only those cells
    partition_by=("task", "take", "variation", "strategy"),
)

#: SQL of the `report_table4` view (schemas/reports.py): per task and strategy, successes / trials under each
#: variation ("k/n", thesis Table 4) and the success rate over the three variations (nominal excluded: it is
#: the reference); an `all tasks` row per strategy is the thesis's bottom row.
REPORT_TABLE4_SQL = """
    WITH per AS (
        SELECT task, strategy, variation, count(*) AS n, count(*) FILTER (WHERE success) AS k
        FROM variation_trials GROUP BY task, strategy, variation
        UNION ALL
        SELECT 'all tasks' AS task, strategy, variation, count(*) AS n, count(*) FILTER (WHERE success) AS k
        FROM variation_trials GROUP BY strategy, variation
    )
    SELECT task, strategy,
           max(CASE WHEN variation = 'nominal' THEN CAST(k AS VARCHAR) || '/' || CAST(n AS VARCHAR) END) AS nominal,
           max(CASE WHEN variation = 'clutter' THEN CAST(k AS VARCHAR) || '/' || CAST(n AS VARCHAR) END) AS clutter,
           max(CASE WHEN variation = 'object' THEN CAST(k AS VARCHAR) || '/' || CAST(n AS VARCHAR) END) AS object,
           max(CASE WHEN variation = 'spatial' THEN CAST(k AS VARCHAR) || '/' || CAST(n AS VARCHAR) END) AS spatial,
           round(sum(k) FILTER (WHERE variation <> 'nominal')
                 / nullif(sum(n) FILTER (WHERE variation <> 'nominal'), 0), 3) AS variation_success_rate
    FROM per GROUP BY task, strategy
    ORDER BY task = 'all tasks', task,
             CASE strategy WHEN 'replay_top1' THEN 0 WHEN 'transform_demo' THEN 1 ELSE 2 END
"""

REPORT_TABLE4 = ReportSection(
    "report_table4", "Table 4 analogue: success under simulated scene variations",
    computed_from=("variation_trials",),
    stamp="variations",
    intro=("The thesis's Table 4 (clutter, object instance, spatial configuration; Pouring, Mix-bowl, "
           "Trash-in-bin) in MuJoCo: successes / scenes of the robot executing each strategy's trajectory on a "
           "varied scene. `nominal`: a placement from the task's own distribution (the reference; every "
           "variation of a scene starts from it); `clutter`: 2-3 solid distractor bodies on the table (they "
           "have no keypoints: the strategies do not see them, like the thesis's prompts); `object`: the "
           "objects resized (even scenes) or reshaped (odd: wider and shorter, or narrower and taller) within "
           "their category, keypoints following the geometry; `spatial`: every object shifted 4-8 cm and turned "
           "0.3-0.7 rad. Strategies: `replay_top1` (the nearest database episode by keypoint MSE, replayed), "
           "`transform_demo` (the ingested demonstration transformed to the scene's keypoints), "
           "`transform_scripted` (the take's ground-truth demonstration transformed: the variation's cost "
           "without ingest error). `variation_success_rate` pools the three variations; `all tasks` is the "
           "thesis's bottom row. With 2 scenes per cell one success either way is within the simulation's "
           "sensitivity: borderline pouring runs change outcome even when distractors stand at the table's far "
           "corners."),
    sql=REPORT_TABLE4_SQL,
)

#: SQL of the `report_table4_failures` view: what went wrong under each variation (outcome last in the
#: order: outcomes with equal counts otherwise came out in either order from one run to the next).
REPORT_TABLE4_FAILURES_SQL = """
    SELECT task, variation, strategy, CASE WHEN success THEN 'success' ELSE failure_reason END AS outcome,
           count(*) AS trials, round(max(distractor_max_shift_m), 3) AS max_distractor_shift_m
    FROM variation_trials GROUP BY task, variation, strategy, outcome
    ORDER BY task, CASE variation WHEN 'nominal' THEN 0 WHEN 'clutter' THEN 1 WHEN 'object' THEN 2 ELSE 3 END,
             strategy, trials DESC, outcome
"""

REPORT_TABLE4_FAILURES = ReportSection(
    "report_table4_failures", "Why trials failed under scene variations",
    computed_from=("variation_trials",),
    stamp="variations",
    sql=REPORT_TABLE4_FAILURES_SQL,
)
