"""A small table contract of the tests' own, `_test_poses` (registered on import), and rows for it."""

import numpy as np
import pyarrow as pa

from demoforge.schemas.core import Column, dual_pose8, keypoints3d, table

POSES = table(
    "_test_poses",
    version=3,
    doc="test table",
    columns=[
        Column("take", pa.string(), "take id"),
        Column("frame", pa.int64(), "frame index"),
        Column("joints", keypoints3d(21), "joints, m"),
        Column("action", dual_pose8(), "2x8 poses"),
        Column("score", pa.float64(), "optional score", nullable=True),
    ],
    partition_by=("take",),
)


def pose_rows(n=4, take="t1", seed=0):
    rng = np.random.default_rng(seed)
    return {
        "take": [take] * n,
        "frame": np.arange(n),
        "joints": rng.normal(size=(n, 21, 3)),
        "action": rng.normal(size=(n, 2, 8)),
        "score": [0.5] * n,
    }

