"""A task database's episodes and steps as the stages, flows, exports, the report and the scripts read
them: actions by episode id, the selections the exports write (:class:`EpisodeSelection`), the episodes
a robot check passed, the cameras of the source takes."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.exports import ExportError
from demoforge.lib.takes import TakeError, parse_camera
from demoforge.schemas.catalog import placeholders, query
from demoforge.schemas.core import column_numpy, read_parquet_file, read_table, table_files

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


def check_name(what: str, value: str) -> None:
    """An ExportError unless ``value`` (a task or take named on the command line) is a plain name."""
    if not _NAME.match(value):
        raise ExportError(f"invalid {what} {value!r}: letters, digits, '_', '-' and '.' only")


def episode_files(warehouse: str, task: str, take: str | None = None) -> list[Path]:
    """The episodes and episode_steps files of a task (one take or all), the export's inputs."""
    check_name("task", task)
    part = {"task": task} | ({"take": take} if take else {})
    if take:
        check_name("take", take)
    eps = table_files("episodes", warehouse, **part)
    if not eps:
        raise ExportError(f"no episodes of task {task!r}{' from take ' + take if take else ''} in {warehouse}; "
                          "run `demoforge augment TAKE` (or `make evaluate`) first")
    return eps + table_files("episode_steps", warehouse, **part)


def read_steps(warehouse: str, task: str, take: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """episode_id, step and action (rows, 2, 8) of one take's episode_steps, as numpy.

    Read whole and selected in numpy: pyarrow 26.0.1 returns wrong values when it filters a nested
    fixed-size-list column whose chunk is a slice (as parquet reads give), in `filters=` and `.filter`.
    """
    files = table_files("episode_steps", warehouse, task=task, take=take)
    if not files:
        return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 2, 8), np.float32)
    t = pa.concat_tables([read_parquet_file(f, "episode_steps", ["episode_id", "step", "action"]) for f in files])
    return t.column("episode_id").to_numpy(), t.column("step").to_numpy(), column_numpy(t, "action")


def load_episodes(warehouse: str, task: str, take: str | None = None, include_invalid: bool = False,
                  limit: int | None = None, only: set | None = None) -> EpisodeSelection:
    """A task's episodes (valid ones unless ``include_invalid``; only the (take, episode_id) pairs in
    ``only`` if given; the first ``limit`` by take and id)."""
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
        e, s, act = read_steps(warehouse, task, tk)
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
    rows = query("SELECT take, episode_id FROM sim_outcomes WHERE task = ? AND robot = ? AND gripper = ? "
                 "AND success AND (? IS NULL OR take = ?)", warehouse, [task, robot, gripper, take, take]).to_pylist()
    if not rows:
        raise ExportError(f"no episode of task {task!r} passed the robot check with --robot {robot} --gripper "
                          f"{gripper}: run `demoforge simulate --task {task} --robot {robot} --gripper {gripper}` "
                          "first, or pass --unchecked to export every episode the arms can reach")
    return {(r["take"], int(r["episode_id"])) for r in rows}


def check_files(warehouse: str, task: str, robot: str, gripper: str) -> list[Path]:
    """The `sim_results` files of a task and robot: the robot check an export's selection depends on."""
    return table_files("sim_results", warehouse, task=task, robot=robot, gripper=gripper)


def take_cameras(warehouse: str, takes: list[str]) -> dict:
    """{take: CameraInfo} from each take's camera.json (folder from the warehouse's `takes` table)."""
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


def episode_actions(warehouse: str, task: str, take: str, ids) -> dict[int, np.ndarray]:
    """{episode_id: (length, 2, 8) actions} of the given episodes, read from `episode_steps`."""
    id_list = [int(i) for i in ids]
    t = query("SELECT episode_id, action FROM episode_steps WHERE task = ? AND take = ? "
              f"AND episode_id IN ({placeholders(len(id_list))}) ORDER BY episode_id, step", warehouse, [task, take, *id_list])
    eid = np.asarray(t.column("episode_id").to_numpy())
    act = np.asarray(t.column("action").to_pylist(), float)
    return {int(i): act[eid == i] for i in np.unique(eid)}
