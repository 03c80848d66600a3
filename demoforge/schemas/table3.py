"""The `table3_trials` table: the thesis's Table 3 grid (takes x query scenes x strategies) under a
named protocol, with the LLM-free baselines and the learned policy beside the three prompts."""

import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from demoforge.schemas.core import DATA_FILE, Column, keypoints3d, register_migration, table, write_table
from demoforge.schemas.report_section import OMIT, ReportSection

TABLE3_TRIALS = table(
    "table3_trials",
    version=2,
    doc=("One prediction for one query scene of one take's database, judged by the MuJoCo success check. "
         "Protocol `thesis`: scenes drawn from the database's own augmentation sampler with held-out seeds; "
         "`novel`: the task library's independent placements with yaw, against a database built to cover them."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("protocol", pa.string(), "`thesis` or `novel` (lib/trajectories/query_scenes.py)."),
        Column("take", pa.string(), "Source take (the demonstration)."),
        Column("take_index", pa.int32(), "1-based number of the take in the grid (the thesis's Take1..Take5)."),
        Column("database", pa.string(), "The episode database's key in `episodes.take` (the take, or the take with a protocol suffix)."),
        Column("scene", pa.int32(), "Query scene number within the take (0-based)."),
        Column("seed", pa.int64(), "Seed of the grid: query scenes, the random strategy, the policy."),
        Column("scene_mirrored", pa.bool_(), "The query scene is a mirror image of the demonstration's layout (`thesis` draws mirrored scenes at the database's rate)."),
        Column("nearest_mse", pa.float64(), "Keypoint MSE of the scene to its nearest database episode, m^2 (how far retrieval must reach)."),
        Column("query_keypoints", keypoints3d(11), "The query scene's 11 object keypoints, world frame, m."),
        Column("robot", pa.string(), "The robot that executed the predictions (lib/sim/robots): `grippers` or `aloha`; "
               "the rows of a robot other than `grippers` are kept under `table3_trials/gripper=.../robot=.../`."),
        Column("gripper", pa.string(), "Its hands: `2f140` or `aloha` (ALOHA's fingers)."),
        Column("strategy", pa.string(), "Prompts `single`, `random`, `retrieval` (thesis: One Demo / 3 Random / 3 Retrieved); LLM-free `replay_original` (the demo replayed unchanged), `replay_top1` (the nearest episode replayed), `knn_blend` (the top-3 episodes carried to the scene in their objects' frames and averaged), `transform_demo` (the demo, or its mirror image, carried to the scene); `policy` (the learned policy trained on this database)."),
        Column("backend", pa.string(), "LLM backend (`local`, `openai`, ...), `torch` for the policy, `none` otherwise."),
        Column("model", pa.string(), "Model name, or the policy's checkpoint id; empty for `none`."),
        Column("example_ids", pa.list_(pa.int64()), "Database episodes used (prompt examples, replayed or blended)."),
        Column("prompt_tokens", pa.int32(), "Prompt length in the backend's tokens (0 without an LLM)."),
        Column("answer_tokens", pa.int32(), "Answer length in tokens."),
        Column("latency_s", pa.float64(), "Wall time of the prediction, s (0 when the answer came from the cache)."),
        Column("cached", pa.bool_(), "The LLM answer came from the answer cache."),
        Column("parse_status", pa.string(), "`ok` or the parser's / backend's failure (`wrong_shape`, `truncated`, `llm_error`, ...)."),
        Column("success", pa.bool_(), "The trajectory succeeded in the MuJoCo check (false when there was none)."),
        Column("failure_reason", pa.string(), "The simulator's failure class, or the parse status; empty on success."),
        Column("sim_detail", pa.string(), "The simulator's (or parser's) explanation."),
        Column("prompt_hash", pa.string(), "sha256 of the prompt (empty without an LLM)."),
        Column("raw_answer", pa.string(), "The backend's answer as returned (empty without an LLM)."),
    ],
    # one file per (protocol, take, strategy): a grid run re-writes only the cells it computes
    partition_by=("task", "protocol", "take", "strategy"),
)

STRATEGY_ORDER = """CASE strategy WHEN 'single' THEN 0 WHEN 'random' THEN 1 WHEN 'retrieval' THEN 2
    WHEN 'replay_original' THEN 3 WHEN 'replay_top1' THEN 4 WHEN 'knn_blend' THEN 5 WHEN 'transform_demo' THEN 6
    WHEN 'policy' THEN 7 ELSE 8 END"""


def _cell(strategy: str, alias: str) -> str:
    return (f"max(CASE WHEN strategy = '{strategy}' THEN CAST(k AS VARCHAR) || '/' || CAST(n AS VARCHAR) END) "
            f"AS {alias}")


_COLUMNS = (("single", "one_demo"), ("random", "random_3"), ("retrieval", "retrieved_3"),
            ("replay_original", "replay_original"), ("replay_top1", "replay_top1"), ("knn_blend", "knn_blend"),
            ("transform_demo", "transform_demo"), ("policy", "policy"))

#: The `report_table3_grid` view: the thesis's layout, one row per take (Take1..Take5, successes/scenes)
#: and an Average row (pooled success rate, %), per task and protocol; LLM-free columns after the prompts.
REPORT_TABLE3_GRID_SQL = f"""
    WITH per AS (
        SELECT task, protocol, robot, gripper, take_index, 'Take' || CAST(take_index AS VARCHAR) AS row_label,
               strategy, count(*) AS n, count(*) FILTER (WHERE success) AS k
        FROM table3_trials GROUP BY task, protocol, robot, gripper, take_index, strategy
    ), avg AS (
        SELECT task, protocol, robot, gripper, 1000 AS take_index, 'Average' AS row_label, strategy,
               sum(n) AS n, sum(k) AS k FROM per GROUP BY task, protocol, robot, gripper, strategy
    )
    SELECT * EXCLUDE (take_index) FROM (
        SELECT task, protocol, robot, gripper, take_index, row_label AS take,
               {", ".join(_cell(s, a) for s, a in _COLUMNS)}
        FROM per GROUP BY task, protocol, robot, gripper, take_index, row_label
        UNION ALL
        SELECT task, protocol, robot, gripper, take_index, row_label AS take,
               {", ".join(f"max(CASE WHEN strategy = '{s}' THEN CAST(round(100.0 * k / n) AS INTEGER) || ' %' END) AS {a}"
                          for s, a in _COLUMNS)}
        FROM avg GROUP BY task, protocol, robot, gripper, take_index, row_label)
    ORDER BY task, protocol DESC, robot <> 'grippers', robot, gripper, take_index
"""

REPORT_TABLE3_GRID = ReportSection(
    "report_table3_grid", "Table 3 (thesis layout), per protocol",
    computed_from=("table3_trials",),
    stamp="table3",
    intro=("The thesis's Table 3 (pouring: 5 takes x 10 query scenes; its figures: One Demo 6 %, 3 Random 24 %, "
           "3 Retrieved 96 %) in its layout, successes/scenes in the MuJoCo check per take and the pooled rate "
           "on the Average row. Protocol `thesis`: every take has its own database and its query scenes are "
           "drawn from that database's own augmentation sampler with held-out seeds (in its distribution, never "
           "one of its episodes: the thesis's 5.3.1). Protocol `novel`: the task library's placements (each "
           "object placed and turned independently) against a second database of the take built to cover them. "
           "Prompts: `one_demo` (the original demonstration as the only example), `random_3`, `retrieved_3` "
           "(top 3 by keypoint MSE). LLM-free: `replay_original` (the demonstration replayed unchanged: One "
           "Demo without an LLM), `replay_top1` (the nearest episode replayed), `knn_blend` (the 3 nearest "
           "episodes carried to the scene in their objects' frames and averaged), `transform_demo` (the "
           "demonstration, or its mirror image, carried to the scene); `policy`: the learned policy trained on "
           "that take's database. A grid run with fewer LLM scenes than scenes shows it in the denominators."),
    if_empty="_No Table 3 grid in this warehouse yet: `make table3`._",
    empty_title="Table 3 (thesis layout)",
    sql=REPORT_TABLE3_GRID_SQL,
)

#: The `report_table3_intervals` view: per task, protocol and strategy the pooled successes with a
#: Wilson 95 % score interval (z = 1.96), parse failures and latency.
REPORT_TABLE3_INTERVALS_SQL = f"""
    WITH s AS (
        SELECT task, protocol, robot, gripper, strategy, any_value(backend) AS backend, count(*) AS n,
               count(*) FILTER (WHERE success) AS k, count(DISTINCT take) AS takes,
               count(*) FILTER (WHERE parse_status NOT IN ('ok', 'truncated')) AS unparsable,
               avg(latency_s) FILTER (WHERE NOT cached) AS latency_s,
               avg(sqrt(nearest_mse)) AS nearest_rms_m
        FROM table3_trials GROUP BY task, protocol, robot, gripper, strategy
    ), w AS (
        SELECT *, k / n AS p, 1.96 AS z FROM s
    )
    SELECT task, protocol, robot, gripper, strategy, backend, takes, n AS trials, k AS successes, round(p, 3) AS success_rate,
           round(greatest(0.0, (p + z * z / (2 * n) - z * sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)), 3) AS wilson_low,
           round(least(1.0, (p + z * z / (2 * n) + z * sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)), 3) AS wilson_high,
           unparsable, round(latency_s, 2) AS mean_latency_s, round(1000 * nearest_rms_m, 1) AS nearest_episode_rms_mm
    FROM w ORDER BY task, protocol DESC, robot <> 'grippers', robot, gripper, {STRATEGY_ORDER}
"""

REPORT_TABLE3_INTERVALS = ReportSection(
    "report_table3_intervals", "Table 3: success rates with Wilson 95 % intervals",
    computed_from=("table3_trials",),
    stamp="table3",
    intro=("Pooled over the takes; `nearest_episode_rms_mm`: how far the scenes lie from their nearest database "
           "episode (RMS over the keypoints)."),
    if_empty=OMIT,
    sql=REPORT_TABLE3_INTERVALS_SQL,
)

#: The `report_table3_failures` view: outcomes per task, protocol and strategy.
REPORT_TABLE3_FAILURES_SQL = f"""
    SELECT task, protocol, robot, gripper, strategy,
           CASE WHEN success THEN 'success' ELSE failure_reason END AS outcome, count(*) AS trials
    FROM table3_trials GROUP BY task, protocol, robot, gripper, strategy, outcome
    ORDER BY task, protocol DESC, robot <> 'grippers', robot, gripper, {STRATEGY_ORDER}, trials DESC, outcome
"""

REPORT_TABLE3_FAILURES = ReportSection(
    "report_table3_failures", "Table 3: why trials failed",
    computed_from=("table3_trials",),
    stamp="table3",
    if_empty=OMIT,
    sql=REPORT_TABLE3_FAILURES_SQL,
)


def migrate_table3_v1(root: str | os.PathLike) -> int:
    """Version 1 files (before robots had names: every prediction was executed by the floating grippers)
    to version 2 in place: `robot` = grippers, `gripper` = 2f140. Returns how many were rewritten."""
    base = Path(root) / TABLE3_TRIALS.name
    moved = 0
    for path in sorted(base.glob(f"task=*/protocol=*/take=*/strategy=*/{DATA_FILE}")):
        if (pq.read_schema(path).metadata or {}).get(b"demoforge.schema_version") != b"1":
            continue
        t = pq.read_table(path)
        for name, value in (("robot", "grippers"), ("gripper", "2f140")):
            t = t.append_column(name, pa.array([value] * t.num_rows, pa.string()))
        write_table(TABLE3_TRIALS, t.select(TABLE3_TRIALS.arrow.names), root)  # atomic, to the same file
        moved += 1
    return moved


register_migration(TABLE3_TRIALS.name, migrate_table3_v1)
