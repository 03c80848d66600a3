"""Flow: one RGB-D take -> frames, hand keypoints, aligned keypoints, gripper poses, object keypoints."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence
from prefect import flow, get_run_logger

from demoforge.lib.errors import one_line
from demoforge.lib.ingest.options import IngestOptions
from demoforge.lib.perception.detectors import DETECTORS
from demoforge.lib.sim import scene_fingerprint
from demoforge.lib.takes import take_task_name
from demoforge.lib.takes.sources import take_root
from demoforge.lib.task_library import TASK_NAMES
from demoforge.runtime.runners import run_flow
from demoforge.tasks.common import Manifest, opened_take, run_stage
from demoforge.tasks.ingest import (
    align_keypoints, detect_hands, hand_presence, index_frames, map_grippers, object_keypoints, take_media_key,
)
from demoforge.tasks.ingest_drawing import overlay_video
from demoforge.tasks.ingest_evaluation import ingest_keypoint_metrics, ingest_metrics
from demoforge.tasks.sim import check_ingested_demo, demo_failure_row


@flow(name="ingest-take")
def ingest_take(
    path: str,
    warehouse: str,
    task: str | None = None,
    options: IngestOptions | None = None,
    show_progress: bool = True,
    variant: dict | None = None,
) -> dict[str, Manifest | None]:
    """Ingest one take folder (layout: docs/takes.md) into the warehouse.

    options: how (demoforge.lib.ingest.options.IngestOptions: the detector and its settings, depth
    alignment, hand tracking, hand-to-gripper mapping, the depth checks' verdict, the overlay video;
    default: the simulated detector and the defaults). The per-hand tracking verdict is the
    `hand_presence` table; depth that fails a check stops the take with demoforge.tasks.ingest.DepthError
    unless options.accept_bad_depth (every row then flagged in `depth_problem`).
    Every stage is cached on the content of its inputs and the options it reads: a second run is
    served from the cache.
    variant: None (where augment and every later stage read the take) or {"detector": detector} to keep
    this detector's rows beside those (demoforge.schemas.core.variant_parts; see ingest_side_by_side).
    """
    logger = get_run_logger()
    opts = options or IngestOptions()
    detector = opts.detector
    DETECTORS.check(detector)  # an unknown name: one line listing the registered detectors
    if variant is not None and variant != {"detector": detector}:
        raise ValueError(f"variant must be None or {{'detector': {detector!r}}}, got {variant!r}")
    var = {"variant": dict(variant)} if variant else {}  # absent, not None: the stages' keys stay as they were
    take_dir = take_root(path)  # a take folder's .mp4 given as a file: the folder
    # fails early, with a clear message, on a take that cannot be read; opened once: the stages get this take
    take = opened_take(take_dir)
    bad = take.status_counts()
    if set(bad) - {"ok"}:
        logger.warning("take %s: frame problems %s (recorded in `frames`)", take.take_id, bad)
    detector_options = dict(opts.detector_options)
    for key in ("path", "checkpoint", "mano_model"):  # files: their content, not their name, is the cache key
        if key in detector_options and detector_options[key] is not None:
            detector_options[key] = Path(detector_options[key]).resolve()
    # the task name resolved here is part of every key; the first three stages are keyed on the take's
    # content without annotations.json (media_key), so annotating later keeps their results
    common = dict(take_dir=take_dir, task=take_task_name(take, task), warehouse=warehouse)
    media = take_media_key(take_dir)
    frames = run_stage(index_frames, warehouse, **common, media_key=media)
    hands = run_stage(detect_hands, warehouse, **common, detector=detector, detector_options=detector_options,
                      frames=frames, show_progress=show_progress, media_key=media, **var)
    tracker = dict(opts.tracker)
    aligned = run_stage(align_keypoints, warehouse, **common, hand_keypoints=hands, alignment=dict(opts.alignment),
                        tracker=tracker, accept_bad_depth=bool(opts.accept_bad_depth), media_key=media, **var)
    presence = run_stage(hand_presence, warehouse, **common, aligned=aligned, tracker=tracker, **var)
    grippers = run_stage(map_grippers, warehouse, **common, aligned=aligned, state_method=opts.state_method,
                         smoothing=opts.smoothing, grasp_prior=opts.grasp_prior,
                         table_clearance=opts.table_clearance, **var)
    objects = run_stage(object_keypoints, warehouse, **common)  # None: not annotated yet (warned)
    metrics = run_stage(ingest_metrics, warehouse, **common, hand_keypoints=hands, aligned=aligned,
                        grippers=grippers, **var)
    result = {"frames": frames, "hand_keypoints": hands, "aligned_keypoints": aligned,
              "hand_presence": presence, "gripper_poses": grippers, "object_keypoints": objects, "ingest_metrics": metrics}
    if opts.video:
        result["overlay_video"] = run_stage(overlay_video, warehouse, **common, aligned=aligned, grippers=grippers,
                                            **var)
    return result


SIMULATED = "simulated"


def detector_variant(detector: str) -> dict | None:
    """Where a detector's rows go in a side-by-side ingest: the simulated detector's where every later
    stage reads them (augment, simulate, ...), any other's beside them under `detector=<name>/`."""
    return None if detector == SIMULATED else {"detector": detector}


@flow(name="ingest-side-by-side")
def ingest_side_by_side(
    path: str,
    warehouse: str,
    detectors: Sequence[str] = (SIMULATED, "mediapipe"),
    task: str | None = None,
    check_demo: bool = True,
    show_progress: bool = False,
) -> dict[str, dict]:
    """Ingest one take with each of `detectors` and keep their rows side by side (detector_variant);
    for a synthetic take also its keypoint metrics per detector (`keypoint_metrics`, the simulated
    detector's come from demoforge.flows.keypoint_eval as before), and with `check_demo` the robot executing each
    detector's ingested demonstration in MuJoCo (`ingested_demo_checks`).

    A detector whose ingest or demonstration fails (e.g. untrustworthy depth, a hand never found) is
    recorded in `ingested_demo_checks` with the reason, and the other detectors go on.
    Returns {detector: {"ingest": manifests or None, "demo": manifest or None, "error": str}}."""
    logger = get_run_logger()
    take_dir = take_root(path)
    name = take_task_name(opened_take(take_dir), task)
    out: dict[str, dict] = {}
    for det in dict.fromkeys(detectors):  # each once, in the given order
        variant = detector_variant(det)
        var = {"variant": variant} if variant else {}
        res: dict = {"ingest": None, "demo": None, "error": ""}
        try:
            ingested = run_flow(ingest_take, str(take_dir), warehouse, task=task,
                                options=IngestOptions(detector=det), show_progress=show_progress, variant=variant)
            res["ingest"] = ingested
            common = dict(take_dir=take_dir, task=task, warehouse=warehouse)
            if variant is not None:
                res["keypoints"] = run_stage(ingest_keypoint_metrics, warehouse, **common,
                                             hand_keypoints=ingested["hand_keypoints"], **var)
            if check_demo:
                res["demo"] = check_demonstration(take_dir, warehouse, task, name, ingested, **var)
        except Exception as e:  # noqa: BLE001  (one detector's failure must not hide the other's rows)
            res["error"] = f"{type(e).__name__}: {one_line(e)}"[:2000]
            logger.warning("take %s, detector %s: %s", take_dir.name, det, res["error"])
            if check_demo and name in TASK_NAMES:
                from demoforge.schemas.core import write_table

                write_table("ingested_demo_checks", demo_failure_row(name, take_dir.name, det, "ingest_failed",
                                                                     res["error"]), warehouse)
        out[det] = res
    return out


def check_demonstration(take_dir: Path, warehouse: str, task: str | None, task_name: str, ingested: dict,
                        **variant) -> Manifest | None:
    """The robot executing the ingested demonstration in MuJoCo (`ingested_demo_checks`, cached), or None
    for a take without object keypoints or a task the robot simulator does not know (a custom task).
    ``variant``: the detector's variant of the ingest (see detector_variant)."""
    if ingested["object_keypoints"] is None or task_name not in TASK_NAMES:
        return None
    return run_stage(check_ingested_demo, warehouse, take_dir=take_dir, task=task, warehouse=warehouse,
                     grippers=ingested["gripper_poses"], objects=ingested["object_keypoints"],
                     presence=ingested["hand_presence"], scene=scene_fingerprint(task_name), **variant)
