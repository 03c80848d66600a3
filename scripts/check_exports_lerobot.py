"""Checks of a demoforge LeRobot export with the real `lerobot` package (run in .venv-lerobot).

    .venv-lerobot/bin/python scripts/check_exports_lerobot.py EXPORT [IMAGE_EXPORT] WORKDIR
    .venv-lerobot/bin/python scripts/check_exports_lerobot.py --joint-space ALOHA_EXPORT

Prints one line per check: CHECK {"check", "ok", "detail"} (JSON).
"""

import json
import sys
import traceback
from pathlib import Path

import numpy as np


def report(name, fn):
    try:
        detail = fn()
        print("CHECK " + json.dumps({"check": name, "ok": True, "detail": detail}), flush=True)
    except Exception as e:  # a check that fails reports why and the others still run
        traceback.print_exc(file=sys.stderr)
        print("CHECK " + json.dumps({"check": name, "ok": False, "detail": f"{type(e).__name__}: {e}"[:300]}), flush=True)


def load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset("demoforge/pouring", root=root, video_backend="pyav",
                          delta_timestamps={"action": [i / 30 for i in range(10)]})


def check_load(root):
    ds = load(root)
    item = ds[5]
    assert item["observation.environment_state"].shape == (33,), item["observation.environment_state"].shape
    assert item["action"].shape == (10, 16), item["action"].shape
    assert ds.meta.total_episodes == ds.num_episodes and len(ds) == ds.meta.total_frames
    return f"{ds.num_episodes} episodes, {len(ds)} frames, action chunk {tuple(item['action'].shape)}"


def check_images(root):
    ds = load(root)
    key = "observation.images.camera"
    last = ds.meta.episodes[ds.num_episodes - 1]
    img = ds[int(last["dataset_to_index"]) - 1][key]  # the last frame of the last episode: timestamps line up
    assert img.ndim == 3 and img.shape[0] == 3 and float(img.max()) > 0.1, (img.shape, float(img.max()))
    return f"{key} {tuple(img.shape)} decoded (pyav), {ds.meta.info['features'][key]['info']['video.codec']}"


def check_stats(root):
    """Recompute the statistics with LeRobot's own compute_episode_stats + aggregate_stats."""
    import pyarrow.parquet as pq
    from lerobot.datasets.compute_stats import aggregate_stats, compute_episode_stats

    info = json.loads((Path(root) / "meta/info.json").read_text())
    feats = {k: v for k, v in info["features"].items() if v["dtype"] not in ("video", "image", "string")}
    t = pq.read_table(sorted((Path(root) / "data").rglob("*.parquet"))).to_pandas() \
        if False else __import__("pandas").concat([pq.read_table(p).to_pandas()
                                                   for p in sorted((Path(root) / "data").rglob("*.parquet"))])
    per_ep = []
    for _, g in t.groupby("episode_index"):
        per_ep.append(compute_episode_stats({k: np.stack(g[k].to_numpy()) if info["features"][k]["shape"] != [1]
                                             else g[k].to_numpy() for k in feats}, feats))
    theirs = aggregate_stats(per_ep)
    ours = json.loads((Path(root) / "meta/stats.json").read_text())
    worst = {}
    for k in feats:
        rng = np.maximum(np.asarray(theirs[k]["max"], float) - np.asarray(theirs[k]["min"], float), 1e-12)
        for s, v in theirs[k].items():
            d = np.abs(np.asarray(ours[k][s], float) - np.asarray(v, float)) / rng
            worst[s] = max(worst.get(s, 0.0), float(d.max()))
    bad = {s: v for s, v in worst.items() if v > 1e-3}
    assert not bad, f"differences / range above 1e-3: {bad}"
    return "largest abs(ours - lerobot) / range: " + ", ".join(f"{s} {v:.1e}" for s, v in worst.items())


def check_split(root, work):
    from lerobot.datasets.dataset_tools import split_dataset
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("demoforge/pouring", root=root, video_backend="pyav")
    n = ds.num_episodes
    out = split_dataset(ds, {"train": list(range(n - 2)), "val": [n - 2, n - 1]}, output_dir=Path(work) / "split")
    val = out["val"]
    takes = set(val.hf_dataset["demoforge.take"])
    ids = sorted(set(int(x) for x in val.hf_dataset["demoforge.episode_id"]))
    src_ids = sorted(set(int(x) for x in ds.hf_dataset.filter(lambda r: r["episode_index"] >= n - 2)
                         ["demoforge.episode_id"]))
    assert ids == src_ids and takes, (ids, src_ids)
    return f"after split_dataset the val split's rows still name take {sorted(takes)} and episode ids {ids}"


def check_delete(root, work):
    from lerobot.datasets.dataset_tools import delete_episodes
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("demoforge/pouring", root=root, video_backend="pyav")
    src = [int(x) for x in ds.hf_dataset["demoforge.episode_id"]]
    src_ep = [int(x) for x in ds.hf_dataset["episode_index"]]
    kept = sorted({e: i for e, i in zip(src_ep, src) if e != 0}.values())
    out = delete_episodes(ds, episode_indices=[0], output_dir=Path(work) / "deleted",
                          repo_id="demoforge/pouring_deleted")
    ids = sorted(set(int(x) for x in out.hf_dataset["demoforge.episode_id"]))
    assert ids == kept, (ids, kept)
    return (f"after delete_episodes([0]) the rows still name episode ids {ids} "
            f"(meta/demoforge.json kept: {(Path(work) / 'deleted' / 'meta/demoforge.json').exists()})")


def check_joint_space(root):
    """The `--robot aloha` export: 14 joint values per step named as the ALOHA datasets name them."""
    ds = load(root)
    item = ds[3]
    names = ds.meta.info["features"]["observation.state"]["names"]
    assert item["observation.state"].shape == (14,) and item["action"].shape == (10, 14), item["action"].shape
    assert names[:7] == ["left_waist", "left_shoulder", "left_elbow", "left_forearm_roll", "left_wrist_angle",
                         "left_wrist_rotate", "left_gripper"] and names[7] == "right_waist", names
    assert ds.meta.info["robot_type"] == "aloha"
    return f"{ds.num_episodes} episodes, state {tuple(item['observation.state'].shape)}, robot_type aloha"


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[0] == "--joint-space":
        report("lerobot: LeRobotDataset loads the ALOHA joint-space export", lambda: check_joint_space(args[1]))
        sys.exit(0)
    root, work = args[0], args[-1]
    report("lerobot: LeRobotDataset loads the export offline", lambda: check_load(root))
    report("lerobot: stats.json equals LeRobot's compute_episode_stats + aggregate_stats", lambda: check_stats(root))
    report("lerobot: provenance survives split_dataset", lambda: check_split(root, work))
    report("lerobot: provenance survives delete_episodes", lambda: check_delete(root, work))
    if len(args) == 3:
        report("lerobot: video frames decode (observation.images.camera)", lambda: check_images(args[1]))
