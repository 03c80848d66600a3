"""The ViperX 300 6-DOF's closed-form inverse kinematics, vectorised over any number of poses.

seeds.py solves one pose at a time (scipy's Rotation, a Python loop over its branches): enough for the
first step of an IK window, far too slow to screen millions of candidate pinch poses (base placements,
grasp orientations) before any of them reaches mink. This is the same geometry, branch for branch and
angle for angle, in plain numpy over arrays of poses:

    ik = ViperXBatchIK(ViperXGeometry(model), lower, upper)
    sol = ik.solve(base, pos, R)          # pos (..., 3), R (..., 3, 3) -> sol.q (..., 8, 6)
    ok = sol.closes & sol.in_range        # which branches reach the pose within the joints' ranges
    pts = ik.points(base, sol.q)          # elbow, wrist centre, pinch point (..., 8, 3) for a screening

Branches (axis -2 of q, see BRANCHES): seeds.py's four, in its order (the waist facing the wrist centre or
turned half a turn with the arm leaning over backwards, each with the elbow angle's two signs), then the
same four with the other wrist branch (roll + pi, -pitch, roll2 + pi: the same gripper pose, as
ik.wrist_branch). Every link offset of the model lies in the arm's plane, and the upper arm's forward
offset is the tilt alpha, so the answer is exact up to rounding (tests/lib/sim/robots/aloha/test_closed_form.py measures
it against MuJoCo's forward kinematics).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import LINK_TO_GRIPPER, BasePose
from .seeds import ViperXGeometry

TAU = 2.0 * np.pi
# poses per pass: the temporaries (a few MB) stay in the cache; one pass over 10^6 poses runs at about half
# the speed (measured on one core: 1.0 against 1.8 million poses/s)
CHUNK = 4096
# the elbow above or below the shoulder-wrist line; seeds.py's order (its delta = +acos, -acos per turn)
BRANCHES = tuple(f"{arm}, wrist {wrist}" for wrist in ("as solved", "flipped") for arm in
                 ("facing, elbow up", "facing, elbow down", "leaning back, elbow down", "leaning back, elbow up"))
_SIGN = np.array([1.0, -1.0, 1.0, -1.0])  # the elbow angle's sign per branch (seeds.py's order)
_LEAN = np.array([1.0, 1.0, -1.0, -1.0])  # +1 facing the wrist centre, -1 turned half a turn
# R_link = R @ LINK_TO_GRIPPER.T is a permutation of the pinch frame's columns: pick them, no matmul
_LINK_COLUMNS = np.argmax(LINK_TO_GRIPPER, axis=1)
# below this sin(pitch) the wrist's rolls are one angle (gimbal lock): scipy's rule, roll2 = 0
_GIMBAL = 1e-7


@dataclass
class BatchSolution:
    """Every branch of every pose: q (..., B, 6) joint angles; closes (..., B) the shoulder-elbow triangle
    closes (the wrist centre is within reach; where not, q is the arm stretched towards it, as seeds.py);
    in_range (..., B) every joint inside its range; margin (..., B) the smallest distance (rad) of a joint
    to its range's ends, negative when outside (how much a refinement may move before a limit)."""
    q: np.ndarray
    closes: np.ndarray
    in_range: np.ndarray
    margin: np.ndarray


class ViperXBatchIK:
    """ViperXGeometry.solutions for arrays of poses (see the module docstring)."""

    def __init__(self, geometry: ViperXGeometry, lower: np.ndarray, upper: np.ndarray):
        self.g = geometry
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        if (self.upper - self.lower > TAU).any():
            raise ValueError("a joint range wider than a full turn: its angles have no single best 2 pi shift")
        self.mid, self.half = (self.lower + self.upper) / 2, (self.upper - self.lower) / 2

    def solve(self, base: BasePose, pos: np.ndarray, R: np.ndarray) -> BatchSolution:
        """pos (..., 3) world pinch positions, R (..., 3, 3) pinch-frame rotations (columns: the gripper's x,
        y, z axes; z = approach) -> all 8 branches, angles shifted by 2 pi into the joints' ranges where that
        brings them in (seeds.py leaves them as its atan2s give them; the same joint configuration)."""
        pos, R = np.asarray(pos, float), np.asarray(R, float)
        lead, B = pos.shape[:-1], len(BRANCHES)
        pos, R = pos.reshape(-1, 3), R.reshape(-1, 3, 3)
        q, margin, closes = np.empty((len(pos), B, 6)), np.empty((len(pos), B)), np.empty(len(pos), bool)
        for i in range(0, len(pos), CHUNK):
            part = slice(i, i + CHUNK)
            q_part, closes[part] = self._joints(base, pos[part], R[part])
            q[part], margin[part] = self._wrap(q_part)
        return BatchSolution(q.reshape(*lead, B, 6), np.repeat(closes[:, None], B, axis=1).reshape(*lead, B),
                             (margin >= 0.0).reshape(*lead, B), margin.reshape(*lead, B))

    def joints(self, base: BasePose, pos: np.ndarray, R: np.ndarray) -> np.ndarray:
        """solve's q for n (at most about CHUNK) poses pos (n, 3), R (n, 3, 3), joint first: (6, n, 8), the same
        angles without the margins (a screening takes its own, on each joint's contiguous plane). The arm's
        three joints are shifted once for both wrist branches (theirs are equal)."""
        waist, shoulder, elbow, roll, pitch, roll2 = self._angles(base, np.asarray(pos, float), np.asarray(R, float))[0]
        out = np.empty((6, len(waist), 8))
        for j, x in enumerate((waist, shoulder, elbow)):
            out[j, :, :4] = self._shift(x, j)
            out[j, :, 4:] = out[j, :, :4]
        for j, (x, other) in enumerate(((roll, roll + np.pi), (pitch, -pitch), (roll2, roll2 + np.pi)), start=3):
            out[j, :, :4], out[j, :, 4:] = self._shift(x, j), self._shift(other, j)
        return out

    def _shift(self, x: np.ndarray, j: int) -> np.ndarray:
        """_wrap's shift of joint j's angles x."""
        off = x - self.mid[j]
        off -= TAU * np.rint(off * (1.0 / TAU))
        off += self.mid[j]
        return off

    def points(self, base: BasePose, q: np.ndarray) -> dict[str, np.ndarray]:
        """World positions (..., 3) of the shoulder (the shoulder joint), the elbow, the wrist centre (the
        wrist-angle joint) and the pinch point for joints q (..., 6): what a screening needs for the table's
        clearance and the distance between the two forearms, without MuJoCo."""
        g = self.g
        q = np.asarray(q, float)
        roll, pitch = q[..., 3], q[..., 4]
        ux, uy, shoulder_pt, elbow_pt, wrist_pt, cs, ss = self._arm(base, q)
        # the gripper link's x axis: Rz(phi) Ry(s) Rx(roll) Ry(pitch) x, its lateral part (along z x u) apart
        cp, sp = np.cos(pitch), np.sin(pitch)
        vx, vy, vz = cp, np.sin(roll) * sp, -np.cos(roll) * sp
        ahead, up = cs * vx + ss * vz, -ss * vx + cs * vz
        approach = _in_plane(ux, uy, ahead, up) + np.stack([-uy * vy, ux * vy, np.zeros_like(vy)], axis=-1)
        return {"shoulder": shoulder_pt.copy(), "elbow": elbow_pt, "wrist": wrist_pt,
                "pinch": wrist_pt + g.wrist_to_pinch * approach}

    def wrist(self, base: BasePose, q: np.ndarray) -> np.ndarray:
        """points(base, q)["wrist"] alone (..., 3): the wrist centre, without the pinch point's trigonometry."""
        return self._arm(base, np.asarray(q, float))[4]

    def _arm(self, base: BasePose, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """(ux, uy, shoulder, elbow, wrist centre, cos and sin of shoulder + elbow) of joints q (..., 6): the arm's
        plane and its points up to the wrist, as points() and wrist() take them."""
        g = self.g
        waist, shoulder, elbow = q[..., 0], q[..., 1], q[..., 2]
        ux, uy = np.cos(base.yaw + waist), np.sin(base.yaw + waist)  # the arm's plane, horizontally
        shoulder_pt = np.broadcast_to(np.array([base.x, base.y, base.z + g.shoulder_z]), ux.shape + (3,))
        psi = shoulder + g.alpha  # the upper arm's angle from vertical, towards u
        elbow_pt = shoulder_pt + g.l1 * _in_plane(ux, uy, np.sin(psi), np.cos(psi))
        cs, ss = np.cos(shoulder + elbow), np.sin(shoulder + elbow)
        wrist_pt = elbow_pt + g.l2 * _in_plane(ux, uy, cs, -ss)
        return ux, uy, shoulder_pt, elbow_pt, wrist_pt, cs, ss

    # ------------------------------------------------------------------ the solution, step by step
    def _joints(self, base: BasePose, pos: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q (n, 8, 6) unwrapped, closes (n,)) of n poses: seeds.py's formulas on arrays."""
        (waist, shoulder, elbow, roll, pitch, roll2), closes = self._angles(base, pos, R)
        q = np.empty((len(pos), 8, 6))
        q[:, :4, 0], q[:, :4, 1], q[:, :4, 2] = waist, shoulder, elbow
        q[:, :4, 3], q[:, :4, 4], q[:, :4, 5] = roll, pitch, roll2
        q[:, 4:, :3] = q[:, :4, :3]
        q[:, 4:, 3], q[:, 4:, 4], q[:, 4:, 5] = roll + np.pi, -pitch, roll2 + np.pi  # the other wrist branch
        return q, closes

    def _angles(self, base: BasePose, pos: np.ndarray, R: np.ndarray) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
        """((waist, shoulder, elbow, roll, pitch, roll2) (n, 4) each of the first wrist branch, unwrapped; closes
        (n,)) of n poses: seeds.py's formulas on arrays (the other wrist branch: roll + pi, -pitch, roll2 + pi)."""
        g = self.g
        Rl = R[:, :, _LINK_COLUMNS]  # the gripper link's axes in the world (x = approach)
        d = pos - g.wrist_to_pinch * Rl[:, :, 0] - (base.x, base.y, base.z)  # base -> wrist centre, world axes
        cy, sy = np.cos(base.yaw), np.sin(base.yaw)
        wx, wy = cy * d[:, 0] + sy * d[:, 1], cy * d[:, 1] - sy * d[:, 0]  # in the base frame
        waist = np.arctan2(wy, wx)
        r, h = np.hypot(wx, wy), d[:, 2] - g.shoulder_z
        c = (r * r + h * h - g.l1 ** 2 - g.l2 ** 2) / (2.0 * g.l1 * g.l2)
        closes = np.abs(c) <= 1.0
        delta = np.arccos(np.clip(c, -1.0, 1.0))
        tilt = np.arctan2(g.l2 * np.sin(delta), g.l1 + g.l2 * np.cos(delta))  # upper arm off the shoulder-wrist line
        reach = np.arctan2(r, h)[:, None] * _LEAN  # atan2(-r, h) = -atan2(r, h)
        signed = delta[:, None] * _SIGN
        psi1 = reach - tilt[:, None] * _SIGN
        # the horizontal direction the arm faces (yaw + waist) without trigonometry; waist = 0 where r = 0
        r_safe = np.where(r > 0.0, r, 1.0)
        cw, sw = np.where(r > 0.0, d[:, 0] / r_safe, cy), np.where(r > 0.0, d[:, 1] / r_safe, sy)
        roll, pitch, roll2 = _wrist(Rl, cw, sw, psi1 + signed - np.pi / 2)
        arm = (np.where(_LEAN > 0, waist[:, None], waist[:, None] + np.pi), psi1 - g.alpha, g.alpha + signed - np.pi / 2)
        return arm + (roll, pitch, roll2), closes

    def _wrap(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, margin): each angle shifted by a multiple of 2 pi to within pi of its range's middle (the shift
        that brings it furthest into the range, no range being wider than 2 pi), and per branch the smallest
        distance of a joint to its range's ends (one rounding: comparing the three shifts' margins cost
        more than solving)."""
        off = q - self.mid
        off -= TAU * np.rint(off * (1.0 / TAU))
        margin = _min_last(self.half - np.abs(off))
        off += self.mid
        return off, margin


def _in_plane(ux, uy, along, up) -> np.ndarray:
    """(..., 3) the vector `along` u (horizontal unit vector (ux, uy)) plus `up` z."""
    return np.stack([along * ux, along * uy, up], axis=-1)


def _min_last(a: np.ndarray) -> np.ndarray:
    """a.min(axis=-1) for a short last axis: numpy's reduction over it costs about 10 times the element-wise
    minimum of its slices (250 against 25 ns a pose for 8 x 6 angles)."""
    out = a[..., 0].copy()
    for j in range(1, a.shape[-1]):
        np.minimum(out, a[..., j], out=out)
    return out


def _wrist(Rl: np.ndarray, cw: np.ndarray, sw: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, ...]:
    """(roll, pitch, roll2) (n, 4): the XYX Euler angles of M = R_fore^T R_link per branch, R_fore = Rz(phi)
    Ry(s), (cw, sw) (n,) = cos, sin of phi = yaw + waist, s (n, 4) the forearm's pitch (shoulder + elbow).
    Turned half a turn (phi + pi), Rz's first two rows change sign: that sign is folded into cos s, sin s.
    Only the five (seven in gimbal lock) entries of M the angles need are formed."""
    # A = Rz(phi)^T R_link: rows 0, 1 and 2 (n, 3)
    A0 = cw[:, None] * Rl[:, 0, :] + sw[:, None] * Rl[:, 1, :]
    A1 = cw[:, None] * Rl[:, 1, :] - sw[:, None] * Rl[:, 0, :]
    A2 = Rl[:, 2, :]
    cs, ss = np.cos(s), np.sin(s)
    cl, sl = cs * _LEAN, ss * _LEAN
    # M = Ry(s)^T A (A's rows 0, 1 signed per branch): row 0 = cs A0 - ss A2, row 1 = A1, row 2 = ss A0 + cs A2
    M00, M01, M02 = (cl * A0[:, j, None] - ss * A2[:, j, None] for j in range(3))
    M20 = sl * A0[:, 0, None] + cs * A2[:, 0, None]
    sin_pitch = np.hypot(M01, M02)
    pitch = np.arctan2(sin_pitch, M00)
    roll = np.arctan2(_LEAN * A1[:, 0, None], -M20)
    roll2 = np.arctan2(M01, M02)
    lock = sin_pitch < _GIMBAL
    if lock.any():  # one roll carries the whole turn about x: roll = atan2(M21, M11), roll2 = 0
        M21 = sl * A0[:, 1, None] + cs * A2[:, 1, None]
        roll[lock] = np.arctan2(M21, _LEAN * A1[:, 1, None])[lock]
        roll2[lock] = 0.0
    return roll, pitch, roll2
