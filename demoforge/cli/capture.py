"""`demoforge convert` and `demoforge calibrate`: from the file a camera writes to a calibrated take."""

from __future__ import annotations

from pathlib import Path
from typing import Optional
import typer

from demoforge.cli.root import fail
from demoforge.cli.takes import DEPTH_TOPIC, INFO_TOPIC, RGB_TOPIC, TAKE_HELP, _open_take_or_fail

app = typer.Typer()


@app.command()
def convert(
    path: Path = typer.Argument(..., help=TAKE_HELP),
    out: Path = typer.Option(..., "--out", "-o", help="The take folder to write (must not exist, or be empty)."),
    rgb_topic: Optional[str] = RGB_TOPIC, depth_topic: Optional[str] = DEPTH_TOPIC,
    info_topic: Optional[str] = INFO_TOPIC,
) -> None:
    """Write a recording (or any take) as a take folder: rgb/*.png, depth/ (16-bit PNG in the
    recording's unit where its depth is integer, float32 .npy metres otherwise), camera.json.

    Every command reads the recording itself; convert is for anyone who wants the frames on disk.
    The pose (after `demoforge calibrate`) and the annotations come along. Frames are decoded as a
    stream (bounded memory), and the folder appears only when complete."""
    from tqdm.auto import tqdm

    # lazy (CLI start-up): numpy
    from demoforge.lib.takes import TakeError
    from demoforge.lib.takes.convert import convert_take

    take = _open_take_or_fail(path, require_pose=False, rgb_topic=rgb_topic, depth_topic=depth_topic,
                              info_topic=info_topic)
    with tqdm(total=take.n_frames, desc=f"convert {take.take_id}", unit="frame", leave=False) as bar:
        try:
            summary = convert_take(take, out, progress=bar.update)
        except TakeError as e:
            raise fail(str(e))
    problems = {k: v for k, v in summary["problems"].items() if k != "ok"}
    typer.echo(f"{out}: {summary['frames']} of {summary['of']} frames, depth as {summary['depth']}"
               + (f"; frame problems {problems}" if problems else ""))
    if take.camera.T_world_camera is None:
        typer.echo(f"note: no camera pose yet: run `demoforge calibrate {out}`", err=True)


def _pair(text: Optional[str], what: str) -> Optional[tuple[float, float]]:
    if text is None:
        return None
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise fail(f"{what} must be two numbers separated by a comma (e.g. 0.2,0.1), got {text!r}")
    return a, b


def _board_spec(board: str, square_mm: float, marker_mm: Optional[float], dictionary: str):
    from demoforge.lib.calibration import BoardSpec  # lazy (CLI start-up): numpy, scipy

    try:
        nx, ny = (int(x) for x in board.lower().split("x"))
        marker = marker_mm if marker_mm is not None else square_mm * 28 / 38  # the default board: 38 mm squares, 28 mm markers
        return BoardSpec(nx, ny, square_mm / 1000, marker / 1000, f"DICT_{dictionary.upper().removeprefix('DICT_')}")
    except ValueError as e:
        raise fail(f"--board {board!r} / --square-mm / --marker-mm / --dictionary: {e}".replace("invalid literal for int() with base 10", "need COLSxROWS, e.g. 7x5, got"))


@app.command()
def calibrate(
    path: Optional[Path] = typer.Argument(None, help=TAKE_HELP),
    method: str = typer.Option("auto", "--method", "-m", help="auto (the board when it is seen, else the table plane), board, or plane."),
    board: str = typer.Option("7x5", "--board", help="The ChArUco board's squares, COLSxROWS."),
    square_mm: float = typer.Option(38.0, "--square-mm", help="Side of a board square as printed, mm (measure it)."),
    marker_mm: Optional[float] = typer.Option(None, "--marker-mm", help="Side of a marker, mm (default 28/38 of the square: 28 mm on the default board)."),
    dictionary: str = typer.Option("4X4_50", "--dictionary", help="ArUco dictionary: 4X4_50, 4X4_100, 5X5_50, 5X5_100, 6X6_50, 6X6_250."),
    board_origin: Optional[str] = typer.Option(None, "--board-origin", help="X,Y: where the board's centre lies in the table frame, m (default 0,0: the board's centre is the origin)."),
    edge: Optional[str] = typer.Option(None, "--edge", help="U1,V1,U2,V2: two pixels on the table's robot-side edge, its left end then its right end (what the annotate page's two clicks give); the plane method then takes x along it and the origin at its middle."),
    frames: int = typer.Option(8, "--frames", min=1, help="How many frames, spread over the take, to look at (the camera is static)."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Print the pose, write nothing."),
    print_board: Optional[Path] = typer.Option(None, "--print-board", help="Write the board to print (.pdf or .png, at true size) and exit."),
    paper: str = typer.Option("A4", "--paper", help="Paper of --print-board: A4, A3 or letter (landscape)."),
    rgb_topic: Optional[str] = RGB_TOPIC, depth_topic: Optional[str] = DEPTH_TOPIC,
    info_topic: Optional[str] = INFO_TOPIC,
) -> None:
    """Find the camera's pose in the table frame (T_world_camera) and write it where the take keeps its
    camera metadata (the take folder's camera.json; a recording's RECORDING.demoforge/camera.json).

    With a printed ChArUco board lying flat on the table (`--print-board board.pdf` writes one), the
    board's centre is the table frame's origin, its printed top edge points away from the robot (+y).
    Without a board, the table plane in the depth (RANSAC) gives z up and the height; x and the origin
    come from two pixels on the table's robot-side edge (`--edge`, or two clicks on the annotate page),
    else y is the camera's forward direction. Writes a preview (calibration.png) with the table frame
    drawn on a frame; ingest then says which method made the pose."""
    # lazy (CLI start-up): numpy, scipy
    from demoforge.lib.calibration import CalibrationError, calibrate as run_calibration, draw_table_frame, pose_errors
    from demoforge.lib.calibration import write_board_print

    spec = _board_spec(board, square_mm, marker_mm, dictionary)
    if print_board is not None:
        if paper not in ("A4", "A3", "letter"):
            raise fail(f"--paper must be A4, A3 or letter, got {paper!r}")
        try:
            out = write_board_print(spec, print_board, paper=paper)
        except ValueError as e:
            raise fail(str(e))
        typer.echo(f"{out}: print at 100 % (no fit-to-page); a square must measure {spec.square_m * 1000:g} mm")
        return
    if path is None:
        raise fail("give the take to calibrate (or --print-board FILE)")
    edge_px = None
    if edge is not None:
        try:
            edge_px = [float(x) for x in edge.split(",")]
            assert len(edge_px) == 4
        except (ValueError, AssertionError):
            raise fail(f"--edge must be four pixel coordinates U1,V1,U2,V2, got {edge!r}")
    origin = _pair(board_origin, "--board-origin") or (0.0, 0.0)
    take = _open_take_or_fail(path, require_pose=False, rgb_topic=rgb_topic, depth_topic=depth_topic,
                              info_topic=info_topic)
    try:
        result = run_calibration(take, method=method, board=spec, board_origin=origin,
                                 edge_clicks=edge_px, frames=frames)
    except CalibrationError as e:
        raise fail(str(e))
    _report(take, result, pose_errors, draw_table_frame, dry_run)


def _report(take, result, pose_errors, draw_table_frame, dry_run: bool) -> None:
    import cv2
    import numpy as np

    from demoforge.lib.takes.pose import pose_file, write_pose  # lazy (CLI start-up): numpy

    T = result.T_world_camera
    d = result.details
    how = (f"board: {d['corners']} corners in {len(d['frames_used'])} frame(s), reprojection {d['reprojection_px']:.2f} px"
           if result.method == "board" else
           f"table plane: {d['inlier_fraction']:.0%} of the depth on it (rms {d['plane_rms_mm']:.1f} mm), {d['axes']}")
    typer.echo(f"method: {result.method} ({how})")
    typer.echo(f"camera at x={T[0, 3]:+.3f} y={T[1, 3]:+.3f} z={T[2, 3]:+.3f} m in the table frame, looking "
               f"{np.degrees(np.arcsin(np.clip(-T[2, 2], -1, 1))):.1f} deg down")
    if take.camera.T_world_camera is not None:
        e = pose_errors(T, take.camera.T_world_camera)
        typer.echo(f"previous pose ({take.pose_method}): {e['position_m'] * 1000:.1f} mm and {e['rotation_deg']:.2f} deg "
                   f"away (tilt {e['tilt_deg']:.2f} deg, height {e['height_m'] * 1000:.1f} mm)")
    if dry_run:
        return
    written = write_pose(take, T, result.method, d)
    i, rgb = result.frames[0]
    preview = written.with_name("calibration.png")
    cv2.imwrite(str(preview), cv2.cvtColor(draw_table_frame(rgb, take.K, T), cv2.COLOR_RGB2BGR))
    typer.echo(f"wrote {pose_file(take)} (pose_method {result.method}); preview: {preview}")
