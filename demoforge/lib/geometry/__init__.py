"""Rigid-body geometry for demoforge: quaternions, SE(3), mirroring, alignment, interpolation.

Conventions (docs/architecture.md, fixed):

* quaternions are scalar-last ``[qx, qy, qz, qw]`` (``scipy.spatial.transform.Rotation.as_quat``);
  MuJoCo's scalar-first order appears only through :func:`xyzw_to_wxyz` / :func:`wxyz_to_xyzw`;
* rotations act on column vectors, ``quat_to_matrix(a * b) == quat_to_matrix(a) @ quat_to_matrix(b)``;
* transforms are 4x4 homogeneous matrices ``[[R, t], [0, 1]]``;
* a gripper pose is 8 values ``[x, y, z, qx, qy, qz, qw, g]`` with g = 1 open, 0 closed;
* the gripper frame is z = approach, x = thumb -> index (closing direction), y = z cross x;
* the mirror plane defaults to the world YZ plane (n = (1, 0, 0), d = 0);
* metres, radians, seconds.

Every function is vectorised over leading batch dimensions ``...`` (numpy broadcasting rules)
except where its docstring says the first axis is time (the interpolation functions).
Invalid input (wrong shapes, zero-norm quaternions or vectors, too few points) raises ValueError.

The code lives in submodules; import from the package, which re-exports all of it:
rotations (quaternions, matrices, vectors, random and yaw rotations), transforms (SE(3), pose7/pose8,
mirroring), alignment (umeyama, apply_similarity), interpolation (interpolate_poses, cubic_transition),
camera (project_points, backproject).
"""

from __future__ import annotations

from demoforge.lib.geometry._checks import _EPS_NORM, _as_float, _unit_vectors  # noqa: F401
from demoforge.lib.geometry.alignment import apply_similarity, umeyama
from demoforge.lib.geometry.camera import backproject, project_points
from demoforge.lib.geometry.interpolation import hemisphere_continuous, cubic_transition, interpolate_poses  # noqa: F401
from demoforge.lib.geometry.rotations import (
    matrix_to_quat,
    quat_angle,
    quat_canonical,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_normalize,
    quat_slerp,
    quat_to_matrix,
    random_quaternions,
    random_rotations,
    rotation_between_vectors,
    skew,
    wxyz_to_xyzw,
    xyzw_to_wxyz,
    yaw_rotation,
)
from demoforge.lib.geometry.transforms import (  # noqa: F401  (the private helpers stay importable from here)
    _X_AXIS,
    _apply_linear,
    _check_flip_column,
    make_transform,
    pose7_to_transform,
    pose8_to_transform,
    reflect_points,
    reflect_pose8,
    reflect_quat,
    reflect_rotation,
    reflect_transform,
    reflection_matrix,
    transform_compose,
    transform_inverse,
    transform_points,
    transform_to_pose7,
    transform_to_pose8,
)


__all__ = [
    "quat_normalize",
    "quat_canonical",
    "quat_multiply",
    "quat_conjugate",
    "quat_to_matrix",
    "matrix_to_quat",
    "quat_angle",
    "quat_exp",
    "quat_log",
    "quat_slerp",
    "xyzw_to_wxyz",
    "wxyz_to_xyzw",
    "skew",
    "rotation_between_vectors",
    "make_transform",
    "transform_inverse",
    "transform_compose",
    "transform_points",
    "pose8_to_transform",
    "transform_to_pose8",
    "pose7_to_transform",
    "transform_to_pose7",
    "reflection_matrix",
    "reflect_points",
    "reflect_rotation",
    "reflect_quat",
    "reflect_transform",
    "reflect_pose8",
    "umeyama",
    "apply_similarity",
    "interpolate_poses",
    "cubic_transition",
    "random_rotations",
    "random_quaternions",
    "yaw_rotation",
]
