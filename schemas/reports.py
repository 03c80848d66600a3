"""Report tables as named DuckDB views over the warehouse tables.

Each entry becomes a view in `warehouse/catalog.duckdb` (``SELECT * FROM report_takes``), and the
report (`make evaluate`) is written from these same views, so what a person reads in
reports/REPORT.md and what they query in SQL are one and the same.
"""

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
