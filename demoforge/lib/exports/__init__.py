"""Exports of demoforge episodes to the formats robot-learning code reads, and Rerun recordings.

- :mod:`demoforge.lib.exports.lerobot`: a LeRobotDataset v3.0 folder (parquet + JSON metadata).
- :mod:`demoforge.lib.exports.robomimic`: a robomimic hdf5 file.
- :mod:`demoforge.lib.exports.rerun_view`: an offline Rerun recording (.rrd) of a take or an episode.

Pure functions over arrays: reading the warehouse is the read layer's job (schemas/reads/episodes.py).
Every writer publishes its output atomically (:func:`atomic_dir`, :func:`atomic_file`): a crash or a
refused input never leaves a half-written export where the user asked for one.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np

from demoforge.lib.errors import UserError

ARMS = ("left", "right")
POSE_FIELDS = ("x", "y", "z", "qx", "qy", "qz", "qw", "gripper")
# The flat 16-vector of both arms' poses, arm-major (left first), in the DESIGN's pose order.
POSE16_NAMES = tuple(f"{arm}_{f}" for arm in ARMS for f in POSE_FIELDS)
STEPS_PER_SECOND = 30  # episode_steps are 30 steps per second (schemas/augment.py)

# One instruction per task of the library: LeRobot keys episodes by a natural-language task.
TASK_INSTRUCTIONS = {
    "pouring": "Pour from the bottle into the cup.",
    "trash_in_bin": "Put the trash into the bin.",
    "paper_in_case": "Put the paper into the case.",
    "mix_bowl": "Mix the contents of the bowl with the spoon.",
    "open_container": "Open the container by taking off its lid.",
    "empty_vase": "Take the flower out of the vase.",
}


class ExportError(UserError):
    """The input cannot be exported; the message says what is wrong and how to fix it."""


def task_instruction(task: str) -> str:
    return TASK_INSTRUCTIONS.get(task, task.replace("_", " ").capitalize() + ".")


def check_episodes(poses: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate concatenated episode poses (F, 2, 8) against per-episode lengths (N,)."""
    poses = np.asarray(poses)
    lengths = np.asarray(lengths, dtype=np.int64)
    if poses.ndim != 3 or poses.shape[1:] != (2, 8):
        raise ExportError(f"episode poses must have shape (frames, 2, 8) [x, y, z, qx, qy, qz, qw, g] per arm, "
                          f"got {poses.shape}")
    if lengths.ndim != 1 or len(lengths) == 0:
        raise ExportError("no episodes to export: the selection is empty (check --task/--take, or "
                          "pass --include-invalid if every episode is flagged invalid)")
    if (lengths < 1).any():
        raise ExportError(f"every episode needs at least one step; lengths {lengths[lengths < 1][:5].tolist()}")
    if int(lengths.sum()) != len(poses):
        raise ExportError(f"episode lengths sum to {int(lengths.sum())} steps but {len(poses)} pose rows were given")
    if not np.isfinite(poses).all():
        raise ExportError("episode poses contain NaN or inf; re-run `demoforge augment` for the task")
    return poses, lengths


def episode_starts(lengths: np.ndarray) -> np.ndarray:
    """Index of each episode's first frame in the concatenated arrays."""
    return np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)


def next_poses(poses: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The pose one step later within the same episode; the last step holds its own pose."""
    nxt = np.empty_like(poses)
    nxt[:-1] = poses[1:]
    last = np.cumsum(lengths) - 1
    nxt[last] = poses[last]
    return nxt


def frame_in_episode(lengths: np.ndarray) -> np.ndarray:
    """0-based step of every frame within its episode, without a Python loop."""
    starts = episode_starts(lengths)
    return np.arange(int(lengths.sum()), dtype=np.int64) - np.repeat(starts, lengths)


def _umask() -> int:
    old = os.umask(0)
    os.umask(old)
    return old


def _check_target(target: Path, overwrite: bool) -> None:
    if target.exists() and not overwrite:
        raise ExportError(f"{target} already exists; choose another --out or pass --overwrite")


@contextlib.contextmanager
def atomic_dir(target: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside ``target``; on success it replaces ``target`` by a rename."""
    target = Path(target)
    _check_target(target, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it private; an export is for sharing
        if target.exists():
            # Move the old export aside first so the swap is two renames, never a half-deleted folder.
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.replace(target, old / "previous")
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def atomic_file(target: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; on success it is fsynced and renamed onto ``target``."""
    target = Path(target)
    _check_target(target, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it private
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
