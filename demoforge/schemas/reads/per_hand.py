"""The per-(frame, hand) tables of one take (hand_keypoints, aligned_keypoints, gripper_poses, the ground
truth's gt_hand_joints, ...): one row per frame and hand, frame-major with the left hand first.
:func:`rows` and :func:`arrays` convert between those rows and (T, 2, ...) arrays."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from demoforge.schemas.core import column_numpy

HANDS = ("left", "right")


def rows(take: str, task: str, T: int, **columns: Any) -> dict[str, Any]:
    """(T, 2, ...) arrays -> one row per frame and hand, frame-major, left first."""
    out: dict[str, Any] = {
        "take": [take] * (2 * T), "task": [task] * (2 * T),
        "frame": np.repeat(np.arange(T, dtype=np.int32), 2), "hand": list(HANDS) * T,
    }
    for name, value in columns.items():
        if isinstance(value, np.ndarray) and value.ndim >= 2 and value.shape[:2] == (T, 2):
            out[name] = value.reshape((2 * T,) + value.shape[2:])
        else:
            out[name] = value
    return out


def arrays(table: pa.Table, *names: str) -> tuple[int, dict[str, np.ndarray]]:
    """Rows of one take (any order) -> T and {name: (T, 2, ...)} arrays."""
    frame = np.asarray(table.column("frame").to_numpy())
    hand = np.array([HANDS.index(h) for h in table.column("hand").to_pylist()], dtype=np.int64)
    T = int(frame.max()) + 1 if frame.size else 0
    out = {}
    for n in names:
        values = column_numpy(table, n)
        full = np.empty((T, 2) + values.shape[1:], dtype=values.dtype)
        full[frame, hand] = values
        out[n] = full
    return T, out
