"""Prefect tasks of the ingest stage (thesis 3.1): each reads its inputs, calls lib/, writes one table.

Per-frame, per-hand arrays (T, 2, ...) are stored one row per (frame, hand), frame-major with the
left hand first; demoforge.schemas.reads.per_hand's ``rows`` and ``arrays`` convert between the two.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from demoforge.lib.annotate import annotation_status, not_annotated_message
from demoforge.lib.errors import UserError
from demoforge.lib.geometry import transform_points
from demoforge.lib.ingest.depth_checks import (DepthFrameStats, check_depth, coverage_warning, depth_coverage,
                                               frame_depth_stats)
from demoforge.lib.ingest.gripper_mapping import (clamp_above_table, gripper_state, hand_to_gripper, smooth_poses,
                                                  stabilize_grasps, to_pose8)
from demoforge.lib.ingest.object_keypoints import backproject_keypoints_detailed
from demoforge.lib.perception.tracking import REJECT_REASONS, TrackerConfig, depth_size_ratio, hand_trust, track_hands
from demoforge.lib.takes import iter_depth, iter_frames, read_frame, take_task_name
from demoforge.lib.takes.sources import cache_key_inputs
from demoforge.schemas.core import read_table, read_table_file, unsliced_table, write_table
from demoforge.schemas.reads.per_hand import HANDS, arrays, rows
from demoforge.tasks.common import Manifest, _dir_file_digests, _file_digest, opened_take, stage_task

INGEST_VERSION = "1"
ANNOTATIONS = "annotations.json"


def take_media_key(take_dir: Path) -> str:
    """Content hash of a take (its name and every file; a recording's file and its side folder) except
    annotations.json: the cache key of the stages that never read the annotation (frames, detection,
    alignment), so annotating a take after a first ingest does not redo its hand detection. Digests come
    from the same remembered records as every other key (demoforge.tasks.common), so an unchanged take,
    a multi-GB recording too, is only stat'ed."""
    import hashlib

    take_dir = Path(take_dir)
    h = hashlib.sha256(take_dir.name.encode())
    if take_dir.is_file():
        h.update(_file_digest(take_dir, remember=True).encode())
        files = []
    else:
        files = _dir_file_digests(take_dir)
    for extra in cache_key_inputs(take_dir).values():  # a recording's side folder
        if extra.is_dir():
            files = files + [(f"{extra.name}/{rel}", d) for rel, d in _dir_file_digests(extra) if rel != ANNOTATIONS]
        else:
            files = files + [(extra.name, _file_digest(extra, remember=True))]
    for rel, digest in files:
        if rel != ANNOTATIONS:
            h.update(rel.encode())
            h.update(digest.encode())
    return h.hexdigest()


# --- 1. frames -----------------------------------------------------------------------------------

@stage_task(name="index_frames", version=INGEST_VERSION, key_ignore=("take_dir",))  # keyed on media_key
def index_frames(take_dir: Path, task: str | None, warehouse: str, verify_decode: bool = True, *,
                 media_key: str) -> Manifest:
    """Index the take's frames; with ``verify_decode`` every frame is decoded once so unreadable
    files are reported here, per frame, instead of surfacing later."""
    take = opened_take(take_dir)
    if verify_decode:
        for _ in iter_frames(take, batch_size=32):
            pass
        if not take.decoder.checks_depth_with_rgb:  # a recording's RGB-D pairs: one pass checked both
            for _ in iter_depth(take):
                pass
    f = take.frames
    written = write_table("frames", {
        "take": [take.take_id] * len(f), "task": [take_task_name(take, task)] * len(f),
        "frame": [x.index for x in f], "time_s": take.timestamps_s,
        "status": [x.status for x in f], "message": [x.message or "" for x in f],
        "rgb_source": [str(x.rgb_source or "") for x in f], "depth_source": [str(x.depth_source or "") for x in f],
    }, warehouse)
    return Manifest.from_written("frames", written)


# --- 2. hand keypoints ---------------------------------------------------------------------------

@stage_task(name="detect_hands", version=INGEST_VERSION, key_ignore=("take_dir",),  # keyed on media_key
            key_optional=("variant",))
def detect_hands(take_dir: Path, task: str | None, warehouse: str, detector: str = "simulated",
                 detector_options: dict | None = None, frames: Manifest | None = None,
                 show_progress: bool = True, *, media_key: str, variant: dict | None = None) -> Manifest:
    """Run a detector backend over the take and keep the most confident left and right hand per frame.

    ``variant`` (every stage of the ingest): None writes the take's rows where every later stage reads
    them; ``{"detector": name}`` keeps them beside those (demoforge.schemas.core.variant_parts), for a second
    detector's ingest of the same take (demoforge.flows.ingest.ingest_side_by_side)."""
    from demoforge.lib.perception.detectors import get_detector  # imported when called: tests replace what it names

    take = opened_take(take_dir)
    det = get_detector(detector, **(detector_options or {}))
    bar = None
    if show_progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=take.n_frames, desc=f"{take.take_id} {detector}", unit="frame", leave=False)

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.update(done - bar.n)

    try:
        track = det.detect_take(take, progress=progress)
    finally:
        det.close()
        if bar is not None:
            bar.close()
    T = track.n_frames
    written = write_table("hand_keypoints", rows(
        take.take_id, take_task_name(take, task), T,
        detector=[track.detector] * (2 * T), detector_version=[track.detector_version] * (2 * T),
        present=track.present, confidence=np.nan_to_num(track.confidence),
        joints_cam=track.joints_cam, joints_px=track.joints_px,
        n_candidates=track.n_candidates.astype(np.int32),
    ), warehouse, variant)
    _save_detector_extra(take, track, warehouse)
    return Manifest.from_written("hand_keypoints", written)


def _save_detector_extra(take, track, warehouse: str) -> None:
    """Simulated detections carry what was injected (swaps, misses): kept for the metrics stage."""
    injected = track.extra.get("injected_swap")
    if injected is None:
        return
    d = Path(warehouse) / "_diagnostics" / "detector"
    d.mkdir(parents=True, exist_ok=True)
    tmp = d / f".{take.take_id}.{track.detector}.npz.tmp"
    with open(tmp, "wb") as fh:
        np.savez(fh, injected_swap=np.asarray(injected, bool))
    tmp.replace(d / f"{take.take_id}.{track.detector}.npz")


# --- 3. aligned keypoints ------------------------------------------------------------------------

class DepthError(UserError):
    """The take's depth cannot be trusted (one-line message: what is wrong and how to fix it)."""


@stage_task(name="align_keypoints", version=f"{INGEST_VERSION}/tracker-2", key_ignore=("take_dir",),  # keyed on media_key
            key_optional=("variant",))
def align_keypoints(take_dir: Path, task: str | None, warehouse: str, hand_keypoints: Manifest,
                    alignment: dict | None = None, tracker: dict | None = None,
                    accept_bad_depth: bool = False, *, media_key: str, variant: dict | None = None) -> Manifest:
    """Depth checks (demoforge.lib.ingest.depth_checks), hand tracking (demoforge.lib.perception.tracking), then depth
    alignment (thesis 3.1.2), outlier freeze and bounded gap filling; depth is streamed per batch.

    Raises :class:`DepthError` when the take's depth fails a check, unless ``accept_bad_depth``
    (then every row carries the problem in ``depth_problem`` and the tracker ignores depth)."""
    # imported when called: tests replace what it names
    from demoforge.lib.ingest.alignment import AlignmentConfig, align_to_depth, project, read_depth_robust

    take = opened_take(take_dir)
    name = take_task_name(take, task)
    hk = read_table("hand_keypoints", warehouse, variant=variant, task=name, take=take.take_id)
    T, a = arrays(hk, "joints_cam", "joints_px", "present", "confidence")
    detector = hk.column("detector")[0].as_py()
    cfg = AlignmentConfig(**(alignment or {}))
    tcfg = TrackerConfig(**(tracker or {}))
    tcfg = dataclasses.replace(tcfg, repair_identity=cfg.repair_swaps, swap_margin_px=cfg.swap_margin_px)
    joints_cam = np.where(a["present"][..., None, None], a["joints_cam"], np.nan)
    joints_px = np.where(a["present"][..., None, None], a["joints_px"], np.nan)
    have_px = np.isfinite(joints_px).all(axis=(2, 3)) | ~a["present"]
    uv_src = joints_px if have_px.all() else project(joints_cam, take.K)
    uv = uv_src[:, :, list(cfg.anchors), :]
    anchor_depth = np.full(uv.shape[:-1], np.nan)
    stats = DepthFrameStats.empty(T)
    for idx, depth in iter_depth(take):
        anchor_depth[idx], _ = read_depth_robust(depth, uv[idx], cfg.window, cfg.min_valid)
        fs = frame_depth_stats(depth, take.K, take.camera.T_world_camera)
        for f in dataclasses.fields(fs):
            getattr(stats, f.name)[idx] = getattr(fs, f.name)

    # the take's depth verdict: stop loudly rather than write hands a metre off
    present = a["present"] & np.isfinite(uv_src).all(axis=(2, 3))
    # the size check needs the detector's own 2D; 2D projected from its 3D would measure its depth error
    ratio = (depth_size_ratio(joints_cam, uv_src, anchor_depth, take.K) if have_px.all()
             else np.full(present.shape, np.nan))
    anchor_ok = np.isfinite(anchor_depth).sum(-1) >= cfg.min_anchors
    report = check_depth(stats, present, anchor_ok, ratio)
    if not report.ok and not accept_bad_depth:
        raise DepthError(f"take {take.take_id}: {report.message}")

    tr = track_hands(uv_src, present, a["confidence"], joints_cam=joints_cam, anchor_depth=anchor_depth,
                     K=take.K, config=tcfg, use_depth=report.ok and bool(have_px.all()))
    tt = np.arange(T)[:, None]
    src = np.where(tr.swapped[:, None], np.array([1, 0]), np.array([0, 1]))
    keep = tr.accepted[..., None, None]
    X = np.where(keep, joints_cam[tt, src], np.nan)
    P = np.where(keep, uv_src[tt, src], np.nan)
    res = align_to_depth(X, None, take.K, P if have_px.all() else None,
                         cfg.with_(repair_swaps=False, max_gap_frames=tcfg.max_gap_frames),
                         anchor_depth=anchor_depth[tt, src])
    world = transform_points(take.camera.T_world_camera, res.joints_cam.reshape(T, 2 * 21, 3)).reshape(T, 2, 21, 3)
    written = write_table("aligned_keypoints", rows(
        take.take_id, name, T, detector=[detector] * (2 * T),
        present=res.present, detected=res.detected, joints_cam=res.joints_cam, joints_world=world,
        translation=res.translation, anchors_used=res.anchors_used.astype(np.int64),
        n_anchors_valid=res.n_anchors_valid.astype(np.int32), no_depth=res.no_depth,
        depth_outlier=res.depth_outlier, outlier_frozen=res.outlier_frozen,
        swap_repaired=tr.swapped[:, None] & tr.detected, filled_missing=res.filled_missing,
        track_id=tr.track_id.astype(np.int32), rejected=list(np.asarray(REJECT_REASONS)[tr.rejected].reshape(-1)),
        depth_ratio=tr.depth_ratio, depth_problem=[report.problem] * (2 * T),
    ), warehouse, variant)
    return Manifest.from_written("aligned_keypoints", written)


@stage_task(name="hand_presence", version=f"{INGEST_VERSION}/depth-coverage-1", key_optional=("variant",))
def hand_presence(take_dir: Path, task: str | None, warehouse: str, aligned: Manifest,
                  tracker: dict | None = None, variant: dict | None = None) -> Manifest:
    """Per hand: frames detected / accepted / rejected / filled / tracked, the trust verdict and the
    share without depth at the hand (warned about above DepthCheckConfig.warn_missing_fraction)."""
    take = opened_take(take_dir)
    name = take_task_name(take, task)
    al = read_table("aligned_keypoints", warehouse, variant=variant, task=name, take=take.take_id)
    T, a = arrays(al, "present", "detected", "filled_missing", "track_id", "rejected", "no_depth")
    coverage = depth_coverage(a["detected"], a["no_depth"])
    warning = coverage_warning(take.take_id, coverage)
    if warning:
        from prefect import get_run_logger

        get_run_logger().warning(warning)
    detector = al.column("detector")[0].as_py()
    problem = al.column("depth_problem")[0].as_py()
    rej = a["rejected"].astype(str)
    seen = a["detected"] | (rej != "")
    trusted, reasons = hand_trust(a["present"], seen, a["detected"], TrackerConfig(**(tracker or {})))
    out = [{
        "take": take.take_id, "task": name, "detector": detector, "hand": hand, "frames": T,
        "frames_detected": int(seen[:, h].sum()), "frames_accepted": int(a["detected"][:, h].sum()),
        "frames_isolated": int((rej[:, h] == "isolated").sum()),
        "frames_depth_inconsistent": int((rej[:, h] == "depth_inconsistent").sum()),
        "frames_duplicate": int((rej[:, h] == "duplicate").sum()),
        "frames_filled": int(a["filled_missing"][:, h].sum()), "frames_tracked": int(a["present"][:, h].sum()),
        "tracks": int(a["track_id"][:, h].max() + 1) if T else 0,
        "trusted": bool(trusted[h]), "reason": reasons[h], "depth_problem": problem,
        "depth_missing_fraction": float(coverage.hand_missing[h]), "depth_missing_frame_fraction": coverage.frame_missing,
    } for h, hand in enumerate(HANDS)]
    written = write_table("hand_presence", pa.Table.from_pylist(out), warehouse, variant)
    return Manifest.from_written("hand_presence", written)


# --- 4. gripper poses ----------------------------------------------------------------------------

@stage_task(name="map_grippers", version=f"{INGEST_VERSION}/grasp-prior-1/depth-flag-1", key_optional=("variant",))
def map_grippers(take_dir: Path, task: str | None, warehouse: str, aligned: Manifest,
                 state_method: str = "auto", smoothing: int = 0, grasp_prior: str = "pose",
                 table_clearance: float | None = 0.010, variant: dict | None = None) -> Manifest:
    """The thesis's hand-to-gripper mapping per frame and arm, with all three open/close methods,
    then the rigid-grasp prior while a hand is closed and the table floor (see demoforge.lib.ingest.gripper_mapping)."""
    take = opened_take(take_dir)
    name = take_task_name(take, task)
    al = read_table("aligned_keypoints", warehouse, variant=variant, task=name, take=take.take_id)
    T, a = arrays(al, "joints_world", "present")
    detector = al.column("detector")[0].as_py()
    depth_problem = al.column("depth_problem")[0].as_py()
    pose7, dist = hand_to_gripper(a["joints_world"])
    g_thr = gripper_state(dist, "threshold")
    g_auto = gripper_state(dist, "auto")
    ranges = take.annotations.gripper_closed_ranges if take.annotations is not None else None
    ranges = ranges if ranges and any(ranges.values()) else None
    g_man = gripper_state(dist, "manual", closed_ranges=ranges) if ranges else None
    chosen_method = "manual" if g_man is not None else state_method
    g = g_man if g_man is not None else gripper_state(dist, state_method)
    if grasp_prior != "off":
        pose7 = stabilize_grasps(pose7, g, a["joints_world"], mode=grasp_prior)
    if smoothing:
        pose7 = smooth_poses(pose7, g, window=int(smoothing))
    if table_clearance is not None:
        pose7 = clamp_above_table(pose7, min_height=float(table_clearance))
    valid = a["present"] & np.isfinite(pose7).all(-1)
    pose = np.where(valid[..., None], to_pose8(pose7, g), np.nan)
    written = write_table("gripper_poses", rows(
        take.take_id, name, T, detector=[detector] * (2 * T), pose=pose, valid=valid,
        fingertip_distance=dist, g_threshold=g_thr.astype(np.int8), g_auto=g_auto.astype(np.int8),
        g_manual=None if g_man is None else g_man.astype(np.int8),
        state_method=[chosen_method] * (2 * T), depth_problem=[depth_problem] * (2 * T),
    ) | ({"g_manual": pa.nulls(2 * T, pa.int8())} if g_man is None else {}), warehouse, variant)
    return Manifest.from_written("gripper_poses", written)


# --- 5. object keypoints -------------------------------------------------------------------------

@stage_task(name="object_keypoints", version=f"{INGEST_VERSION}/annotate-1")
def object_keypoints(take_dir: Path, task: str | None, warehouse: str) -> Manifest | None:
    """Object keypoints at the first frame: ground truth for synthetic takes, else the 2D annotation
    back-projected with depth. None (nothing written) for a take not annotated yet: the stages
    before this one stand, and `demoforge annotate` is what is missing."""
    take = opened_take(take_dir)
    name = take_task_name(take, task)
    status = annotation_status(take)
    if not status.annotated:
        from prefect import get_run_logger

        get_run_logger().warning(not_annotated_message(take.path, status.detail))
        return None
    custom = take.annotations.task is not None and not take.annotations.task.library
    if take.has_ground_truth and not custom:  # a custom task's points exist only as clicked
        gt = unsliced_table(read_table_file("gt_object_keypoints", take.ground_truth_dir / "gt_object_keypoints.parquet"))
        first = gt.filter(pa.compute.equal(gt.column("frame"), 0))
        pts = np.array(first.column("keypoints_world")[0].as_py())
        names = _keypoint_names(take, len(pts))
        uv = np.full((len(pts), 1, 2), np.nan)
        data = {"point_world": pts, "valid": [True] * len(pts), "reason": ["ok"] * len(pts),
                "source": ["ground truth"] * len(pts)}
    else:
        ann = take.annotations
        names = _keypoint_names(take, len(ann.object_keypoints_uv))
        uv2 = np.asarray(ann.object_keypoints_uv, float)
        if ann.task is not None:  # the task's keypoint order, whatever order the file lists them in
            order = [names.index(k) for k in ann.task.keypoint_names]
            names, uv2 = [names[i] for i in order], uv2[order]
        _, depth = read_frame(take, ann.object_keypoints_frame or 0)
        r = backproject_keypoints_detailed(uv2, depth, take.K, take.camera.T_world_camera)
        uv = uv2[:, None, :]
        data = {"point_world": r.points_world, "valid": r.valid, "reason": r.reasons,
                "source": ["annotation+depth"] * len(names)}
    n = len(names)
    written = write_table("object_keypoints", {
        "take": [take.take_id] * n, "task": [name] * n, "keypoint": np.arange(n, dtype=np.int32),
        "name": list(names), "uv": uv, **data}, warehouse)
    return Manifest.from_written("object_keypoints", written)


def _keypoint_names(take: Any, n: int) -> list[str]:
    ann = take.annotations
    if ann is not None and len(ann.object_keypoint_names) == n:
        return list(ann.object_keypoint_names)
    return [f"keypoint_{i}" for i in range(n)]


def alignment_options(config: Any) -> dict:
    """A JSON-able dict of an AlignmentConfig (for cache keys and task parameters)."""
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(config).items()}
