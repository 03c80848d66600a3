"""Stages: a task's episodes exported to LeRobot v3.0 / robomimic.

The episodes are read through the warehouse's read layer (demoforge.schemas.reads.episodes); the formats
live in lib/exports. Exports are cached stages keyed on the content of the episode tables they read:
exporting again with nothing changed returns the manifest of the existing export, and a deleted or edited
export is rewritten."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demoforge.lib.exports import ExportError, task_instruction
from demoforge.lib.exports.joint_space import joint_episodes
from demoforge.lib.exports.lerobot import (
    ROBOT_TYPE, VideoSource, keypoint_feature_names, validate_lerobot_dataset, write_lerobot_dataset,
)
from demoforge.lib.exports.object_state import episode_object_keypoints
from demoforge.lib.exports.robomimic import write_robomimic_hdf5
from demoforge.lib.sim import SimOptions
from demoforge.lib.sim.render import episode_frames
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.task_library import get_task
from demoforge.schemas.core import WrittenFile, file_sha256
from demoforge.schemas.reads.episodes import (
    EpisodeSelection, checked_episodes, load_episodes, subset, take_cameras,
)
from demoforge.tasks.common import Manifest, stage_task
from demoforge.tasks.screening import screened_pairs


EXPORT_VERSION = "3"  # 2: environment state, per-row provenance, LeRobot-style stats, images; 3: robots


def _export_manifest(kind: str, out: Path, rows: int) -> Manifest:
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


def episode_video_source(warehouse: str, sel: EpisodeSelection, image_size: tuple[int, int] | None = None,
                         robot=None):
    """The video of an export: each episode executed by the robot (default the grippers: key `camera`;
    an arm robot: key `top`, the camera above and between the arms) in MuJoCo and drawn from its take's
    camera (K scaled to ``image_size`` (width, height) when given; default the first take's resolution)."""
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
