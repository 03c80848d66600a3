"""Episodes as a LeRobotDataset v3.0 folder, and a validator of that layout.

The layout is LeRobot's (huggingface/lerobot, src/lerobot/datasets/utils.py; checked against the
lerobot 0.6.1 package, which reads and writes codebase v3.0)::

    meta/info.json                                codebase_version "v3.0", fps, features, totals, paths
    meta/stats.json                               {feature: {min, max, mean, std, count, q01 .. q99}}
    meta/tasks.parquet                            index = task text, column task_index
    meta/episodes/chunk-000/file-000.parquet      one row per episode: tasks, length, data/chunk_index,
                                                  data/file_index, dataset_from_index, dataset_to_index,
                                                  videos/<key>/{chunk_index, file_index, from_timestamp,
                                                  to_timestamp}, meta/episodes/*, stats/<feature>/<stat>
    data/chunk-000/file-000.parquet ...           one row per frame, many episodes per file
    videos/<key>/chunk-000/file-000.mp4 ...       with images: many episodes per file, back to back

Features per frame: ``observation.state`` = both grippers' current poses and ``action`` = the poses
one step later (the last step of an episode holds its pose), each a flat float32 16-vector: the
(2, 8) pose array of docs/architecture.md flattened arm-major, named ``left_x .. left_gripper, right_x ..
right_gripper`` (policies read a 1-D state; the names keep the 2 x 8 structure recoverable).
Quaternions are scalar-last ``qx, qy, qz, qw``; gripper 1 = open, 0 = closed; world (table) frame, m.
In joint space (``joint_state`` given: an arm robot's export) both are instead the robot's joint values
per step, named by ``state_names``: for the ALOHA arms 14 float32, ``left_waist .. left_wrist_rotate,
left_gripper, right_...`` (rad; the gripper's normalized opening, 1 open, 0 closed), as the ALOHA
datasets name them, with ``robot_type`` ``aloha``.
``observation.environment_state`` (when given) = the 11 object keypoints of the step, flattened to
33 float32 named ``<keypoint>_x, _y, _z`` (lib/exports/object_state.py says how they move).
``observation.images.<camera>`` (when given) = a video feature: RGB frames in mp4 files.
``demoforge.take``, ``demoforge.episode_id``, ``demoforge.kind`` (when given) = where the frame's
episode came from, in every data row, so the provenance survives LeRobot's edit tools (which
rewrite meta/episodes and drop unknown files such as meta/demoforge.json).

Statistics are computed as LeRobot computes them for a dataset it records; the statistics
module :mod:`demoforge.lib.exports.lerobot_stats` says how (its names are re-exported here).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from demoforge.lib.exports import (
    POSE16_NAMES, STEPS_PER_SECOND, ExportError, atomic_dir, check_episodes, episode_starts,
    frame_in_episode, next_poses,
)
from demoforge.lib.exports.lerobot_stats import (  # noqa: F401  (re-exported)
    HISTOGRAM_BINS, QUANTILE_KEYS, QUANTILES, STAT_KEYS, episode_stats, aggregate_stats, image_stats,
    lerobot_stats, sample_indices,
)

CODEBASE_VERSION = "v3.0"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
DEFAULT_CHUNK_SIZE = 1000          # files per chunk folder (LeRobot's default)
DEFAULT_DATA_FILE_SIZE_IN_MB = 100  # LeRobot's default cap per data file
DEFAULT_VIDEO_FILE_SIZE_IN_MB = 200
ROBOT_TYPE = "demoforge_dual_parallel_gripper"
PROVENANCE_FILE = "meta/demoforge.json"  # demoforge's own file: where the episodes came from
ENV_STATE = "observation.environment_state"
IMAGE_PREFIX = "observation.images."
# The video codec: OpenCV's MPEG-4 Part 2 encoder ('mp4v', FFmpeg's `mpeg4`) runs at ~1,000 fps at
# 640 x 480 here; its VP9 encoder ran at 15 fps and it has no AV1 or H.264 encoder. LeRobot decodes
# mpeg4 with PyAV (video_backend="pyav"), and with torchcodec where FFmpeg's libraries are installed.
VIDEO_FOURCC, VIDEO_CODEC = "mp4v", "mpeg4"

_SCALAR = {"timestamp": "float32", "frame_index": "int64", "episode_index": "int64", "index": "int64",
           "task_index": "int64"}
_ARROW = {"float32": pa.float32(), "float64": pa.float64(), "int64": pa.int64(), "int32": pa.int32(),
          "bool": pa.bool_(), "string": pa.string()}
# per-frame provenance: data column -> (key of the `provenance` argument, dtype)
PROVENANCE_FEATURES = {"demoforge.take": ("take", "string"), "demoforge.episode_id": ("episode_id", "int64"),
                       "demoforge.kind": ("kind", "string")}
_PROVENANCE_COLUMNS = {"take": pa.string(), "episode_id": pa.int64(), "kind": pa.string(), "valid": pa.bool_()}


@dataclass
class VideoSource:
    """One camera's frames for every exported episode (``frames(i)``: episode i's RGB uint8
    (height, width, 3) frames, one per step), written as ``observation.images.<key>``."""

    key: str
    width: int
    height: int
    frames: Callable[[int], Iterable[np.ndarray]]


def features(environment_names: list[str] | None = None, provenance: bool = False,
             videos: dict[str, dict] | None = None, state_names: list[str] | None = None) -> dict:
    """The `features` of info.json: dtype, shape and names of every column of the data files (and
    of every video, whose ``info`` holds the stream's codec, size and rate). ``state_names``: the
    state's and action's names (default: the two grippers' 16 pose values)."""
    names = list(state_names) if state_names is not None else list(POSE16_NAMES)
    vec = {"dtype": "float32", "shape": [len(names)], "names": names}
    out = {"observation.state": dict(vec), "action": dict(vec)}
    if environment_names is not None:
        out[ENV_STATE] = {"dtype": "float32", "shape": [len(environment_names)], "names": list(environment_names)}
    for key, info in (videos or {}).items():
        out[key] = {"dtype": "video", "shape": [info["video.height"], info["video.width"], 3],
                    "names": ["height", "width", "channels"], "info": info}
    out.update({k: {"dtype": d, "shape": [1], "names": None} for k, d in _SCALAR.items()})
    if provenance:
        out.update({k: {"dtype": d, "shape": [1], "names": None} for k, (_, d) in PROVENANCE_FEATURES.items()})
    return out


def keypoint_feature_names(keypoint_names: Iterable[str]) -> list[str]:
    """``<keypoint>_x, _y, _z`` per keypoint: the names of the flattened environment state."""
    return [f"{k}_{a}" for k in keypoint_names for a in "xyz"]


def _frame_columns(poses: np.ndarray, lengths: np.ndarray, task_of_episode: np.ndarray, fps: float,
                   environment_state: np.ndarray | None, provenance: dict | None,
                   joint_state: np.ndarray | None = None) -> dict:
    """Every frame's columns as numpy arrays: state, action, (environment state,) index columns and
    (the per-frame provenance). The state is the poses flattened, or ``joint_state`` (F, D) if given."""
    frame_index = frame_in_episode(lengths)
    episode_index = np.repeat(np.arange(len(lengths), dtype=np.int64), lengths)
    state = poses.reshape(len(poses), 16) if joint_state is None else joint_state
    cols = {
        "observation.state": state.astype(np.float32),
        "action": next_poses(state, lengths).astype(np.float32),
    }
    if environment_state is not None:
        cols[ENV_STATE] = environment_state.reshape(len(poses), -1).astype(np.float32)
    cols.update({
        "timestamp": (frame_index / fps).astype(np.float32),
        "frame_index": frame_index,
        "episode_index": episode_index,
        "index": np.arange(len(poses), dtype=np.int64),
        "task_index": np.repeat(task_of_episode.astype(np.int64), lengths),
    })
    if provenance is not None:
        for col, (key, dtype) in PROVENANCE_FEATURES.items():
            vals = np.asarray(provenance[key])
            cols[col] = np.repeat(vals.astype(str) if dtype == "string" else vals.astype(np.int64), lengths)
    return cols


def _file_plan(lengths: np.ndarray, file_size_mb: float, chunks_size: int, bytes_per_frame: int) -> np.ndarray:
    """Data file number of each episode: whole episodes packed into files of at most ``file_size_mb``
    (LeRobot's uncompressed-size cap), a new file when the next episode would not fit."""
    cap = max(1, int(file_size_mb * 2**20 // bytes_per_frame))
    file_of = np.empty(len(lengths), np.int64)
    f, used = 0, 0
    for i, L in enumerate(lengths.tolist()):  # a scan over episodes (10^4), not frames
        if used and used + L > cap:
            f, used = f + 1, 0
        file_of[i] = f
        used += L
    if file_of[-1] >= chunks_size * 1000:
        raise ExportError("too many data files; raise data_files_size_in_mb")
    return file_of


def _fixed_list(values: np.ndarray) -> pa.Array:
    return pa.FixedSizeListArray.from_arrays(pa.array(np.ascontiguousarray(values).reshape(-1)), values.shape[1])


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


def _write_json(obj: dict, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=4, ensure_ascii=False, default=_json_default))


def _write_videos(root: Path, src: VideoSource, lengths: np.ndarray, fps: int, file_size_mb: float,
                  chunks_size: int, progress: bool) -> tuple[dict, dict[str, np.ndarray], dict]:
    """Encode every episode's frames back to back into videos/<key>/chunk-*/file-*.mp4 (a new file
    once one passes ``file_size_mb``). Returns the episodes-table columns, the per-episode image
    statistics and the feature's ``info``."""
    import cv2
    from tqdm import tqdm

    key = IMAGE_PREFIX + src.key
    n = len(lengths)
    cols = {f"videos/{key}/{c}": np.zeros(n, np.float64 if "timestamp" in c else np.int64)
            for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")}
    stats: dict[str, list] = {k: [] for k in STAT_KEYS}
    file_no, offset, writer, path = 0, 0, None, None
    for i in tqdm(range(n), desc=f"render {src.key}", unit="episode", disable=not progress):
        if writer is None:
            path = root / VIDEO_PATH.format(video_key=key, chunk_index=file_no // chunks_size,
                                            file_index=file_no % chunks_size)
            path.parent.mkdir(parents=True, exist_ok=True)
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*VIDEO_FOURCC), float(fps),
                                     (src.width, src.height))
            if not writer.isOpened():
                raise ExportError(f"OpenCV cannot write {VIDEO_FOURCC} video to {path}")
        want = sample_indices(int(lengths[i]))
        sampled, count = [], 0
        for frame in src.frames(i):
            if frame.shape != (src.height, src.width, 3) or frame.dtype != np.uint8:
                raise ExportError(f"camera {src.key}: episode {i} gave a frame of {frame.shape} {frame.dtype}, "
                                  f"expected ({src.height}, {src.width}, 3) uint8")
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            if count in want:
                sampled.append(frame)
            count += 1
        if count != lengths[i]:
            raise ExportError(f"camera {src.key}: episode {i} gave {count} frames for {lengths[i]} steps")
        for k, v in image_stats(np.stack(sampled)).items():
            stats[k].append(v)
        cols[f"videos/{key}/chunk_index"][i] = file_no // chunks_size
        cols[f"videos/{key}/file_index"][i] = file_no % chunks_size
        cols[f"videos/{key}/from_timestamp"][i] = offset / fps
        offset += count
        cols[f"videos/{key}/to_timestamp"][i] = offset / fps
        if path.stat().st_size > file_size_mb * 2**20:
            writer.release()
            writer, file_no, offset = None, file_no + 1, 0
    if writer is not None:
        writer.release()
    info = {"video.height": src.height, "video.width": src.width, "video.codec": VIDEO_CODEC,
            "video.pix_fmt": "yuv420p", "video.fps": int(fps), "video.channels": 3, "has_audio": False,
            "is_depth_map": False}
    return cols, {k: np.stack(v) for k, v in stats.items()}, info


def _per_frame(values, names, frames: int, what: str, names_what: str) -> np.ndarray | None:
    """A per-frame feature (frames, len(names)) checked (one finite row of len(names) values per frame)."""
    if values is None:
        return None
    values = np.asarray(values)
    if values.shape[0] != frames or names is None or values.reshape(frames, -1).shape[1] != len(names):
        raise ExportError(f"{what} must have one row of len({names_what}) values per frame ({frames}), "
                          f"got {values.shape}")
    if not np.isfinite(values).all():
        raise ExportError(f"{what} contains NaN or inf")
    return values.reshape(frames, -1)


def _write_data_files(root: Path, cols: dict, feats: dict, file_of: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                      chunks_size: int) -> None:
    """data/chunk-*/file-*.parquet: each file the frames of its episodes (file_of: the file of each episode)."""
    for f in np.unique(file_of):
        eps = np.flatnonzero(file_of == f)
        lo, hi = int(starts[eps[0]]), int(ends[eps[-1]])
        tbl = pa.table({
            name: (_fixed_list(v[lo:hi]) if v.ndim == 2 else pa.array(v[lo:hi], type=_ARROW[feats[name]["dtype"]]))
            for name, v in cols.items()
        })
        path = root / DATA_PATH.format(chunk_index=int(f // chunks_size), file_index=int(f % chunks_size))
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(tbl, path)


def _row_provenance(provenance: dict | None, n: int) -> dict | None:
    """The provenance written into every data row (take, episode_id and kind all given), else None;
    every given per-episode array checked to hold n values."""
    for k, vals in (provenance or {}).items():
        if k in _PROVENANCE_COLUMNS and len(vals) != n:
            raise ExportError(f"provenance {k!r} has {len(vals)} values for {n} episodes")
    return provenance if provenance and all(k in provenance for k in ("take", "episode_id", "kind")) else None


def write_lerobot_dataset(
    out: str | os.PathLike,
    poses: np.ndarray,
    lengths: np.ndarray,
    *,
    tasks: list[str],
    task_of_episode: np.ndarray | None = None,
    fps: int = STEPS_PER_SECOND,
    robot_type: str = ROBOT_TYPE,
    provenance: dict | None = None,
    source: dict | None = None,
    environment_state: np.ndarray | None = None,
    environment_names: list[str] | None = None,
    joint_state: np.ndarray | None = None,
    state_names: list[str] | None = None,
    videos: list[VideoSource] | None = None,
    data_files_size_in_mb: float = DEFAULT_DATA_FILE_SIZE_IN_MB,
    video_files_size_in_mb: float = DEFAULT_VIDEO_FILE_SIZE_IN_MB,
    chunks_size: int = DEFAULT_CHUNK_SIZE,
    progress: bool = False,
    overwrite: bool = False,
) -> dict:
    """Write episodes as a LeRobotDataset v3.0 folder at ``out`` (atomically) and return its info.json.

    poses: (F, 2, 8) concatenated episodes; lengths: (N,) steps per episode; tasks: the task texts;
    task_of_episode: (N,) index into ``tasks`` (default all 0). provenance: per-episode arrays
    ``take``, ``episode_id``, ``kind`` (and ``valid``): ``demoforge/*`` columns of the episodes
    table, and ``demoforge.take / .episode_id / .kind`` in every data row when all three are given.
    environment_state: (F, E) per frame, named by ``environment_names`` (E); joint_state: (F, D) the
    robot's joint values per frame, named by ``state_names`` (D), which then are the state and action
    instead of the poses; videos: cameras whose frames become ``observation.images.<key>``. source:
    JSON-able description of the export, written to meta/demoforge.json.
    """
    poses, lengths = check_episodes(poses, lengths)
    joint_state = _per_frame(joint_state, state_names, len(poses), "joint_state", "state_names")
    n = len(lengths)
    if not tasks or len(set(tasks)) != len(tasks):
        raise ExportError(f"tasks must be a non-empty list of distinct task texts, got {tasks!r}")
    task_of_episode = np.zeros(n, np.int64) if task_of_episode is None else np.asarray(task_of_episode, np.int64)
    if task_of_episode.shape != (n,) or task_of_episode.min() < 0 or task_of_episode.max() >= len(tasks):
        raise ExportError(f"task_of_episode must give one index into the {len(tasks)} tasks per episode")
    if fps <= 0:
        raise ExportError(f"fps must be positive, got {fps}")
    row_provenance = _row_provenance(provenance, n)
    environment_state = _per_frame(environment_state, environment_names, len(poses), "environment_state",
                                   "environment_names")
    videos = list(videos or [])
    if len({v.key for v in videos}) != len(videos):
        raise ExportError("video keys must be distinct")

    cols = _frame_columns(poses, lengths, task_of_episode, fps, environment_state, row_provenance, joint_state)
    names = state_names if joint_state is not None else None
    feats = features(environment_names if environment_state is not None else None, row_provenance is not None,
                     state_names=names)
    bytes_per_frame = sum(np.asarray(v[:1]).nbytes if v.dtype != object and v.dtype.kind != "U" else 32
                          for v in cols.values())
    file_of = _file_plan(lengths, data_files_size_in_mb, chunks_size, bytes_per_frame)
    chunk_idx, file_idx = file_of // chunks_size, file_of % chunks_size
    starts = episode_starts(lengths)
    ends = starts + lengths

    with atomic_dir(out, overwrite=overwrite) as root:
        _write_data_files(root, cols, feats, file_of, starts, ends, chunks_size)

        ep_cols: dict[str, pa.Array] = {
            "episode_index": pa.array(np.arange(n, dtype=np.int64)),
            "tasks": pa.array([[tasks[t]] for t in task_of_episode.tolist()], type=pa.list_(pa.string())),
            "length": pa.array(lengths.astype(np.int64)),
            "data/chunk_index": pa.array(chunk_idx), "data/file_index": pa.array(file_idx),
            "dataset_from_index": pa.array(starts), "dataset_to_index": pa.array(ends),
        }
        ep_stats = episode_stats(cols, feats, lengths)
        video_feats = {}
        for src in videos:
            vcols, vstats, vinfo = _write_videos(root, src, lengths, fps, video_files_size_in_mb, chunks_size,
                                                 progress)
            ep_cols.update({k: pa.array(v) for k, v in vcols.items()})
            ep_stats[IMAGE_PREFIX + src.key] = vstats
            video_feats[IMAGE_PREFIX + src.key] = vinfo
        if video_feats:  # video features go before the index columns, as LeRobot lists them
            feats = features(environment_names if environment_state is not None else None,
                             row_provenance is not None, video_feats, state_names=names)
        for name, st in ep_stats.items():
            for k in STAT_KEYS:
                v = st[k].astype(np.int64) if k == "count" else st[k]
                ep_cols[f"stats/{name}/{k}"] = pa.array([x.tolist() for x in v])
        ep_cols["meta/episodes/chunk_index"] = pa.array(np.zeros(n, np.int64))
        ep_cols["meta/episodes/file_index"] = pa.array(np.zeros(n, np.int64))
        for k, typ in _PROVENANCE_COLUMNS.items():
            if provenance is not None and k in provenance:
                ep_cols[f"demoforge/{k}"] = pa.array(np.asarray(provenance[k]).tolist(), type=typ)
        ep_path = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
        ep_path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table(ep_cols), ep_path)

        # tasks.parquet as LeRobot writes it: a pandas frame indexed by the task text.
        import pandas as pd

        (root / TASKS_PATH).parent.mkdir(parents=True, exist_ok=True)
        pd.DataFrame({"task_index": np.arange(len(tasks), dtype=np.int64)}, index=list(tasks)).to_parquet(
            root / TASKS_PATH)

        stats = {name: aggregate_stats(st) for name, st in ep_stats.items()}
        _write_json(stats, root / STATS_PATH)
        info = {"codebase_version": CODEBASE_VERSION, "robot_type": robot_type, "total_episodes": n,
                "total_frames": int(len(poses)), "total_tasks": len(tasks), "chunks_size": chunks_size,
                "data_files_size_in_mb": data_files_size_in_mb, "video_files_size_in_mb": video_files_size_in_mb,
                "fps": fps, "splits": {"train": f"0:{n}"}, "data_path": DATA_PATH,
                "video_path": VIDEO_PATH if videos else None, "features": feats}
        _write_json(info, root / INFO_PATH)
        if source is not None:
            _write_json(source, root / PROVENANCE_FILE)
    return info


# ------------------------------------------------------------------------------------------ validation

class LeRobotFormatError(ExportError):
    """A folder does not follow the LeRobotDataset v3.0 layout; the message names the file and key."""


def _need(cond: bool, msg: str) -> None:
    if not cond:
        raise LeRobotFormatError(msg)


def validate_lerobot_dataset(root: str | os.PathLike) -> dict:
    """Check a folder against the v3.0 layout as LeRobot reads it, and return a summary.

    Checks: info.json keys and version, every feature's dtype/shape in every data file, the episodes
    table's index ranges against the data files (contiguous global ``index``, per-episode
    ``frame_index`` 0..length-1, ``timestamp`` = frame_index / fps), tasks.parquet against the
    ``task_index`` values, and stats.json having every statistic of every feature with its shape.
    """
    root = Path(root)
    _need((root / INFO_PATH).is_file(), f"{root}: no {INFO_PATH}")
    info = json.loads((root / INFO_PATH).read_text())
    for key in ("codebase_version", "fps", "features", "total_episodes", "total_frames", "total_tasks",
                "chunks_size", "data_path", "splits"):
        _need(key in info, f"{INFO_PATH}: missing key {key!r}")
    _need(info["codebase_version"] == CODEBASE_VERSION,
          f"{INFO_PATH}: codebase_version {info['codebase_version']!r}, expected {CODEBASE_VERSION!r}")
    feats = info["features"]
    for key, ft in feats.items():
        _need({"dtype", "shape", "names"} <= set(ft), f"{INFO_PATH}: feature {key!r} needs dtype, shape and names")
    for key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        _need(key in feats, f"{INFO_PATH}: missing default feature {key!r}")

    tasks = pq.read_table(root / TASKS_PATH).to_pandas()
    _need("task_index" in tasks.columns, f"{TASKS_PATH}: no task_index column")
    _need(len(tasks) == info["total_tasks"], f"{TASKS_PATH}: {len(tasks)} tasks, info.json says {info['total_tasks']}")

    ep_files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    _need(bool(ep_files), f"{root}: no meta/episodes/chunk-*/file-*.parquet")
    eps = pa.concat_tables([pq.read_table(f) for f in ep_files]).to_pydict()
    for key in ("episode_index", "tasks", "length", "data/chunk_index", "data/file_index", "dataset_from_index",
                "dataset_to_index"):
        _need(key in eps, f"meta/episodes: missing column {key!r}")
    n = len(eps["episode_index"])
    _need(n == info["total_episodes"], f"meta/episodes: {n} episodes, info.json says {info['total_episodes']}")
    _need(eps["episode_index"] == list(range(n)), "meta/episodes: episode_index must be 0..N-1 in order")
    frm, to, length = (np.asarray(eps[k], np.int64) for k in ("dataset_from_index", "dataset_to_index", "length"))
    _need(bool((to - frm == length).all()), "meta/episodes: dataset_to_index - dataset_from_index != length")
    _need(frm[0] == 0 and bool((frm[1:] == to[:-1]).all()) and to[-1] == info["total_frames"],
          "meta/episodes: episodes must tile the frames 0..total_frames without gaps")

    dtypes = _ARROW
    frames = 0
    files = sorted({(c, f) for c, f in zip(eps["data/chunk_index"], eps["data/file_index"])})
    for c, f in files:
        path = root / info["data_path"].format(chunk_index=c, file_index=f)
        _need(path.is_file(), f"{path}: data file named by meta/episodes is missing")
        t = pq.read_table(path)
        for key, ft in feats.items():
            if ft["dtype"] in ("video", "image"):
                continue
            _need(key in t.column_names, f"{path}: no column {key!r}")
            typ = t.schema.field(key).type
            if list(ft["shape"]) == [1]:
                _need(typ == dtypes[ft["dtype"]], f"{path}: column {key!r} is {typ}, expected {ft['dtype']}")
            else:
                _need(pa.types.is_fixed_size_list(typ) or pa.types.is_list(typ),
                      f"{path}: column {key!r} is {typ}, expected a list of {ft['shape']}")
                _need(typ.value_type == dtypes[ft["dtype"]], f"{path}: column {key!r} holds {typ.value_type}")
                lens = pc.list_value_length(t.column(key)).to_numpy(zero_copy_only=False)
                _need(bool((lens == int(np.prod(ft["shape"]))).all()),
                      f"{path}: column {key!r} rows not of {ft['shape']}")
        sel = np.flatnonzero((np.asarray(eps["data/chunk_index"]) == c) & (np.asarray(eps["data/file_index"]) == f))
        idx = t.column("index").to_numpy()
        _need(bool((idx == np.arange(frm[sel[0]], to[sel[-1]])).all()),
              f"{path}: global index must run {frm[sel[0]]}..{to[sel[-1]] - 1} for its episodes")
        ep = t.column("episode_index").to_numpy()
        fi = t.column("frame_index").to_numpy()
        _need(bool((ep == np.repeat(sel, length[sel])).all()), f"{path}: episode_index does not match meta/episodes")
        _need(bool((fi == frame_in_episode(length[sel])).all()), f"{path}: frame_index must restart at 0 per episode")
        ts = t.column("timestamp").to_numpy()
        _need(bool(np.allclose(ts, fi / info["fps"], atol=1e-4)), f"{path}: timestamp != frame_index / fps")
        ti = t.column("task_index").to_numpy()
        _need(bool(np.isin(ti, tasks["task_index"].to_numpy()).all()), f"{path}: task_index not in {TASKS_PATH}")
        frames += t.num_rows
    _need(frames == info["total_frames"], f"data: {frames} frames, info.json says {info['total_frames']}")

    videos = [k for k, ft in feats.items() if ft["dtype"] == "video"]
    for key in videos:
        _need(info.get("video_path") is not None, f"{INFO_PATH}: video feature {key!r} but no video_path")
        for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp"):
            _need(f"videos/{key}/{c}" in eps, f"meta/episodes: missing column 'videos/{key}/{c}'")
        frm_t, to_t = (np.asarray(eps[f"videos/{key}/{c}"], np.float64) for c in ("from_timestamp", "to_timestamp"))
        _need(bool(np.allclose(to_t - frm_t, length / info["fps"], atol=1e-6)),
              f"meta/episodes: videos/{key} timestamps do not span each episode's length / fps")
        for c, f in sorted(set(zip(eps[f"videos/{key}/chunk_index"], eps[f"videos/{key}/file_index"]))):
            path = root / info["video_path"].format(video_key=key, chunk_index=c, file_index=f)
            _need(path.is_file() and path.stat().st_size > 0, f"{path}: video file named by meta/episodes is missing")

    if (root / STATS_PATH).is_file():
        stats = json.loads((root / STATS_PATH).read_text())
        for key, ft in feats.items():
            if ft["dtype"] in ("image", "string"):
                continue
            _need(key in stats, f"{STATS_PATH}: no statistics for {key!r}")
            for s in STAT_KEYS:
                _need(s in stats[key], f"{STATS_PATH}: {key!r} lacks {s!r}")
                want = [1] if s == "count" else [3, 1, 1] if ft["dtype"] == "video" else list(ft["shape"])
                _need(list(np.shape(stats[key][s])) == want,
                      f"{STATS_PATH}: {key}/{s} has shape {list(np.shape(stats[key][s]))}, expected {want}")
    return {"episodes": n, "frames": frames, "tasks": tasks.index.tolist(), "data_files": len(files),
            "fps": info["fps"], "videos": videos}


def read_lerobot_episode(root: str | os.PathLike, episode_index: int) -> dict[str, np.ndarray]:
    """One episode's frames back from the data files: {feature: array} (vector features as (T, 16))."""
    root = Path(root)
    info = json.loads((root / INFO_PATH).read_text())
    eps = pq.read_table(sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))[0]).to_pydict()
    i = eps["episode_index"].index(episode_index)
    path = root / info["data_path"].format(chunk_index=eps["data/chunk_index"][i], file_index=eps["data/file_index"][i])
    t = pq.read_table(path)
    rows = np.flatnonzero(t.column("episode_index").to_numpy() == episode_index)
    t = t.slice(int(rows[0]), len(rows))  # an episode's rows are contiguous
    out = {}
    for name in t.column_names:
        col = t.column(name).combine_chunks()
        out[name] = (np.asarray(col.flatten().to_numpy()).reshape(len(col), -1)
                     if pa.types.is_fixed_size_list(col.type) or pa.types.is_list(col.type)
                     else col.to_numpy(zero_copy_only=False))
    return out
