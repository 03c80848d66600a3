"""`demoforge synth`, `annotate`, `ingest`, `ingest-folder`: takes in, gripper trajectories out."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional
import click
import typer

from demoforge.runtime.runners import run_flow
from demoforge.cli.root import TASK_HELP, current_warehouse, detector_option, fail, warn

app = typer.Typer()


@app.command()
def synth(
    task: List[str] = typer.Option(["pouring"], "--task", "-t", help="Task(s) to generate (repeatable), or `all`. " + TASK_HELP),
    takes: int = typer.Option(1, "--takes", "-n", min=1, help="Takes per task (seeds seed, seed+1, ...)."),
    seed: int = typer.Option(0, help="First seed; a take is fully determined by (task, seed, mirror)."),
    mirror: bool = typer.Option(False, "--mirror", help="Write the mirrored variant (hands' roles swapped)."),
    both: bool = typer.Option(False, "--both", help="Write the original and the mirrored variant."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Folder for the take folders. Default: <warehouse>/synthetic."),
    depth_noise: bool = typer.Option(True, help="Add realistic depth noise and holes (0 = invalid)."),
    video: bool = typer.Option(True, help="Also write rgb.mp4 per take."),
    max_frames: Optional[int] = typer.Option(None, help="Keep only the first N frames (previews)."),
    hand_style: str = typer.Option("capsule", "--hand-style", help="Look of the hands: capsule (default) or skin (palm, forearm, sleeve, nails: what a real detector finds far more often; the depth at the wrist and thumb base differs from what the ingest's alignment assumes, see README). The ground truth is the same."),
) -> None:
    """Generate synthetic RGB-D demonstrations with exact ground truth (MuJoCo renders).

    Each take folder has the layout of a real recording (rgb/, depth/, camera.json,
    annotations.json, rgb.mp4) plus ground_truth/ tables; takes are registered in the `takes`
    table and their ground truth in the gt_* tables of the warehouse.
    """
    from demoforge.flows.synth import synthesize_takes  # lazy: mujoco, prefect
    from demoforge.lib.task_library import TASK_NAMES  # lazy (CLI start-up): numpy, scipy

    tasks = list(TASK_NAMES) if "all" in task else task
    unknown = [t for t in tasks if t not in TASK_NAMES]
    if unknown:
        raise fail(f"unknown task(s) {unknown}; choose from: all, {', '.join(TASK_NAMES)}")
    if hand_style not in ("skin", "capsule"):
        raise fail(f"--hand-style must be skin or capsule, got {hand_style!r}")
    manifests = run_flow(
        synthesize_takes,
        str(current_warehouse()), tasks=tasks, takes=takes, seed=seed,
        mirror="both" if both else ("yes" if mirror else "no"),
        takes_dir=str(out) if out else None, depth_noise=depth_noise, video=video, max_frames=max_frames,
        hand_style=hand_style,
    )
    for m in manifests:
        typer.echo(m.path)


TAKE_HELP = ("Take: a take folder (rgb/ or .mp4, depth/, camera.json) or a recording: RealSense .bag/.db3, "
             "Record3D .r3d or export folder, ROS 2 bag (.mcap, .db3 or its folder).")
RGB_TOPIC = typer.Option(None, "--rgb-topic", help="ROS 2 bag: the colour topic (Image or CompressedImage); default: found from the topic list. Remembered in the bag's side folder.")
DEPTH_TOPIC = typer.Option(None, "--depth-topic", help="ROS 2 bag: the depth topic aligned to colour (16UC1 mm or 32FC1 m).")
INFO_TOPIC = typer.Option(None, "--info-topic", help="ROS 2 bag: the colour camera's CameraInfo topic.")


def _open_take_or_fail(path: Path, require_pose: bool = True, rgb_topic: Optional[str] = None,
                       depth_topic: Optional[str] = None, info_topic: Optional[str] = None):
    """The opened take, or a one-line error (exit 2) before any flow starts: missing folder or recording,
    missing or malformed camera.json / annotations.json, an unreadable recording, no camera pose.
    Topics given are remembered in the recording's side folder; a recording's notes go to stderr."""
    # lazy (CLI start-up): numpy
    from demoforge.lib.takes import TakeError, open_take
    from demoforge.lib.takes.sources import remember_options

    if not path.exists():
        raise fail(f"{path}: no such take folder or recording file")
    try:
        if rgb_topic or depth_topic or info_topic:
            if path.is_dir() and (path / "camera.json").is_file():
                raise TakeError("--rgb-topic/--depth-topic/--info-topic are for ROS 2 bags, not take folders")
            remember_options(path, rgb_topic=rgb_topic, depth_topic=depth_topic, info_topic=info_topic)
        take = open_take(path, require_pose=require_pose)
    except (TakeError, FileNotFoundError) as e:
        raise fail(str(e))
    if take.rgb_kind == "recording":  # a recording's notes: pairing tolerance, dropped frames, depth scale
        for note in take.notes:
            typer.echo(f"note: {note}", err=True)
    return take


@app.command()
def annotate(
    path: Path = typer.Argument(..., help=TAKE_HELP),
    task: Optional[str] = typer.Option(None, "--task", "-t", help="Task of the take (pouring, ...), or `custom` / "
                                       "`custom:NAME` (with --keypoints) for a task of your own. Default: what "
                                       "annotations.json says."),
    keypoints: Optional[str] = typer.Option(None, "--keypoints", help="For --task custom: 11 keypoint names, comma "
                                            "separated; `object:name` puts a keypoint on an object (at most two objects)."),
    task_file: Optional[Path] = typer.Option(None, "--task-file", help='A task of your own as JSON: {"name": ..., '
                                             '"objects": [{"name": ..., "arm": "left"|"right", "keypoints": [...]}]}.'),
    port: int = typer.Option(8765, "--port", "-p", min=0, max=65535, help="Port on 127.0.0.1 (0: any free port)."),
    open_browser: bool = typer.Option(False, "--open", help="Also open the page in the default browser."),
    rgb_topic: Optional[str] = RGB_TOPIC, depth_topic: Optional[str] = DEPTH_TOPIC,
    info_topic: Optional[str] = INFO_TOPIC,
) -> None:
    """Annotate a take in the browser: click the object keypoints, mark gripper open/close ranges, save.

    Serves a page on 127.0.0.1 until Ctrl-C, at the printed URL: it carries this run's token, and the
    server answers nothing without it (nor another web page's requests). It shows the frames (scrub with the slider or
    the arrow keys), asks for the task's keypoints one by one and shows each click's depth and world
    position, and plots the fingertip distance of an earlier `demoforge ingest` with the automatic
    method's closed ranges pre-filled. Save writes TAKE/annotations.json (an existing one is edited; a
    recording's go to its side folder RECORDING.demoforge/). A take whose camera pose is not known yet
    can be calibrated on the page (a board on the table, or the table plane and two clicks on its
    robot-side edge), as `demoforge calibrate` does.
    """
    # lazy (CLI start-up): numpy, pyarrow, scipy
    from demoforge.runtime.annotate import AnnotationSession, server_url, start_server
    from demoforge.lib.takes import TakeError

    _open_take_or_fail(path, require_pose=False, rgb_topic=rgb_topic, depth_topic=depth_topic, info_topic=info_topic)
    try:
        session = AnnotationSession(path, current_warehouse(), task=task, keypoints=keypoints, task_file=task_file)
    except TakeError as e:
        raise fail(str(e))
    try:
        server = start_server(session, port=port)
    except OSError as e:
        raise fail(f"cannot listen on 127.0.0.1:{port} ({e.strerror or e}); choose another --port")
    url = server_url(server)
    typer.echo(f"annotating {session.take.path} (task {session.task.name}): open {url}  (Ctrl-C to stop)", err=True)
    typer.echo(url)
    if open_browser:
        import webbrowser

        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()


@app.command()
def ingest(
    path: Path = typer.Argument(..., help=TAKE_HELP),
    detector: str = detector_option(help="simulated: synthetic takes; hamer: a local checkpoint."),
    predictions: Optional[Path] = typer.Option(None, help="For --detector precomputed: thesis-code keypoint JSON, or Parquet/NPZ predictions."),
    task: Optional[str] = typer.Option(None, help="Task of the take (needed later to augment a recorded take)."),
    state_method: str = typer.Option("auto", help="Open/close when the take has no labelled ranges: auto, otsu or threshold."),
    smoothing: int = typer.Option(0, help="Segment-wise pose smoothing window in frames (0 = off)."),
    video: bool = typer.Option(False, "--video", help="Also write an MP4 with the skeletons and gripper frames drawn on the frames."),
    hamer_checkpoint: Optional[Path] = typer.Option(None, "--hamer-checkpoint", help="For --detector hamer: local hamer.ckpt (licensed; never downloaded)."),
    mano_model: Optional[Path] = typer.Option(None, "--mano-model", help="For --detector hamer: local MANO_RIGHT.pkl (licensed; never downloaded)."),
    grasp_prior: str = typer.Option("pose", "--grasp-prior", help="While a hand is closed the grasp is rigid: 'pose' takes the pinch pose (position and rotation) from the whole hand's motion (default), 'twist' only the twist about the approach axis, 'off' keeps the thesis's mapping."),
    table_clearance: float = typer.Option(0.010, "--table-clearance", help="Lowest pinch height above the table top, m (fingertips cannot go below the table); negative = off."),
    box_source: str = typer.Option("previous", "--box-source", help="For --detector hamer: 'previous' (last frame's keypoints; MediaPipe finds untracked hands) or 'mediapipe' (every frame)."),
    accept_bad_depth: bool = typer.Option(False, "--accept-bad-depth", help="Go on when the take's depth fails a check (empty, wrong unit, misaligned): every row is flagged in `depth_problem` instead of stopping."),
    mediapipe_mode: str = typer.Option("auto", "--mediapipe-mode", help="For --detector mediapipe: auto (video mode: landmark tracking between palm detections; default) or image (every frame on its own)."),
    rgb_topic: Optional[str] = RGB_TOPIC, depth_topic: Optional[str] = DEPTH_TOPIC,
    info_topic: Optional[str] = INFO_TOPIC,
) -> None:
    """Ingest one take: frames, hand keypoints, depth checks, hand tracking, depth alignment, gripper
    poses, object keypoints.

    Results go to the warehouse tables frames, hand_keypoints, aligned_keypoints, hand_presence,
    gripper_poses, object_keypoints (and ingest_metrics for synthetic takes, against their ground
    truth). Depth that cannot be trusted stops the take (exit 2) unless --accept-bad-depth; a hand
    tracked in too few frames is reported as not trusted (and `augment` refuses it).
    """
    from demoforge.lib.takes import TakeError  # lazy (CLI start-up): numpy

    options = {}
    if detector == "mediapipe" and mediapipe_mode != "auto":
        if mediapipe_mode not in ("image", "video"):
            raise fail(f"--mediapipe-mode must be auto, image or video, got {mediapipe_mode!r}")
        options["running_mode"] = mediapipe_mode
    if detector == "precomputed":
        if predictions is None:
            raise fail("--detector precomputed needs --predictions FILE")
        options["path"] = str(predictions)
    if detector == "hamer":
        if hamer_checkpoint is None or mano_model is None:
            raise fail("--detector hamer needs --hamer-checkpoint PATH and --mano-model PATH (both licensed, not downloaded by demoforge)")
        if box_source not in ("previous", "mediapipe"):
            raise fail(f"--box-source must be previous or mediapipe, got {box_source!r}")
        options.update(checkpoint=str(hamer_checkpoint.resolve()), mano_model=str(mano_model.resolve()), box_source=box_source)
    take = _open_take_or_fail(path, rgb_topic=rgb_topic, depth_topic=depth_topic, info_topic=info_topic)
    if take.pose_method not in (None, "camera.json"):
        typer.echo(f"camera pose: {take.pose_method} (demoforge calibrate)", err=True)
    # the flow's modules (Prefect, the detectors) once the take is known to be readable: a mistyped
    # path is reported at once
    from demoforge.flows.ingest import ingest_take
    # lazy (CLI start-up): numpy, scipy
    from demoforge.lib.ingest.options import IngestOptions
    from demoforge.lib.perception.detectors import DetectorError

    try:
        ingest_options = IngestOptions(detector=detector, detector_options=options, state_method=state_method,
                                       smoothing=smoothing, grasp_prior=grasp_prior,
                                       table_clearance=None if table_clearance < 0 else table_clearance,
                                       accept_bad_depth=accept_bad_depth, video=video)
        result = run_flow(ingest_take, str(path), str(current_warehouse()), task=task, options=ingest_options)
    except (TakeError, ValueError, DetectorError) as e:
        raise fail(str(e))
    for name, m in result.items():
        if m is not None:
            typer.echo(f"{name:<18} {m.rows:>7} rows  {m.path}")
    _echo_hand_presence(result["hand_presence"])
    if result.get("object_keypoints") is None:  # the hand stages stand; the objects wait for annotation
        from demoforge.lib.annotate import annotation_status, not_annotated_message  # lazy (CLI start-up): numpy, scipy

        # the stage's own words (it names the resolved take folder): printed once, also when it was cached
        warn(f"object_keypoints: {not_annotated_message(path.resolve(), annotation_status(take).detail)}")


def _echo_hand_presence(presence) -> None:
    """The take's per-hand tracking summary (the `hand_presence` table), untrusted hands and depth missing
    at the hands on stderr."""
    import numpy as np

    # lazy (CLI start-up): numpy, pyarrow, scipy
    from demoforge.lib.ingest.depth_checks import DepthCoverage, coverage_warning
    from demoforge.schemas.core import read_table_file

    found = [r for f in presence.files for r in read_table_file("hand_presence", f).to_pylist()]
    for r in found:
        line = (f"{r['hand']} hand: detected in {r['frames_detected']} of {r['frames']} frames, "
                f"{r['frames_accepted']} in {r['tracks']} track(s), {r['frames_filled']} filled, "
                f"trajectory on {r['frames_tracked']} frames")
        if r["depth_problem"]:
            line += f"; depth accepted despite `{r['depth_problem']}`"
        if r["trusted"]:
            typer.echo(line + " -- trusted")
        else:
            warn(f"{line} -- NOT TRUSTED: {r['reason']}")
    if found:  # the stage's warning, also when the stage came from the cache
        coverage = DepthCoverage(np.array([r["depth_missing_fraction"] for r in found]),
                                 found[0]["depth_missing_frame_fraction"], 0)
        text = coverage_warning(found[0]["take"], coverage)
        if text:
            warn(f"hand_presence: {text}")


@app.command("ingest-folder")
def ingest_folder_cmd(
    folder: Path = typer.Argument(..., help="Folder whose takes to ingest: take folders (with camera.json) and recordings (.bag, .db3, .r3d, .mcap, bag and Record3D folders), at any depth."),
    detector: str = detector_option(help="simulated: synthetic takes."),
    task: Optional[str] = typer.Option(None, help="Task of the takes (synthetic takes know theirs)."),
    augment: bool = typer.Option(False, "--augment", help="Also generate each take's episode database."),
    episodes: int = typer.Option(10_000, "--episodes", "-n", min=1, help="Episodes per take with --augment."),
) -> None:
    """Ingest every take under a folder; a take that fails is recorded in `folder_ingests` and skipped.

    This is the flow of the scheduled deployment (`demoforge serve`)."""
    if not folder.is_dir():  # before the flow starts (and its modules load): one line, no flow-run traceback
        raise fail(f"{folder}: no such folder to ingest takes from")
    from demoforge.flows.ingest_folder import ingest_folder  # lazy: prefect
    # lazy (CLI start-up): numpy, scipy
    from demoforge.lib.ingest.options import IngestOptions
    from demoforge.lib.trajectories.augmentation.options import AugmentOptions

    try:
        rows = run_flow(ingest_folder, str(folder), str(current_warehouse()), task=task,
                        ingest=IngestOptions(detector=detector),
                        augment=AugmentOptions.half_mirrored(episodes) if augment else None)
    except ValueError as e:
        raise fail(str(e))
    for r in rows:
        typer.echo(f"{r['status']:<16} {r['take']}  {r['error']}")
    if not rows:
        typer.echo(f"no takes (folders with camera.json, or recordings) under {folder}")
