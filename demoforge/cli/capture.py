"""`demoforge convert` and `demoforge calibrate`: from the file a camera writes to a calibrated take."""

from __future__ import annotations

from pathlib import Path
from typing import Optional
import typer

import demoforge.lib  # noqa: F401
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
