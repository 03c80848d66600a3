"""Episodes as a robomimic hdf5 dataset, with each demonstration's demoforge provenance.

robomimic's layout (robomimic.github.io, "Datasets > Overview > Dataset Structure")::

    data                      attrs: total (samples in the file), env_args (JSON string)
      demo_0                  attrs: num_samples; here also src_task, src_take, src_episode_id, src_kind,
                                     src_valid, src_transform (JSON) - where the episode came from
        actions     (T, 16)   the two grippers' poses one step later (the last step holds)
        rewards     (T,)      0 everywhere (demoforge does not score steps)
        dones       (T,)      1 at the last step
        obs/<key>   (T, ...)  low-dim observations at step t (keys below)
        next_obs/<key>        the same at step t + 1 (the last step repeats)
    mask                      filter keys: datasets of demo names (bytes), e.g. mask/train, mask/valid

Observation keys, per arm ``robot0`` = left, ``robot1`` = right: ``robotK_eef_pos`` (T, 3) world m,
``robotK_eef_quat`` (T, 4) scalar-last ``qx, qy, qz, qw`` (robosuite's order too), ``robotK_gripper``
(T, 1) 1 = open, 0 = closed; ``object`` (T, 33): the 11 object keypoints of the step, flattened,
world m (carried by the grippers: lib/exports/object_state.py; the keypoints at the episode's start
held constant when no per-step keypoints are given). Actions are the flat 16-vector ``left [x y z qx qy qz qw g], right [...]``.
Arrays are float32: the warehouse stores the actions as float32 (0.1 µm at 1 m), so float64 would
only double the file.
``mask/valid`` is robomimic's validation split, not demoforge's `valid` flag (that is ``src_valid``).
"""

from __future__ import annotations

import json
import os

import numpy as np

from demoforge.lib.exports import ExportError, atomic_file, check_episodes, episode_starts, next_poses

FORMAT_VERSION = "demoforge-robomimic-1"


def _obs(poses: np.ndarray, objects: np.ndarray) -> dict[str, np.ndarray]:
    out = {}
    for arm in (0, 1):
        out[f"robot{arm}_eef_pos"] = poses[:, arm, :3]
        out[f"robot{arm}_eef_quat"] = poses[:, arm, 3:7]
        out[f"robot{arm}_gripper"] = poses[:, arm, 7:8]
    out["object"] = objects.reshape(len(poses), -1)
    return out


def write_robomimic_hdf5(
    out: str | os.PathLike,
    poses: np.ndarray,
    lengths: np.ndarray,
    *,
    keypoints: np.ndarray,
    provenance: dict,
    env_name: str,
    env_kwargs: dict | None = None,
    object_state: np.ndarray | None = None,
    valid_fraction: float = 0.1,
    seed: int = 0,
    overwrite: bool = False,
) -> dict:
    """Write episodes to a robomimic hdf5 file at ``out`` (atomically); return a summary.

    poses: (F, 2, 8) concatenated episodes; lengths: (N,); keypoints: (N, k, 3) object keypoints per
    episode at its start; object_state: (F, k, 3) the keypoints at every step (default: the start's
    held constant); provenance: per-episode ``task``, ``take``, ``episode_id``, ``kind``, ``valid`` and
    optionally ``transform`` (N, objects, 3). ``valid_fraction`` of the demos (seeded) go to the
    ``mask/valid`` split, the rest to ``mask/train``; ``mask/<kind>`` lists each episode kind.
    """
    import h5py

    poses, lengths = check_episodes(poses, lengths)
    n = len(lengths)
    keypoints = np.asarray(keypoints, np.float64)
    if keypoints.ndim != 3 or keypoints.shape[0] != n or keypoints.shape[2] != 3:
        raise ExportError(f"keypoints must be (episodes={n}, k, 3), got {keypoints.shape}")
    for k in ("task", "take", "episode_id", "kind", "valid"):
        if k not in provenance or len(provenance[k]) != n:
            raise ExportError(f"provenance needs {k!r} with one value per episode ({n})")
    if not 0 <= valid_fraction < 1:
        raise ExportError(f"valid_fraction must be in [0, 1), got {valid_fraction}")
    if object_state is None:
        object_state = np.repeat(keypoints, lengths, axis=0)
    object_state = np.asarray(object_state, np.float32).reshape(len(poses), -1)
    if object_state.shape[1] != keypoints.shape[1] * 3:
        raise ExportError(f"object_state must hold {keypoints.shape[1]} x 3 values per step, got {object_state.shape}")
    nxt = next_poses(poses, lengths)
    nxt_objects = next_poses(object_state[:, None, :], lengths)[:, 0]
    starts = episode_starts(lengths)
    names = np.array([f"demo_{i}" for i in range(n)])
    rng = np.random.default_rng(seed)
    is_val = np.zeros(n, bool)
    is_val[rng.permutation(n)[: int(round(valid_fraction * n))]] = True
    transform = provenance.get("transform")
    env_args = {"env_name": env_name, "type": None, "env_kwargs": dict(env_kwargs or {}),
                "format": FORMAT_VERSION,
                "note": ("demoforge episodes (MuJoCo dual parallel-jaw grippers); no robomimic env wrapper: "
                         "type is null, so train with rollouts disabled")}

    with atomic_file(out, overwrite=overwrite) as tmp:
        with h5py.File(tmp, "w") as f:
            data = f.create_group("data")
            data.attrs["total"] = int(lengths.sum())
            data.attrs["env_args"] = json.dumps(env_args)
            for i in range(n):  # one hdf5 group per demo: robomimic's layout, the loop is over episodes
                lo, hi = int(starts[i]), int(starts[i] + lengths[i])
                g = data.create_group(names[i])
                g.attrs["num_samples"] = int(lengths[i])
                g.attrs["src_task"] = str(provenance["task"][i])
                g.attrs["src_take"] = str(provenance["take"][i])
                g.attrs["src_episode_id"] = int(provenance["episode_id"][i])
                g.attrs["src_kind"] = str(provenance["kind"][i])
                g.attrs["src_valid"] = bool(provenance["valid"][i])
                if transform is not None:
                    g.attrs["src_transform"] = json.dumps(np.asarray(transform[i]).tolist())
                g.create_dataset("actions", data=nxt[lo:hi].reshape(-1, 16).astype(np.float32))
                g.create_dataset("rewards", data=np.zeros(hi - lo))
                dones = np.zeros(hi - lo, np.int64)
                dones[-1] = 1
                g.create_dataset("dones", data=dones)
                for grp, src, objs in (("obs", poses[lo:hi], object_state[lo:hi]),
                                       ("next_obs", nxt[lo:hi], nxt_objects[lo:hi])):
                    og = g.create_group(grp)
                    for key, val in _obs(src.astype(np.float32), objs).items():
                        # `object` is constant while no gripper carries an object: gzip shrinks it cheaply
                        extra = {"compression": "gzip", "compression_opts": 1} if key == "object" else {}
                        og.create_dataset(key, data=np.ascontiguousarray(val), **extra)
            mask = f.create_group("mask")
            mask.create_dataset("train", data=names[~is_val].astype("S"))
            mask.create_dataset("valid", data=names[is_val].astype("S"))
            kinds = np.asarray(provenance["kind"]).astype(str)
            for kind in np.unique(kinds):
                mask.create_dataset(str(kind), data=names[kinds == kind].astype("S"))
    return {"demos": n, "samples": int(lengths.sum()), "train": int((~is_val).sum()), "valid": int(is_val.sum())}


def is_demoforge_robomimic(path: str | os.PathLike) -> bool:
    """True if ``path`` is an hdf5 file this module wrote (so a new export may replace it)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return json.loads(f["data"].attrs["env_args"]).get("format") == FORMAT_VERSION
    except (OSError, KeyError, ValueError, TypeError):
        return False


def read_robomimic_demo(path: str | os.PathLike, demo: str) -> dict:
    """One demo back: {"actions", "obs": {...}, "attrs": {...}} (for checks and tests)."""
    import h5py

    with h5py.File(path, "r") as f:
        if f"data/{demo}" not in f:
            raise ExportError(f"{path}: no data/{demo}")
        g = f[f"data/{demo}"]
        return {"actions": g["actions"][()], "obs": {k: v[()] for k, v in g["obs"].items()},
                "next_obs": {k: v[()] for k, v in g["next_obs"].items()}, "dones": g["dones"][()],
                "attrs": dict(g.attrs)}
