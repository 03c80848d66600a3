"""The column types the contracts are written in: fixed-shape lists for points, poses and matrices."""

from __future__ import annotations

import pyarrow as pa


def vec3() -> pa.DataType:
    return pa.list_(pa.float64(), 3)


def fixed_list(value_type: pa.DataType, size: int) -> pa.DataType:
    return pa.list_(value_type, size)


def keypoints3d(n: int) -> pa.DataType:
    """n x 3 points as a fixed-size list of fixed-size lists."""
    return pa.list_(pa.list_(pa.float64(), 3), n)


def keypoints2d(n: int) -> pa.DataType:
    return pa.list_(pa.list_(pa.float64(), 2), n)


def pose8() -> pa.DataType:
    """[x, y, z, qx, qy, qz, qw, g]: world-frame position (m), unit quaternion (scalar-last), gripper 1=open."""
    return pa.list_(pa.float64(), 8)


def dual_pose8() -> pa.DataType:
    """2 x 8: arm 0 = left, arm 1 = right."""
    return pa.list_(pa.list_(pa.float64(), 8), 2)


def matrix4() -> pa.DataType:
    return pa.list_(pa.list_(pa.float64(), 4), 4)
