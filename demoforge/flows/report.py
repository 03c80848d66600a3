"""Write reports/: REPORT.md (read top to bottom), one CSV per report view, PNG figures."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow.csv as pacsv

from demoforge.runtime.provenance import git_commit
from demoforge.lib.evaluation.markdown import markdown_table
from demoforge.schemas.catalog import build_catalog, query
from demoforge.schemas.reports import REPORT_VIEWS

PROJECT_ROOT = Path(__file__).resolve().parents[2]


# Views for SQL that the report does not show: `demoforge llm-eval`'s prompting trials on placement scenes
# (not the Table 3 grid, which the report shows in the thesis's layout).
SQL_ONLY_VIEWS = {"report_table3", "report_llm_failures"}

# The views the report shows (each report view is one of these or SQL-only)
SHOWN_VIEWS = {
    "report_takes", "report_replay_by_task", "report_visibility", "report_benchmarks", "report_ingest_by_task",
    "report_ingest_accuracy", "report_segmentation", "report_ingested_demos", "report_augmentation",
    "report_table1", "report_table2", "report_appendix_b", "report_big_vs_small", "report_real_photos",
    "report_sim", "report_sim_robots", "report_screening", "report_sim_failures", "report_sim_stability", "report_table4",
    "report_table4_failures", "report_policy", "report_policy_failures", "report_table3_grid",
    "report_table3_intervals", "report_table3_failures", "report_data_scaling"}

# While write_report runs: every view it has queried, so that publishing them as Prefect artifacts
# after the Markdown does not query each of them a second time.
_REPORT_VIEWS_READ: dict[tuple[str, str], object] | None = None


def _view(name: str, warehouse: Path):
    key = (str(warehouse), name)
    if _REPORT_VIEWS_READ is not None and key in _REPORT_VIEWS_READ:
        return _REPORT_VIEWS_READ[key]
    t = query(f"SELECT * FROM {name}", warehouse)
    if _REPORT_VIEWS_READ is not None:
        _REPORT_VIEWS_READ[key] = t
    return t


def _section(title: str, name: str, warehouse: Path, reports: Path, stamp: str, intro: str = "") -> str:
    t = _view(name, warehouse)
    pacsv.write_csv(t, reports / f"{name}.csv")
    rows = [list(r.values()) for r in t.to_pylist()]
    parts = [f"## {title}", ""]
    if intro:
        parts += [intro, ""]
    parts += [f"_{stamp} · SQL view `{name}` · CSV `{name}.csv`_", "", markdown_table(t.column_names, rows)]
    return "\n".join(parts)


def takes_figure(warehouse: Path, out_png: Path, columns: int = 3) -> Path | None:
    """One rendered frame per task (first grasp of its first take) with GT skeletons and object keypoints."""
    import cv2

    from demoforge.lib.evaluation.visualize import draw_hand, draw_points, montage

    takes = query(
        "SELECT task, take, path FROM takes WHERE NOT mirror "
        "QUALIFY row_number() OVER (PARTITION BY task ORDER BY seed) = 1 ORDER BY task", warehouse
    ).to_pylist()
    tiles, captions = [], []
    for t in takes:
        grasp = query(
            "SELECT coalesce(min(frame), 0) AS f FROM gt_gripper "
            "WHERE take = ? AND closed", warehouse, [t["take"]]).column("f")[0].as_py()
        frame = int(grasp) + 10
        hands = query(
            "SELECT hand, joints_px, visible, present FROM gt_hand_joints "
            "WHERE take = ? AND frame = ? ORDER BY hand", warehouse, [t["take"], frame]).to_pylist()
        kps = query(
            "SELECT keypoints_px FROM gt_object_keypoints "
            "WHERE take = ? AND frame = ?", warehouse, [t["take"], frame]).to_pylist()
        png = Path(t["path"]) / "rgb" / f"{frame:06d}.png"
        if not png.exists():
            continue
        rgb = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
        for h in hands:
            if h["present"]:
                rgb = draw_hand(rgb, np.array(h["joints_px"]), np.array(h["visible"]), h["hand"])
        if kps:
            rgb = draw_points(rgb, np.array(kps[0]["keypoints_px"]))
        tiles.append(rgb)
        captions.append(f"{t['task']}  frame {frame}")
    if not tiles:
        return None
    grid = montage(tiles, columns=min(columns, len(tiles)), captions=captions)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out_png), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    return out_png


def data_scaling_sections(warehouse: Path, reports: Path, stamp: str) -> list[str]:
    """The data-scaling table and its plot (nothing when no closed-loop policy was evaluated)."""
    from demoforge.lib.evaluation.data_scaling import plot_data_scaling

    t = _view("report_data_scaling", warehouse)
    if t.num_rows == 0:
        return ["## Data scaling: a closed-loop policy trained on generated episodes", "",
                "_Not run in this warehouse: `demoforge data-scaling`._", ""]
    md = [_section("Data scaling: a closed-loop policy trained on generated episodes", "report_data_scaling",
                   warehouse, reports, stamp,
                   "Success of the closed-loop policy (`demoforge train-policy --closed-loop`: action chunks from the "
                   "arms' joints and the objects' keypoints at every step, ACT-style) trained on 1 (the original "
                   "demonstration), 10, 100, ... generated episodes the arms' screening lets through, rolled out "
                   "step by step in the task's Gymnasium environment (demoforge.envs) on held-out scenes (thesis "
                   "protocol, scene seeds no database uses), beside the LLM-free baselines and the open-loop keypoint "
                   "policy (`open_loop`, trained on every screened-in episode) executed on the same scenes. "
                   "`n_train_episodes` of a baseline: the episodes it chooses from. Wilson 95 % intervals."),
          ""]
    png = plot_data_scaling(t.to_pylist(), reports / "data_scaling.png")
    if png is not None:
        md += [f"![closed-loop success against training episodes]({png.name})", ""]
    return md


def keypoint_sections(warehouse: Path, reports: Path, commit: str) -> list[str]:
    """Thesis Tables 1, 2, Appendix B and the big/small comparison per dataset, plus the real photos."""
    from demoforge.lib.evaluation.keypoints import plot_big_vs_small, plot_per_take_bars

    md = []
    rows = query("SELECT * FROM keypoint_metrics", warehouse).to_pylist()
    for dataset in sorted({r["dataset"] for r in rows}):
        # every detector of a dataset in one table, the `detector` column side by side (simulated first)
        detectors = sorted({r["detector"] for r in rows if r["dataset"] == dataset}, key=_detector_order)
        src = {"arctic": "ARCTIC (egocentric view; anchor depth from ground truth: ARCTIC has no depth camera)",
               "synthetic": "synthetic renders (depth alignment on the rendered depth)"}.get(dataset, dataset)
        stamp = f"data: {src} · detectors: {', '.join(detectors)} · commit {commit}"
        order = "ORDER BY CASE detector WHEN 'simulated' THEN 0 ELSE 1 END, detector"
        for title, view in (("Table 1: MPJPE and PA-MPJPE (m)", "report_table1"),
                            ("Table 2: 2D MPJPE (px) and PCK", "report_table2"),
                            ("Appendix B: per take", "report_appendix_b")):
            t = query(f"SELECT * FROM (SELECT *, row_number() OVER () AS _row FROM {view}) WHERE dataset = ? "
                      f"{order}, _row", warehouse, [dataset]).drop_columns(["_row"])
            name = f"{view}_{dataset}"
            pacsv.write_csv(t, reports / f"{name}.csv")
            md += [f"## {title} — {dataset}, by detector", "",
                   f"_{stamp} · SQL view `{view}` · CSV `{name}.csv`_", "",
                   markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()])]
        for detector in detectors:
            sel = [r for r in rows if r["dataset"] == dataset and r["detector"] == detector]
            png = plot_per_take_bars(sel, "mpjpe_aligned_m", reports / f"keypoints_per_take_{dataset}_{detector}.png")
            md += [f"![aligned MPJPE per take, {detector} detector]({Path(png).name})", ""]
            if any(r.get("size_group") for r in sel):
                png = plot_big_vs_small(sel, reports / f"keypoints_big_vs_small_{dataset}_{detector}.png")
                md += [f"![big vs small objects, {detector} detector]({Path(png).name})", ""]
    md.append(_section("A real detector on labelled real photos", "report_real_photos", warehouse, reports,
                       f"data: real photos (../shared/data/real_hands) · commit {commit}",
                       "MediaPipe on FreiHAND, OneHand10K, CMU Panoptic and COCO-WholeBody samples: PCK by "
                       "the labelled box size over the hands it found; `pck20_all_hands` counts the joints "
                       "of missed hands as wrong."))
    return md


def _detector_order(name: str) -> tuple:
    """The simulated detector first, then the real ones by name."""
    return (name != "simulated", name)


TABLE3_INTRO = (
    "The thesis's Table 3 (pouring: 5 takes x 10 query scenes; its figures: One Demo 6 %, 3 Random 24 %, "
    "3 Retrieved 96 %) in its layout, successes/scenes in the MuJoCo check per take and the pooled rate on "
    "the Average row. Protocol `thesis`: every take has its own database and its query scenes are drawn from "
    "that database's own augmentation sampler with held-out seeds (in its distribution, never one of its "
    "episodes: the thesis's 5.3.1). Protocol `novel`: the task library's placements (each object placed "
    "and turned independently) against a second database of the take built to cover them. Prompts: "
    "`one_demo` (the original demonstration as the only example), `random_3`, `retrieved_3` (top 3 by "
    "keypoint MSE). LLM-free: `replay_original` (the demonstration replayed unchanged: One Demo without an "
    "LLM), `replay_top1` (the nearest episode replayed), `knn_blend` (the 3 nearest episodes carried to the "
    "scene in their objects' frames and averaged), `transform_demo` (the demonstration, or its mirror image, "
    "carried to the scene); `policy`: the learned policy trained on that take's database. A grid run with "
    "fewer LLM scenes than scenes shows it in the denominators.")


def table3_sections(warehouse: Path, reports: Path, stamp: str) -> list[str]:
    """Table 3 in the thesis's layout, its Wilson intervals and failure reasons (empty without a grid run)."""
    if _view("report_table3_grid", warehouse).num_rows == 0:
        return ["## Table 3 (thesis layout)", "", "_No Table 3 grid in this warehouse yet: `make table3`._", ""]
    return [_section("Table 3 (thesis layout), per protocol", "report_table3_grid", warehouse, reports, stamp,
                     TABLE3_INTRO),
            _section("Table 3: success rates with Wilson 95 % intervals", "report_table3_intervals", warehouse,
                     reports, stamp, "Pooled over the takes; `nearest_episode_rms_mm`: how far the scenes lie "
                     "from their nearest database episode (RMS over the keypoints)."),
            _section("Table 3: why trials failed", "report_table3_failures", warehouse, reports, stamp)]


def sim_sections(warehouse: Path, reports: Path, stamp: str, params: dict) -> list[str]:
    """The robots side by side (per task: success, reachable fraction, failure classes), per episode kind,
    and why episodes failed."""
    md = []
    robots = ", ".join(params.get("robots") or ["grippers"])
    sim_stamp = stamp + f" · robots: {robots} · episodes per task: {params.get('sim_episodes')}"
    md.append(_section("The robots side by side", "report_sim_robots", warehouse, reports, sim_stamp,
                       "The same sample of each task's episodes (the original demonstration first) executed by "
                       "each robot with real contacts, friction and gravity: `grippers`, two free-floating "
                       "Robotiq 2F-140-class grippers (every pose reachable, only the hands collide); `aloha`, two "
                       "ViperX 300 6-DOF arms driven in joint space from inverse kinematics (mink), with ALOHA's "
                       "own fingers (`gripper` aloha: 69 mm between the pads) or the 2F-140 on the wrists. "
                       "`reachable_fraction`: the episodes whose every step the arms reach within 1 cm and 5 "
                       "degrees; `failures`: each failure class with its count (`unreachable`, `joint_limit`: a "
                       "pose beyond reach or a joint at its range's end or speed limit; `link_collision`: an arm "
                       "link on the table, an object or the other arm; `wider_than_stroke`: an object the hand "
                       "cannot open around). docs/robot-checks.md says where the arms stand and why they fail."))
    md.append(_section("The databases screened for the arms", "report_screening", warehouse, reports, stamp,
                       "Every episode of each task's database checked for the arms without physics "
                       "(`demoforge screen`; lib/sim/robots/aloha/screening.py): reach, joint ranges, the grasps the "
                       "planner would choose, the fingers above the table and the forearms apart, with the arms' "
                       "closed-form inverse kinematics. Retrieval, `knn_blend`, the policy and the exports for an "
                       "arm robot use only the screened-in episodes. `physics_passes_screened_in` / "
                       "`_screened_out`: of the episodes the physics check also ran with that robot, the share it "
                       "passed, among those the screening let through and those it did not."))
    md.append(_section("Robot success checks in MuJoCo physics, per episode kind", "report_sim", warehouse, reports,
                       sim_stamp, "The robots replay what the ingest recovered from the video, not the script."))
    md.append(_section("Why episodes failed in physics", "report_sim_failures", warehouse, reports, sim_stamp))
    return md


def write_report(warehouse: str | Path, reports_dir: str | Path, params: dict) -> Path:
    global _REPORT_VIEWS_READ
    _REPORT_VIEWS_READ = {}
    try:
        return _write_report(Path(warehouse), Path(reports_dir), params)
    finally:
        _REPORT_VIEWS_READ = None


def _write_report(warehouse: Path, reports: Path, params: dict) -> Path:
    reports.mkdir(parents=True, exist_ok=True)
    build_catalog(warehouse)
    commit = git_commit(str(PROJECT_ROOT))
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    stamp = (f"data: synthetic (demoforge.synth, MuJoCo renders, exact ground truth) · "
             f"seeds {params.get('seed')}..{params.get('seed', 0) + params.get('takes', 1) - 1} · commit {commit}")
    md = [
        "# demoforge report",
        "",
        f"Generated {now} by `make evaluate` (commit `{commit}`). Parameters: `{json.dumps(params, sort_keys=True)}`.",
        "Every table below is a DuckDB view in `warehouse/catalog.duckdb`: run "
        "`demoforge sql \"SELECT * FROM <view>\"` to query it yourself.",
        "",
    ]
    fig = takes_figure(warehouse, reports / "synthetic_takes.png")
    md += ["## The synthetic demonstrations", "",
           "One frame per task at its first grasp, rendered by MuJoCo from the head camera "
           "(640x480, fx = fy = 570.3422), with the ground-truth hand skeletons (filled dots: joint "
           "visible in the depth test, hollow: occluded) and the 11 object keypoints (crosses).", ""]
    md += [f"![synthetic takes]({fig.name})" if fig else "_(no take to show)_", ""]
    md.append(_section("Takes", "report_takes", warehouse, reports, stamp,
                       "Every generated take; `replay_success` is the task's success predicate after "
                       "replaying the scripted demonstration in MuJoCo physics."))
    md.append(_section("Scripted demonstrations in physics, per task", "report_replay_by_task", warehouse,
                       reports, stamp))
    md.append(_section("Ground-truth joint visibility", "report_visibility", warehouse, reports, stamp,
                       "Mean fraction of the 21 joints that pass the depth test, per task and hand."))
    det_stamp = stamp.replace("exact ground truth",
                              f"exact ground truth; detectors: {', '.join(params.get('detectors') or ['simulated'])}")
    md.append(_section("Ingest accuracy per task and detector", "report_ingest_by_task", warehouse, reports,
                       det_stamp,
                       "Hand keypoints from each detector, corrected with the rendered depth, then mapped to "
                       "grippers; the `detector` column puts them side by side. `simulated`: the HaMeR-like "
                       "error model applied to the ground truth (not a real detector; every later section "
                       "builds on its ingest); `mediapipe`: the real MediaPipe hand landmarker run on the "
                       "rendered frames (video mode, with the hand tracker). Goals: aligned MPJPE within 5 mm "
                       "of PA-MPJPE; automatic open/close >= 95 %."))
    md.append(_section("Robot success on the ingested demonstrations, per detector", "report_ingested_demos",
                       warehouse, reports, det_stamp,
                       "Each take's ingested gripper trajectory (undetected frames held at the nearest detected "
                       "pose) executed by the robot in MuJoCo with the take's object keypoints, per detector "
                       "(`ingested_demo_checks`; `failures`: why the others failed). Goal: the MediaPipe "
                       "ingests succeed at least 90 % as often as the simulated detector's."))
    md.append(_section("Ingest accuracy per take and hand", "report_ingest_accuracy", warehouse, reports,
                       det_stamp,
                       "MPJPE before (m) and after depth alignment (mm), PA-MPJPE, 2D error and PCK, gripper "
                       "position/rotation/approach-axis error, open/close accuracy of the thesis's fixed "
                       "threshold (0.06 m), the automatic per-take method and the labelled ranges, and the "
                       "left/right swaps injected by the detector and repaired."))
    md += keypoint_sections(warehouse, reports, commit)
    md.append(_section("Segmentation against the scripted boundaries", "report_segmentation", warehouse, reports,
                       stamp, "Boundaries matched within 30 frames; errors in frames (30 fps)."))
    md.append(_section("Augmented episodes", "report_augmentation", warehouse, reports, stamp,
                       "The task databases: episode 0 is the ingested demonstration, then translated and "
                       "mirrored-and-translated episodes; invalid ones are kept and flagged with the reason."))
    llm_stamp = stamp + f" · LLM backend: {params.get('llm_backend')} · trials per strategy: {params.get('trials')}"
    md += table3_sections(warehouse, reports, llm_stamp + f" · LLM-free and policy scenes: {params.get('grid_scenes')}")
    pol_stamp = stamp + (f" · policy: {params.get('policy_epochs')} epochs, {params.get('policy_waypoints')} waypoints, "
                         f"{params.get('policy_trials')} scenes per kind")
    md.append(_section("Learned keypoint policy", "report_policy", warehouse, reports, pol_stamp,
                       "A small Transformer trained on the task's augmented episodes (`demoforge train-policy`), judged "
                       "by the same MuJoCo check: in_distribution = the prompting evaluation's query scenes (also the "
                       "`policy` row of Table 3), mirrored = their mirror images, out_of_distribution = the demo's "
                       "placement shifted beyond the augmentation's translation range, held_out = validation placements "
                       "of the database. Latency: one forward pass per scene on the CPU (Table 3 has the LLM's). "
                       "The query scenes move each object independently and turn it, which the default database "
                       "(both objects translated together, no yaw) does not cover; held_out shows the policy on "
                       "placements the database does cover. Predictions are uniform waypoints upsampled to 30 Hz: at "
                       "20 most of a database's own successful episodes fail the check once resampled (the LLM "
                       "prompts write keyframes instead), at 40 they pass, so the default policy uses 40."))
    md.append(_section("Why policy trials failed", "report_policy_failures", warehouse, reports, pol_stamp))
    md += data_scaling_sections(warehouse, reports, stamp)
    var_stamp = stamp + f" · scenes per task and variation: {params.get('variation_trials')}"
    md.append(_section("Table 4 analogue: success under simulated scene variations", "report_table4", warehouse,
                       reports, var_stamp,
                       "The thesis's Table 4 (clutter, object instance, spatial configuration; Pouring, Mix-bowl, "
                       "Trash-in-bin) in MuJoCo: successes / scenes of the robot executing each strategy's "
                       "trajectory on a varied scene. `nominal`: a placement from the task's own distribution (the "
                       "reference; every variation of a scene starts from it); `clutter`: 2-3 solid distractor "
                       "bodies on the table (they have no keypoints: the strategies do not see them, like the "
                       "thesis's prompts); `object`: the objects resized (even scenes) or reshaped (odd: wider and "
                       "shorter, or narrower and taller) within their category, keypoints following the geometry; "
                       "`spatial`: every object shifted 4-8 cm and turned 0.3-0.7 rad. Strategies: `replay_top1` "
                       "(the nearest database episode by keypoint MSE, replayed), `transform_demo` (the ingested "
                       "demonstration transformed to the scene's keypoints), `transform_scripted` (the take's "
                       "ground-truth demonstration transformed: the variation's cost without ingest error). "
                       "`variation_success_rate` pools the three variations; `all tasks` is the thesis's bottom "
                       "row. With 2 scenes per cell one success either way is within the simulation's "
                       "sensitivity: borderline pouring runs change outcome even when distractors stand at the "
                       "table's far corners."))
    md.append(_section("Why trials failed under scene variations", "report_table4_failures", warehouse, reports,
                       var_stamp))
    md += sim_sections(warehouse, reports, stamp, params)
    md.append(_section("How stable the robot check's verdicts are", "report_sim_stability", warehouse, reports, stamp,
                       "Episodes of the sample executed again with the whole scene (objects and gripper poses) "
                       "shifted rigidly along the table by about 0.1 mm: physically nothing changes, only the "
                       "simulation's rounding. `flipping` episodes change outcome under that shift: their single "
                       "verdict is decided by numerical chaos, and `success_rate` over all repeats estimates "
                       "their success as a probability (`demoforge stability` for more episodes and repeats)."))
    from demoforge.tasks.report_plots import report_plots  # per task: trajectories, coverage, success maps

    md += report_plots(str(warehouse), str(reports))
    bench = _view("report_benchmarks", warehouse)
    if bench.num_rows:
        md.append(_section("Benchmarks (latest `make bench` run)", "report_benchmarks", warehouse, reports,
                           "measured on this machine"))
    else:
        md += ["## Benchmarks", "", "_No benchmark run in this warehouse yet: `make bench`._", ""]
    unused = set(REPORT_VIEWS) - SQL_ONLY_VIEWS - SHOWN_VIEWS
    assert not unused, f"report views not in the report: {unused}"
    out = reports / "REPORT.md"
    tmp = out.with_name(".REPORT.md.tmp")
    tmp.write_text("\n".join(md))
    tmp.replace(out)
    publish_artifacts(warehouse, out, sorted(REPORT_VIEWS))
    return out


def publish_artifacts(warehouse: Path, report: Path, views: list[str], max_rows: int = 200) -> int:
    """Inside a flow run: the report as a Markdown artifact and every non-empty report view as a table
    artifact, so the Prefect UI shows the results of the run. Returns how many were published."""
    from prefect.artifacts import create_markdown_artifact, create_table_artifact
    from prefect.context import FlowRunContext

    if FlowRunContext.get() is None:
        return 0
    text = report.read_text()
    create_markdown_artifact(text, key="demoforge-report", description=f"{report} (figures in {report.parent})")
    n = 1
    for name in views:
        t = _view(name, warehouse)
        if t.num_rows == 0:
            continue
        rows = [{k: (round(v, 6) if isinstance(v, float) else v if isinstance(v, (int, str, bool)) or v is None
                     else str(v)) for k, v in r.items()} for r in t.slice(0, max_rows).to_pylist()]
        create_table_artifact(rows, key=name.replace("_", "-"),
                              description=f"SQL view `{name}` ({t.num_rows} rows; `demoforge sql \"SELECT * FROM {name}\"`)")
        n += 1
    return n
