"""Stages: a task's episodes exported to LeRobot v3.0 / robomimic, Rerun recordings, and the report plots.

Reading the warehouse happens here; the formats live in lib/exports and lib/evaluation/plots.py. Exports are
cached stages keyed on the content of the episode tables they read: exporting again with nothing
changed returns the manifest of the existing export, and a deleted or edited export is rewritten."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

import demoforge.lib  # noqa: F401
from demoforge.lib.exports import ExportError, task_instruction
from demoforge.tasks.common import Manifest, stage_task
from demoforge.tasks.screening import screened_pairs


EXPORT_VERSION = "3"  # 2: environment state, per-row provenance, LeRobot-style stats, images; 3: robots
_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")


@dataclass
class EpisodeSelection:
    """Episodes of one task database, concatenated: poses (F, 2, 8) and per-episode columns (N,)."""

    task: str
    poses: np.ndarray
    lengths: np.ndarray
    take: np.ndarray
    episode_id: np.ndarray
    kind: np.ndarray
    valid: np.ndarray
    transform: np.ndarray
    keypoints: np.ndarray
    sources: list[Path] = field(default_factory=list)

    @property
    def provenance(self) -> dict:
        return {"task": np.full(len(self.lengths), self.task), "take": self.take, "episode_id": self.episode_id,
                "kind": self.kind, "valid": self.valid, "transform": self.transform}


def _check_name(what: str, value: str) -> None:
    if not _NAME.match(value):
        raise ExportError(f"invalid {what} {value!r}: letters, digits, '_', '-' and '.' only")


def episode_files(warehouse: str, task: str, take: str | None = None) -> list[Path]:
    """The episodes and episode_steps files of a task (one take or all), the export's inputs."""
    from demoforge.schemas.core import table_files

    _check_name("task", task)
    part = {"task": task} | ({"take": take} if take else {})
    if take:
        _check_name("take", take)
    eps = table_files("episodes", warehouse, **part)
    if not eps:
        raise ExportError(f"no episodes of task {task!r}{' from take ' + take if take else ''} in {warehouse}; "
                          "run `demoforge augment TAKE` (or `make evaluate`) first")
    return eps + table_files("episode_steps", warehouse, **part)


def _read_steps(warehouse: str, task: str, take: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """episode_id, step and action (rows, 2, 8) of one take's episode_steps, as numpy.

    Read whole and selected in numpy: pyarrow 26.0.1 returns wrong values when it filters a nested
    fixed-size-list column whose chunk is a slice (as parquet reads give), in `filters=` and `.filter`.
    """
    from demoforge.schemas.core import column_numpy, read_parquet_file, table_files

    files = table_files("episode_steps", warehouse, task=task, take=take)
    if not files:
        return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 2, 8), np.float32)
    t = pa.concat_tables([read_parquet_file(f, "episode_steps", ["episode_id", "step", "action"]) for f in files])
    return t.column("episode_id").to_numpy(), t.column("step").to_numpy(), column_numpy(t, "action")


def load_episodes(warehouse: str, task: str, take: str | None = None, include_invalid: bool = False,
                  limit: int | None = None, only: set | None = None) -> EpisodeSelection:
    """A task's episodes (valid ones unless ``include_invalid``; only the (take, episode_id) pairs in
    ``only`` if given; the first ``limit`` by take and id)."""
    from demoforge.schemas.core import column_numpy, read_table

    if limit is not None and limit < 1:
        raise ExportError(f"--limit must be at least 1, got {limit}")
    files = episode_files(warehouse, task, take)
    part = {"task": task} | ({"take": take} if take else {})
    eps = read_table("episodes", warehouse, **part)
    takes = np.asarray(eps.column("take").to_pylist())
    ids = np.asarray(eps.column("episode_id").to_numpy())
    valid = np.asarray(eps.column("valid").to_numpy(zero_copy_only=False))
    order = np.lexsort((ids, takes))
    keep = order[valid[order]] if not include_invalid else order
    if only is not None:
        keep = keep[np.array([(t, int(i)) in only for t, i in zip(takes[keep], ids[keep])], bool)]
    if limit is not None:
        keep = keep[:limit]
    if len(keep) == 0 and only is not None:
        raise ExportError(f"task {task!r}: none of the episodes that passed the robot check is in the selection "
                          "(--take, --include-invalid)")
    if len(keep) == 0:
        raise ExportError(f"task {task!r} has no valid episodes in {warehouse}; pass --include-invalid to "
                          "export the flagged ones")
    poses, lengths = [], []
    for tk in dict.fromkeys(takes[keep].tolist()):  # takes in order
        want = ids[keep][takes[keep] == tk]        # ascending ids
        e, s, act = _read_steps(warehouse, task, tk)
        rows = np.flatnonzero(np.isin(e, want))
        rows = rows[np.lexsort((s[rows], e[rows]))]
        e_sel = e[rows]
        uniq, first, count = np.unique(e_sel, return_index=True, return_counts=True)
        missing = np.setdiff1d(want, uniq)
        if len(missing):
            raise ExportError(f"take {tk!r}: episodes {missing[:5].tolist()} have no steps in episode_steps; "
                              "re-run `demoforge augment`")
        if not (s[rows][first] == 0).all():
            raise ExportError(f"take {tk!r}: some episodes do not start at step 0 in episode_steps")
        poses.append(act[rows])
        lengths.append(count)
    lengths_all = np.concatenate(lengths).astype(np.int64)
    expected = np.asarray(eps.column("length").to_numpy())[keep]
    if not (lengths_all == expected).all():
        bad = np.flatnonzero(lengths_all != expected)[:5]
        raise ExportError(f"episode_steps disagree with episodes.length for episodes {ids[keep][bad].tolist()}; "
                          "re-run `demoforge augment`")
    return EpisodeSelection(
        task=task, poses=np.concatenate(poses).astype(np.float32, copy=False), lengths=lengths_all,
        take=takes[keep], episode_id=ids[keep], kind=np.asarray(eps.column("kind").to_pylist())[keep],
        valid=valid[keep], transform=column_numpy(eps, "transform")[keep],
        keypoints=column_numpy(eps, "object_keypoints")[keep], sources=files)


def subset(sel: EpisodeSelection, keep: np.ndarray) -> EpisodeSelection:
    """The selection's episodes where ``keep`` (N,) is true."""
    starts = np.concatenate([[0], np.cumsum(sel.lengths)[:-1]])
    rows = np.concatenate([np.arange(starts[i], starts[i] + sel.lengths[i]) for i in np.flatnonzero(keep)]) \
        if keep.any() else np.zeros(0, np.int64)
    return EpisodeSelection(task=sel.task, poses=sel.poses[rows], lengths=sel.lengths[keep], take=sel.take[keep],
                            episode_id=sel.episode_id[keep], kind=sel.kind[keep], valid=sel.valid[keep],
                            transform=sel.transform[keep], keypoints=sel.keypoints[keep], sources=sel.sources)


def checked_episodes(warehouse: str, task: str, robot: str, gripper: str, take: str | None = None) -> set:
    """(take, episode_id) of the episodes whose robot check with this robot and hand succeeded
    (`sim_outcomes`); an ExportError saying how to run the check when there are none."""
    from demoforge.schemas.catalog import query

    rows = query("SELECT take, episode_id FROM sim_outcomes WHERE task = ? AND robot = ? AND gripper = ? "
                 "AND success AND (? IS NULL OR take = ?)", warehouse, [task, robot, gripper, take, take]).to_pylist()
    if not rows:
        raise ExportError(f"no episode of task {task!r} passed the robot check with --robot {robot} --gripper "
                          f"{gripper}: run `demoforge simulate --task {task} --robot {robot} --gripper {gripper}` "
                          "first, or pass --unchecked to export every episode the arms can reach")
    return {(r["take"], int(r["episode_id"])) for r in rows}


def check_files(warehouse: str, task: str, robot: str, gripper: str) -> list[Path]:
    """The `sim_results` files of a task and robot: the robot check an export's selection depends on."""
    from demoforge.schemas.core import table_files

    return table_files("sim_results", warehouse, task=task, robot=robot, gripper=gripper)


def _export_manifest(kind: str, out: Path, rows: int) -> Manifest:
    from demoforge.schemas.core import WrittenFile, file_sha256

    files = [out] if out.is_file() else sorted(p for p in out.rglob("*") if p.is_file())
    written = [WrittenFile(kind, str(p), rows if i == 0 else 0, file_sha256(p)) for i, p in enumerate(files)]
    m = Manifest.from_written(kind, written, path=out)
    return Manifest(m.table, m.path, rows, m.content_hash, m.files)


def export_lerobot(warehouse: str, task: str, out: str, take: str | None = None, include_invalid: bool = False,
                   limit: int | None = None, overwrite: bool = False, with_images: bool = False,
                   image_size: tuple[int, int] | None = None, progress: bool = False, robot: str = "grippers",
                   gripper: str | None = None, unchecked: bool = False) -> dict:
    """Write the export (no Prefect): returns the validator's summary plus the output path.

    with_images: render every episode in MuJoCo (lib/sim/render.py) from its take's camera, at
    the camera's resolution or ``image_size`` (width, height), as ``observation.images.<camera>``.
    robot: `grippers` writes the two grippers' poses; an arm robot (`aloha`) writes its joint values
    (lib/exports/joint_space.py) of the episodes whose robot check with it succeeded (every selected
    one with ``unchecked``) and, where the database is screened for it, its screening let through, leaving
    out any episode its IK cannot reach, and its images as `top`.
    """
    from demoforge.lib.exports.lerobot import (
        ROBOT_TYPE, keypoint_feature_names, validate_lerobot_dataset, write_lerobot_dataset,
    )
    from demoforge.lib.exports.object_state import episode_object_keypoints
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task

    arm = get_robot(robot, gripper)
    joints = arm.joint_names
    only = None if not joints or unchecked else checked_episodes(warehouse, task, arm.name, arm.gripper_name, take)
    screened = screened_pairs(warehouse, task, arm.label, take) if joints else None
    if screened is not None:  # an arm robot exports only what its screening lets through
        only = screened if only is None else only & screened
    sel = load_episodes(warehouse, task, take, include_invalid, limit, only=only)
    joint_state, joint_source, dropped, demonstrated = None, {}, [], sel
    if joints:
        sel, joint_state, dropped, demonstrated, scale = _reachable_joint_space(arm, sel, progress)
        joint_source = {"robot": arm.name, "gripper": arm.gripper_name, "state": list(joints),
                        "check": ("unchecked: every selected episode the arms reach" if unchecked else
                                  f"sim_results success with robot {arm.name}, gripper {arm.gripper_name}")
                                 + (f"; screened in for {arm.label} (episode_screening)" if screened is not None else ""),
                        "trajectory": "as the arms run it, at the dataset's fps: from their ready pose, joint-space "
                                      "transits into and out of each arm's skill segments, the segments through "
                                      "inverse kinematics, slowed where a joint would exceed its servo's speed "
                                      "(lib/sim/robots/arm_motion.py)",
                        "time_scale": [round(float(x), 4) for x in scale],
                        "left_out_unreachable": dropped}
    spec = get_task(task)
    env = episode_object_keypoints(sel.poses, sel.lengths, sel.keypoints, spec.keypoint_object)
    # the video: each episode executed again by the robot from its demonstrated poses (the frames it runs)
    videos = [episode_video_source(warehouse, demonstrated, image_size, robot=arm)] if with_images else None
    write_lerobot_dataset(
        out, sel.poses, sel.lengths, tasks=[task_instruction(task)],
        provenance={"take": sel.take, "episode_id": sel.episode_id, "kind": sel.kind, "valid": sel.valid},
        environment_state=env.reshape(len(env), -1), environment_names=keypoint_feature_names(spec.keypoint_names),
        joint_state=joint_state, state_names=list(joints) if joints else None,
        robot_type=arm.name if joints else ROBOT_TYPE, videos=videos, progress=progress,
        source={"generator": "demoforge", "task": task, "takes": sorted(set(sel.take.tolist())),
                "include_invalid": include_invalid, "limit": limit, "with_images": with_images,
                "pose": "[x, y, z, qx, qy, qz, qw, g] per arm, world (table) frame, m; g 1 = open",
                "environment_state": "the 11 object keypoints per step, world m, carried rigidly by the gripper "
                                     "of the arm that handles the object while it is closed "
                                     "(lib/exports/object_state.py)",
                "episode_index_to_source": "data columns demoforge.take, demoforge.episode_id, demoforge.kind; "
                                           "meta/episodes columns demoforge/take, demoforge/episode_id",
                **joint_source},
        overwrite=overwrite)
    return {**validate_lerobot_dataset(out), "path": str(out), "left_out_unreachable": len(dropped)}


def _reachable_joint_space(arm, sel: EpisodeSelection, progress: bool):
    """(the episodes the arms reach as they execute them: executed poses and lengths, their joint values
    (F', D), the left-out episodes as [take, id, worst position error m, worst rotation error deg], the
    kept episodes as demonstrated, and each kept episode's time-scale)."""
    from tqdm.auto import tqdm

    from demoforge.lib.exports.joint_space import joint_episodes

    with tqdm(total=len(sel.lengths), desc=f"{sel.task}: inverse kinematics ({arm.label})", unit="episode",
              disable=not progress) as bar:
        js = joint_episodes(arm, sel.task, sel.poses, sel.lengths, sel.keypoints,
                            progress=lambda i: bar.update(i - bar.n))
    dropped = [[str(t), int(e), round(float(p), 4), round(float(r), 2)]
               for t, e, p, r, k in zip(sel.take, sel.episode_id, js.position_error, js.rotation_error, js.keep)
               if not k]
    if not js.keep.any():
        raise ExportError(f"task {sel.task!r}: the {arm.label} arms cannot reach any of the {len(sel.lengths)} "
                          f"selected episodes (the first's worst residual: {js.position_error[0] * 1000:.0f} mm, "
                          f"{js.rotation_error[0]:.1f} deg); `demoforge simulate --robot {arm.name}` says why")
    kept = subset(sel, js.keep)
    executed = EpisodeSelection(task=kept.task, poses=js.poses, lengths=js.lengths, take=kept.take,
                                episode_id=kept.episode_id, kind=kept.kind, valid=kept.valid, transform=kept.transform,
                                keypoints=kept.keypoints, sources=kept.sources)
    return executed, js.joints, dropped, kept, js.time_scale[js.keep]


def take_cameras(warehouse: str, takes: list[str]) -> dict:
    """{take: CameraInfo} from each take's camera.json (folder from the warehouse's `takes` table)."""
    from demoforge.lib.takes.reader import TakeError, parse_camera
    from demoforge.schemas.core import read_table, table_files

    rows = {r["take"]: r["path"] for r in read_table("takes", warehouse, columns=["take", "path"]).to_pylist()} \
        if table_files("takes", warehouse) else {}
    out = {}
    for tk in takes:
        cam = Path(rows.get(tk, "")) / "camera.json"
        if tk not in rows or not cam.is_file():
            raise ExportError(f"--with-images needs take {tk}'s camera: {'its folder ' + rows[tk] if tk in rows else 'the take'}"
                              f" is not {'there' if tk in rows else 'registered in ' + warehouse}; run "
                              "`demoforge ingest TAKE_FOLDER` (or export without --with-images)")
        try:
            out[tk] = parse_camera(json.loads(cam.read_text()), cam)
        except (TakeError, ValueError) as e:
            raise ExportError(f"--with-images: {e}")
    return out


def episode_video_source(warehouse: str, sel: EpisodeSelection, image_size: tuple[int, int] | None = None,
                         robot=None):
    """The video of an export: each episode executed by the robot (default the grippers: key `camera`;
    an arm robot: key `top`, the camera above and between the arms) in MuJoCo and drawn from its take's
    camera (K scaled to ``image_size`` (width, height) when given; default the first take's resolution)."""
    from demoforge.lib.sim import SimOptions
    from demoforge.lib.exports.lerobot import VideoSource
    from demoforge.lib.sim.render import episode_frames

    cams = take_cameras(warehouse, list(dict.fromkeys(sel.take.tolist())))
    first = next(iter(cams.values()))
    width, height = image_size or (first.width, first.height)
    if width < 16 or height < 16 or width % 2 or height % 2:
        raise ExportError(f"--image-size must be even and at least 16 x 16 (mpeg4 video), got {width}x{height}")
    starts = np.concatenate([[0], np.cumsum(sel.lengths)[:-1]])

    def frames(i: int):
        cam = cams[sel.take[i]]
        K = np.diag([width / cam.width, height / cam.height, 1.0]) @ cam.K
        acts = sel.poses[starts[i]:starts[i] + sel.lengths[i]].astype(np.float64)
        try:
            yield from episode_frames(sel.task, sel.keypoints[i], acts, K, cam.T_world_camera, width, height,
                                      options=options)
        except ValueError as e:
            raise ExportError(f"episode {sel.episode_id[i]} of take {sel.take[i]}: {e}")

    arms = robot is not None and bool(robot.joint_names)
    options = SimOptions(robot=robot, stop_on_hard_failure=False, stop_when_settled=True) if robot is not None else None
    return VideoSource("top" if arms else "camera", width, height, frames)


def export_robomimic(warehouse: str, task: str, out: str, take: str | None = None, include_invalid: bool = False,
                     limit: int | None = None, overwrite: bool = False, valid_fraction: float = 0.1,
                     seed: int = 0) -> dict:
    from demoforge.lib.exports.robomimic import write_robomimic_hdf5
    from demoforge.lib.task_library import get_task

    from demoforge.lib.exports.object_state import episode_object_keypoints

    sel = load_episodes(warehouse, task, take, include_invalid, limit)
    spec = get_task(task)
    summary = write_robomimic_hdf5(
        out, sel.poses, sel.lengths, keypoints=sel.keypoints, provenance=sel.provenance,
        object_state=episode_object_keypoints(sel.poses, sel.lengths, sel.keypoints, spec.keypoint_object),
        env_name=f"demoforge/{task}",
        env_kwargs={"task": task, "instruction": task_instruction(task), "objects": list(spec.object_names),
                    "keypoint_names": list(spec.keypoint_names), "control_freq": 30},
        valid_fraction=valid_fraction, seed=seed, overwrite=overwrite)
    return {**summary, "path": str(out)}


@stage_task(name="export_lerobot", version=EXPORT_VERSION)
def export_lerobot_stage(sources: list[Path], warehouse: str, task: str, out: str, take: str | None,
                         include_invalid: bool, limit: int | None, with_images: bool = False,
                         image_size: tuple[int, int] | None = None, robot: str = "grippers",
                         gripper: str | None = None, unchecked: bool = False) -> Manifest:
    """Cached on the content of `sources` (the task's episode tables, and for an arm robot its
    `sim_results` files) and the options."""
    summary = export_lerobot(warehouse, task, out, take, include_invalid, limit, overwrite=True,
                             with_images=with_images, image_size=image_size, progress=with_images or robot != "grippers",
                             robot=robot, gripper=gripper, unchecked=unchecked)
    return _export_manifest("export_lerobot", Path(out), summary["frames"])


@stage_task(name="export_robomimic", version=EXPORT_VERSION)
def export_robomimic_stage(sources: list[Path], warehouse: str, task: str, out: str, take: str | None,
                           include_invalid: bool, limit: int | None, valid_fraction: float, seed: int) -> Manifest:
    summary = export_robomimic(warehouse, task, out, take, include_invalid, limit, overwrite=True,
                               valid_fraction=valid_fraction, seed=seed)
    return _export_manifest("export_robomimic", Path(out), summary["samples"])


def refuse_to_replace_foreign_output(out: Path, marker: str | None) -> None:
    """An existing --out is only replaced when it is an export of the same kind (never a random folder)."""
    if not out.exists():
        return
    if marker is None and out.is_file():
        from demoforge.lib.exports.robomimic import is_demoforge_robomimic

        if is_demoforge_robomimic(out):
            return
    if marker is not None and (out / marker).is_file():
        return
    raise ExportError(f"{out} exists and is not a demoforge export of this kind; choose another --out")


def preflight_export(warehouse: str, task: str, out: str, fmt: str, take: str | None = None,
                     with_images: bool = False, robot: str = "grippers", gripper: str | None = None,
                     unchecked: bool = False) -> None:
    """The checks that need no Prefect run: known task, episodes present, --out not someone else's,
    with images every source take's camera, and for an arm robot's export (unless unchecked) episodes
    whose check with it passed."""
    from demoforge.lib.task_library import TASK_NAMES

    if task not in TASK_NAMES:
        raise ExportError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    if fmt == "robomimic" and Path(out).suffix not in (".hdf5", ".h5"):
        raise ExportError(f"--out {out} must end in .hdf5 (or .h5) for robomimic")
    refuse_to_replace_foreign_output(Path(out).resolve(), "meta/info.json" if fmt == "lerobot" else None)
    files = episode_files(warehouse, task, take)
    if robot != "grippers" and not unchecked:
        from demoforge.lib.sim.robots import get_robot

        arm = get_robot(robot, gripper)
        checked_episodes(warehouse, task, arm.name, arm.gripper_name, take)
    if with_images:
        take_cameras(warehouse, [take] if take else sorted({f.parent.name.split("=", 1)[1] for f in files
                                                            if f.parent.name.startswith("take=")}))


def preflight_view(warehouse: str, target: str, take: str | None = None) -> dict:
    """Resolve TAKE_OR_EPISODE and check that it exists, before any Prefect run."""
    from demoforge.schemas.core import read_table

    from demoforge.schemas.core import table_files

    what = resolve_view_target(warehouse, target, take)
    if what["kind"] == "take" and not table_files("gripper_poses", warehouse, take=what["take_id"]):
        raise ExportError(f"take {what['take_id']} is not ingested in {warehouse}; run "
                          f"`demoforge ingest {what['path']}` first")
    if what["kind"] == "episode":
        eps = read_table("episodes", warehouse, columns=["episode_id"], task=what["task"], take=what["take"])
        if what["episode_id"] not in set(eps.column("episode_id").to_pylist()):
            raise ExportError(f"task {what['task']!r} (take {what['take']}) has no episode {what['episode_id']}")
    return what


# ------------------------------------------------------------------------------------------- Rerun view

def _episode_poses(warehouse: str, task: str, take: str, episode_id: int) -> np.ndarray:
    e, s, act = _read_steps(warehouse, task, take)
    rows = np.flatnonzero(e == int(episode_id))
    if len(rows) == 0:
        raise ExportError(f"episode {episode_id} of task {task!r} (take {take}) has no steps; list the "
                          "episodes with `demoforge sql \"SELECT episode_id, kind, valid FROM episodes WHERE "
                          f"task = '{task}'\"`")
    return act[rows[np.argsort(s[rows], kind="stable")]].astype(np.float64)


def resolve_view_target(warehouse: str, target: str, take: str | None = None) -> dict:
    """What `demoforge view TARGET` means: a take folder, an ingested take's id, or TASK/EPISODE_ID."""
    from demoforge.schemas.core import read_table, table_files

    p = Path(target)
    if p.is_dir():
        return {"kind": "take", "take_id": p.name, "path": p.resolve()}
    m = re.fullmatch(r"([A-Za-z0-9_]+)[/:](\d+)", target)
    if m:
        task, eid = m.group(1), int(m.group(2))
        _check_name("task", task)
        if take is None:
            takes = sorted({f.parent.name.split("=", 1)[1] for f in table_files("episodes", warehouse, task=task)})
            if not takes:
                raise ExportError(f"no episodes of task {task!r} in {warehouse}; run `demoforge augment` first")
            take = takes[0]
        return {"kind": "episode", "task": task, "take": take, "episode_id": eid}
    _check_name("take", target)
    rows = read_table("takes", warehouse).filter(pc.field("take") == target).to_pylist() \
        if table_files("takes", warehouse) else []
    if rows and Path(rows[0]["path"]).is_dir():
        return {"kind": "take", "take_id": target, "path": Path(rows[0]["path"])}
    raise ExportError(f"{target!r} is neither a take folder, a take registered in the warehouse, nor "
                      "TASK/EPISODE_ID (e.g. pouring/0)")


def write_view(warehouse: str, target: str, out: str, take: str | None = None, point_stride: int = 8,
               frame_step: int = 1, images: bool = True, depth_images: bool = False,
               overwrite: bool = False) -> dict:
    """Write the Rerun recording of a take or an episode to ``out``; returns what was logged."""
    from demoforge.lib.exports.rerun_view import TakeFrame, write_episode_recording, write_take_recording
    from demoforge.lib.takes import iter_frames, open_take
    from demoforge.lib.task_library import TASK_NAMES, get_task
    from demoforge.schemas.core import column_numpy, read_table

    if frame_step < 1:
        raise ExportError(f"--frame-step must be at least 1, got {frame_step}")
    what = resolve_view_target(warehouse, target, take)
    if what["kind"] == "episode":
        task, tk, eid = what["task"], what["take"], what["episode_id"]
        eps = read_table("episodes", warehouse, task=task, take=tk)
        row = np.flatnonzero(eps.column("episode_id").to_numpy() == eid)
        if len(row) == 0:
            raise ExportError(f"task {task!r} (take {tk}) has no episode {eid}")
        poses = _episode_poses(warehouse, task, tk, eid)
        ref = _episode_poses(warehouse, task, tk, 0) if eid != 0 else None
        names = get_task(task).keypoint_names if task in TASK_NAMES else None
        counts = write_episode_recording(out, name=f"{task}/{tk}/{eid}", poses=poses,
                                         object_keypoints=column_numpy(eps, "object_keypoints")[row[0]],
                                         keypoint_names=names, reference=ref, overwrite=overwrite)
        return {**what, **counts, "path": str(out)}

    take_obj = open_take(what["path"])
    tid = take_obj.take_id
    gp = read_table("gripper_poses", warehouse, take=tid)
    if gp.num_rows == 0:
        raise ExportError(f"take {tid} is not ingested in {warehouse}; run `demoforge ingest {what['path']}` first")
    T = take_obj.n_frames
    hands = np.full((T, 2, 21, 3), np.nan)
    present = np.zeros((T, 2), bool)
    grippers = np.full((T, 2, 8), np.nan)
    al = read_table("aligned_keypoints", warehouse, take=tid)
    g_hand, g_frame = np.asarray(gp.column("hand").to_pylist()), gp.column("frame").to_numpy()
    g_valid, g_pose = gp.column("valid").to_numpy(zero_copy_only=False), column_numpy(gp, "pose")
    a_hand, a_frame = np.asarray(al.column("hand").to_pylist()), al.column("frame").to_numpy()
    a_present, a_joints = al.column("present").to_numpy(zero_copy_only=False), column_numpy(al, "joints_world")
    for arm, hand in enumerate(("left", "right")):
        m = (g_hand == hand) & g_valid
        grippers[g_frame[m], arm] = g_pose[m]
        m = a_hand == hand
        hands[a_frame[m], arm] = a_joints[m]
        present[a_frame[m], arm] = a_present[m]
    ok_t = read_table("object_keypoints", warehouse, take=tid).sort_by("keypoint")
    kp = column_numpy(ok_t, "point_world") if ok_t.num_rows else None
    wanted = list(range(0, T, frame_step))

    def frames():
        for batch in iter_frames(take_obj, frames=wanted):
            for i, idx in enumerate(batch.indices.tolist()):
                yield TakeFrame(idx, idx / take_obj.fps, batch.rgb[i], batch.depth[i])

    cam = take_obj.camera
    counts = write_take_recording(out, take_id=tid, K=cam.K, T_world_camera=cam.T_world_camera, width=cam.width,
                                  height=cam.height, frames=frames(), hands_world=hands, hands_present=present,
                                  gripper_poses=grippers, object_keypoints=kp,
                                  keypoint_names=ok_t.column("name").to_pylist() if kp is not None else None,
                                  point_stride=point_stride, log_images=images,
                                  log_depth_images=depth_images, overwrite=overwrite)
    return {"kind": "take", "take_id": tid, **counts, "path": str(out)}


# ------------------------------------------------------------------------------------------ report plots

def _episodes_by_id(steps: tuple[np.ndarray, np.ndarray, np.ndarray], ids, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Episode ids and actions (rows, 2, 8) of the given episodes (all when ``ids`` is None), every n-th
    step, from one take's ``_read_steps`` (read once per take: it is most of the plots' input time)."""
    e, s, act = steps
    m = np.ones(len(e), bool) if ids is None else np.isin(e, np.asarray(ids))
    if every > 1:
        m &= s % every == 0
    return e[m], act[m].astype(np.float64)
