"""`demoforge` commands of the export area (a sub-app composed into the root app)."""

from __future__ import annotations

import enum
from pathlib import Path
from typing import Optional

import typer

from demoforge.cli.root import TASK_HELP, current_warehouse, fail, gripper_option, robot_choice, robot_option
from demoforge.runtime.runners import run_flow

app = typer.Typer()


class ExportFormat(str, enum.Enum):
    lerobot = "lerobot"
    robomimic = "robomimic"


@app.command("export")
def export_cmd(
    fmt: ExportFormat = typer.Argument(
        ..., metavar="FORMAT",
        help="`lerobot`: a LeRobotDataset v3.0 folder (meta/info.json, meta/stats.json, meta/tasks.parquet, "
             "meta/episodes/, data/chunk-000/file-000.parquet ...). `robomimic`: one hdf5 file "
             "(data/demo_i/actions, obs/, next_obs/, src_* provenance attributes, mask/ splits)."),
    task: str = typer.Option(..., "--task", "-t", help="Task whose episode database to export. " + TASK_HELP),
    out: Path = typer.Option(..., "--out", "-o",
                             help="Output: a folder for lerobot, a .hdf5 file for robomimic. An earlier export "
                                  "of the same kind there is replaced atomically; anything else is refused."),
    take: Optional[str] = typer.Option(None, help="Only the episodes generated from this take (default: all "
                                                  "of the task's takes)."),
    include_invalid: bool = typer.Option(False, "--include-invalid",
                                         help="Also export episodes flagged invalid by the augmentation "
                                              "(left the workspace, grippers too close, objects overlap)."),
    limit: Optional[int] = typer.Option(None, "--limit", "-n", min=1,
                                        help="Export only the first N episodes (by take, then episode id; "
                                             "episode 0 is the demonstration)."),
    with_images: bool = typer.Option(
        False, "--with-images",
        help="lerobot only: also render every episode in MuJoCo (the grippers executing it, seen from its "
             "take's camera) and write it as the video feature observation.images.camera (mpeg4 mp4). Slow: "
             "a physics run and one rendered frame per step (see the README for the cost)."),
    image_size: Optional[str] = typer.Option(None, help="lerobot --with-images: WIDTHxHEIGHT of the images "
                                                        "(default: the take camera's resolution), e.g. 320x240."),
    valid_fraction: float = typer.Option(0.1, help="robomimic only: share of demos in the mask/valid split."),
    seed: int = typer.Option(0, help="robomimic only: seed of the train/valid split."),
    robot: str = robot_option(),
    gripper: Optional[str] = gripper_option(),
    unchecked: bool = typer.Option(False, "--unchecked", help="lerobot --robot aloha: export every selected episode "
                                   "the arms can reach, not only those whose robot check (`demoforge simulate "
                                   "--robot aloha`) succeeded."),
) -> None:
    """Export a task's episodes for robot-learning code: LeRobot v3.0 or robomimic hdf5.

    Each frame holds both grippers' current poses (observation) and the poses one step later
    (action): 16 float values, left arm first, each (x, y, z, qx, qy, qz, qw, g) in the world
    (table) frame, metres, g = 1 open / 0 closed, 30 steps per second, and the 11 object
    keypoints of the step (33 values: LeRobot's observation.environment_state, robomimic's
    obs/object). Every exported frame records its source take, episode id and kind.

    `export lerobot --robot aloha` writes joint space instead: 14 float values per step, the two
    ViperX arms' joints from inverse kinematics and their grippers' opening (left_waist ..
    left_wrist_rotate, left_gripper, right_...: the ALOHA datasets' names; rad, gripper 1 open / 0
    closed), of the episodes whose check with the arms succeeded (--unchecked: every episode they
    reach; an episode they cannot reach within 1 cm and 5 degrees is never written), images as
    observation.images.top.
    """
    from demoforge.flows.export import export_lerobot_flow, export_robomimic_flow, preflight_export  # lazy: prefect
    from demoforge.lib.exports import ExportError  # lazy (CLI start-up): numpy

    if not 0 <= valid_fraction < 1:
        raise fail(f"--valid-fraction must be in [0, 1), got {valid_fraction}")
    if (with_images or image_size) and fmt is not ExportFormat.lerobot:
        raise fail("--with-images and --image-size are for `export lerobot` only")
    robot, gripper = robot_choice(robot, gripper)
    if fmt is not ExportFormat.lerobot and robot != "grippers":
        raise fail(f"--robot {robot} (joint space) is for `export lerobot`; robomimic exports the grippers' poses")
    if unchecked and robot == "grippers":
        raise fail("--unchecked is for an arm robot's joint-space export (--robot aloha)")
    size = None
    if image_size is not None:
        try:
            size = tuple(int(v) for v in image_size.lower().split("x"))
            assert len(size) == 2 and min(size) >= 16 and size[0] % 2 == 0 and size[1] % 2 == 0
        except (ValueError, AssertionError):
            raise fail(f"--image-size must be WIDTHxHEIGHT, both even and at least 16, e.g. 320x240; got {image_size!r}")
        if not with_images:
            raise fail("--image-size needs --with-images")
    wh = str(current_warehouse())
    try:
        preflight_export(wh, task, str(out), fmt.value, take, with_images, robot, gripper, unchecked)  # before a Prefect run
        if fmt is ExportFormat.lerobot:
            m = run_flow(export_lerobot_flow, wh, task=task, out=str(out), take=take,
                         include_invalid=include_invalid, limit=limit, with_images=with_images, image_size=size,
                         robot=robot, gripper=gripper, unchecked=unchecked)
        else:
            m = run_flow(export_robomimic_flow, wh, task=task, out=str(out), take=take,
                         include_invalid=include_invalid, limit=limit, valid_fraction=valid_fraction, seed=seed)
    except ExportError as e:
        raise fail(str(e))
    typer.echo(f"{m.path}: {m.rows:,} frames of task {task} as {fmt.value} ({len(m.files)} files)")
    if robot != "grippers":
        import json

        source = json.loads((Path(m.path) / "meta" / "demoforge.json").read_text())
        left = source.get("left_out_unreachable", [])
        typer.echo(f"joint space of the {robot} arms ({gripper}); {len(left)} selected episode(s) the arms cannot "
                   "reach left out" + (" (meta/demoforge.json lists them)" if left else ""))


@app.command("view")
def view_cmd(
    target: str = typer.Argument(
        ..., metavar="TAKE_OR_EPISODE",
        help="A take folder, the id of a take in the warehouse (e.g. synth_pouring_s0000), or an episode "
             "as TASK/EPISODE_ID (e.g. pouring/42; episode 0 is the demonstration)."),
    rrd: Path = typer.Option(..., "--rrd", "-o", help="Output Rerun recording (.rrd); open it with `rerun FILE`."),
    take: Optional[str] = typer.Option(None, help="For TASK/EPISODE_ID: the episode database (source take); "
                                                  "default: the task's first."),
    point_stride: int = typer.Option(8, min=1, help="Take only: keep every n-th depth pixel (both ways) for "
                                                    "the point cloud."),
    frame_step: int = typer.Option(1, min=1, help="Take only: log every n-th frame."),
    images: bool = typer.Option(True, "--images/--no-images", help="Take only: log the RGB frames (JPEG)."),
    depth_images: bool = typer.Option(False, "--depth-images",
                                      help="Take only: also log the raw depth images (1.2 MB a frame)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing --rrd file."),
) -> None:
    """Save a Rerun recording of a take or an episode, offline (no viewer is started).

    A take shows the camera, its RGB frames and the point cloud back-projected from the depth into
    the world, the aligned hand skeletons, both gripper frames (x red = closing direction, z blue =
    approach), the object keypoints and the grippers' trajectories over time. An episode shows its
    gripper frames and trajectories, its object keypoints, and the demonstration's path for
    comparison. The take must be ingested first (`demoforge ingest TAKE`).
    """
    from demoforge.flows.view import preflight_view, view_flow  # lazy: prefect
    # lazy (CLI start-up): numpy
    from demoforge.lib.exports import ExportError
    from demoforge.lib.takes import TakeError

    if rrd.suffix != ".rrd":
        raise fail(f"--rrd {rrd} must end in .rrd")
    if rrd.exists() and not overwrite:
        raise fail(f"{rrd} already exists; choose another --rrd or pass --overwrite")
    try:
        preflight_view(str(current_warehouse()), target, take)
        r = run_flow(view_flow, str(current_warehouse()), target=target, out=str(rrd), take=take,
                     point_stride=point_stride, frame_step=frame_step, images=images, depth_images=depth_images,
                     overwrite=overwrite)
    except (ExportError, TakeError) as e:
        raise fail(str(e))
    what = f"take {r['take_id']}" if r["kind"] == "take" else f"episode {r['task']}/{r['episode_id']} ({r['take']})"
    typer.echo(f"{rrd}: {what}, {r['frames']} frames" +
               (f", {r['points']:,} points" if "points" in r else "") + "; open with `rerun " + str(rrd) + "`")
