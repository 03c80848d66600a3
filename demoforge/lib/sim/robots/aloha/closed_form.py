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

import math
from dataclasses import dataclass

import numba
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
_INV_TAU = 1.0 / TAU  # _wrap's factor, for the kernels (the same double)


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

    def solve_into(self, base: BasePose, n: int, poses, at: np.ndarray, q: np.ndarray, m: np.ndarray, q5f: np.ndarray,
                   mf: np.ndarray) -> None:
        """A screening's joints of n poses, written into the rows at (n,) of q (N, 8, 6), m, q5f, mf (N, 8): solve's
        angles (bit for bit), m the smallest margin half - |q - mid| of a joint, q5f the last joint of the grasp
        half-turned about its approach (+ pi, shifted into its range) and mf that grasp's margin. poses(i, j)
        gives the poses i to j (pos (j - i, 3), R (j - i, 3, 3), C-contiguous). Chunk by chunk: numba kernels
        between numpy's transcendental functions (see the kernels' section), no (n, 8, 6) temporaries."""
        g, geo, ch = self.g, self.kernel_geometry(base), max(min(n, SCREEN_CHUNK), 1)
        Y1, X1, cc, A, s = np.empty((ch, 2)), np.empty((ch, 2)), np.empty(ch), np.empty((ch, 8)), np.empty((ch, 4))
        W, arm, Y, X, ang = np.empty((ch, 2)), np.empty((ch, 4, 3)), np.empty((ch, 3, 4)), np.empty((ch, 3, 4)), \
            np.empty((ch, 3, 4))
        for i in range(0, n, ch):
            k = min(ch, n - i)
            pos, R = poses(i, i + k)
            _arm_inputs(geo, pos, R, Y1[:k], X1[:k], cc[:k], A[:k])
            np.arctan2(Y1[:k], X1[:k], out=W[:k])  # waist, reach
            delta = np.arccos(cc[:k])
            tilt = np.arctan2(g.l2 * np.sin(delta), g.l1 + g.l2 * np.cos(delta))
            _forearm(geo, W[:k], delta, tilt, s[:k], arm[:k])
            cs, ss = np.cos(s[:k]), np.sin(s[:k])
            locked = _wrist_inputs(A[:k], cs, ss, Y[:k], X[:k])
            np.arctan2(Y[:k], X[:k], out=ang[:k])  # pitch, roll, roll2
            if locked:  # _wrist's rule, on its arrays
                lock = Y[:k, 0] < _GIMBAL
                M21 = ss * _LEAN * A[:k, 1, None] + cs * A[:k, 6, None]
                ang[:k, 1][lock] = np.arctan2(M21, _LEAN * A[:k, 4, None])[lock]
                ang[:k, 2][lock] = 0.0
            _wrap_into(arm[:k], ang[:k], self.mid, self.half, at[i:i + k], q, m, q5f, mf)

    def kernel_geometry(self, base: BasePose) -> np.ndarray:
        """The numbers the kernels take of the arm on `base` (KERNEL_GEOMETRY's order), each computed as
        _angles computes it (numpy's cos and sin of the yaw, Python's powers and products)."""
        g = self.g
        return np.array([base.x, base.y, base.z, np.cos(base.yaw), np.sin(base.yaw), g.wrist_to_pinch, g.shoulder_z,
                         g.l1, g.l2, g.l1 ** 2, g.l2 ** 2, 2.0 * g.l1 * g.l2, g.alpha])

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

    def segments(self, base: BasePose, q: np.ndarray, u: np.ndarray, extra: int = 0) -> np.ndarray:
        """(..., 2 len(u) + extra, 3) the points elbow + u (wrist - elbow), then wrist + u (pinch - wrist) of joints
        q (..., 6) (points()'s elbow, wrist centre and pinch point), then `extra` slots left for the caller: the
        same numbers as points() interpolated (its sines and cosines numpy's, on whole arrays; the rest in
        _segments_kernel, pose by pose, in points()'s order of operations)."""
        g = self.g
        lead = np.shape(q)[:-1]
        q = np.asarray(q, float).reshape(-1, 6)
        waist, shoulder, elbow, roll, pitch = q[:, 0], q[:, 1], q[:, 2], q[:, 3], q[:, 4]
        psi, fore = shoulder + g.alpha, shoulder + elbow
        trig = np.stack([np.cos(base.yaw + waist), np.sin(base.yaw + waist), np.sin(psi), np.cos(psi), np.cos(fore),
                         np.sin(fore), np.cos(pitch), np.sin(pitch), np.sin(roll), np.cos(roll)], axis=1)
        consts = np.array([base.x, base.y, base.z + g.shoulder_z, g.l1, g.l2, g.wrist_to_pinch])
        out = _segments_kernel(trig, consts, np.asarray(u, float), int(extra))
        return out.reshape(lead + out.shape[1:])

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


# ---------------------------------------------------------------------- a screening's joints: numba + numpy
# A screening solves millions of poses, thousands per call. numpy's _angles makes a dozen passes over (n, 4)
# temporaries per step; a numba kernel pose by pose is no faster whole, its scalar atan2 and acos (libm) costing
# 7 and 4 times numpy's SIMD ones (and differing from them in the last bit for a few percent of the arguments).
# So solve_into takes the arithmetic between the transcendental functions to numba kernels, pose by pose, and
# leaves every atan2, acos, sin and cos to numpy on whole chunks: the same operations in the same order as
# _angles, _wrist and _wrap (no fastmath: no reassociation, no fused multiply-adds), the angles solve()'s bit
# for bit. (hypot is the kernels': numpy's is libm's too.)
KERNEL_GEOMETRY = ("base x", "base y", "base z", "cos yaw", "sin yaw", "wrist to pinch", "shoulder z", "l1", "l2",
                   "l1^2", "l2^2", "2 l1 l2", "alpha")
SCREEN_CHUNK = 2048  # poses per pass of solve_into: its buffers (a few hundred kB) stay in the cache


@numba.njit(cache=True)
def _arm_inputs(geo: np.ndarray, pos: np.ndarray, R: np.ndarray, Y: np.ndarray, X: np.ndarray, cc: np.ndarray,
                A: np.ndarray) -> None:
    """_angles up to its first atan2s and acos, of poses pos (k, 3), R (k, 3, 3) on the arm geo (kernel_geometry):
    (Y, X) (k, 2) the arguments of the waist's and the reach's atan2, cc (k,) the clipped cosine of the elbow,
    A (k, 8) the entries of A = Rz(phi)^T R_link _wrist needs (A0 0-2, A1 0-1, A2 0-2)."""
    lc = _LINK_COLUMNS
    cy, sy = geo[3], geo[4]
    for i in range(len(pos)):
        d0 = pos[i, 0] - geo[5] * R[i, 0, lc[0]] - geo[0]  # base -> wrist centre, world axes
        d1 = pos[i, 1] - geo[5] * R[i, 1, lc[0]] - geo[1]
        d2 = pos[i, 2] - geo[5] * R[i, 2, lc[0]] - geo[2]
        wx, wy = cy * d0 + sy * d1, cy * d1 - sy * d0
        r, h = math.hypot(wx, wy), d2 - geo[6]
        c = (r * r + h * h - geo[9] - geo[10]) / geo[11]
        cc[i] = -1.0 if c < -1.0 else (1.0 if c > 1.0 else c)  # np.clip's (NaN stays NaN)
        Y[i, 0], X[i, 0], Y[i, 1], X[i, 1] = wy, wx, r, h
        cw, sw = (d0 / r, d1 / r) if r > 0.0 else (cy, sy)
        for j in range(3):
            A[i, j] = cw * R[i, 0, lc[j]] + sw * R[i, 1, lc[j]]
            A[i, 5 + j] = R[i, 2, lc[j]]
        for j in range(2):
            A[i, 3 + j] = cw * R[i, 1, lc[j]] - sw * R[i, 0, lc[j]]


@numba.njit(cache=True)
def _forearm(geo: np.ndarray, W: np.ndarray, delta: np.ndarray, tilt: np.ndarray, s: np.ndarray,
             arm: np.ndarray) -> None:
    """_angles' arm: from W (k, 2) = (waist, reach) and the elbow's delta, tilt (k,), per branch the forearm's
    pitch s (k, 4) and the unwrapped waist, shoulder and elbow arm (k, 4, 3)."""
    for i in range(len(W)):
        for b in range(4):
            signed = delta[i] * _SIGN[b]
            psi1 = W[i, 1] * _LEAN[b] - tilt[i] * _SIGN[b]
            s[i, b] = psi1 + signed - np.pi / 2
            arm[i, b, 0] = W[i, 0] if _LEAN[b] > 0 else W[i, 0] + np.pi
            arm[i, b, 1] = psi1 - geo[12]
            arm[i, b, 2] = geo[12] + signed - np.pi / 2


@numba.njit(cache=True)
def _wrist_inputs(A: np.ndarray, cs: np.ndarray, ss: np.ndarray, Y: np.ndarray, X: np.ndarray) -> int:
    """_wrist's entries of M = Ry(s)^T A per branch (cs, ss (k, 4): cos s, sin s) as the arguments (Y, X)
    (k, 3, 4) of the pitch's, the roll's and the second roll's atan2; returns how many are in gimbal lock."""
    locked = 0
    for i in range(len(A)):
        for b in range(4):
            cl, lean = cs[i, b] * _LEAN[b], _LEAN[b]
            m01, m02 = cl * A[i, 1] - ss[i, b] * A[i, 6], cl * A[i, 2] - ss[i, b] * A[i, 7]
            sin_pitch = math.hypot(m01, m02)
            Y[i, 0, b], X[i, 0, b] = sin_pitch, cl * A[i, 0] - ss[i, b] * A[i, 5]
            Y[i, 1, b], X[i, 1, b] = lean * A[i, 3], -(ss[i, b] * lean * A[i, 0] + cs[i, b] * A[i, 5])
            Y[i, 2, b], X[i, 2, b] = m01, m02
            locked += sin_pitch < _GIMBAL
    return locked


@numba.njit(cache=True)
def _shift_angle(x: float, mid: float) -> float:
    """_wrap's shift of one angle x by a multiple of 2 pi to within pi of its range's middle mid."""
    off = x - mid
    off -= TAU * np.rint(off * _INV_TAU)
    return off + mid


@numba.njit(cache=True)
def _nan_min(a: float, b: float) -> float:
    """np.minimum of two numbers: NaN if either is."""
    return a if (a < b or a != a) else b


@numba.njit(cache=True)
def _wrap_into(arm: np.ndarray, ang: np.ndarray, mid: np.ndarray, half: np.ndarray, at: np.ndarray, q: np.ndarray,
               m: np.ndarray, q5f: np.ndarray, mf: np.ndarray) -> None:
    """_wrap of the arm's angles arm (k, 4, 3) and the wrist's ang (k, 3, 4) (pitch, roll, roll2 of the first
    wrist branch; the other: roll + pi, -pitch, roll2 + pi) into the rows at (k,): q (N, 8, 6), m (N, 8) the
    smallest margin half - |q - mid| of a joint, q5f (N, 8) the last joint of the gripper half-turned about its
    approach (+ pi, shifted: its range is a full turn, every other joint's margin stays), mf (N, 8) its margin."""
    for i in range(len(arm)):
        row = at[i]
        for b in range(4):
            margin = np.inf
            for j in range(3):
                x = _shift_angle(arm[i, b, j], mid[j])
                q[row, b, j], q[row, b + 4, j] = x, x
                mj = half[j] - abs(x - mid[j])
                margin = mj if j == 0 else _nan_min(margin, mj)
            roll, pitch, roll2 = ang[i, 1, b], ang[i, 0, b], ang[i, 2, b]
            for k, wrist in ((b, (roll, pitch, roll2)), (b + 4, (roll + np.pi, -pitch, roll2 + np.pi))):
                m04 = margin
                for j in range(3, 6):
                    x = _shift_angle(wrist[j - 3], mid[j])
                    q[row, k, j] = x
                    if j < 5:
                        m04 = _nan_min(m04, half[j] - abs(x - mid[j]))
                m[row, k] = _nan_min(m04, half[5] - abs(x - mid[5]))
                off = x + np.pi - mid[5]
                off -= TAU * np.rint(off / TAU)
                q5f[row, k] = off + mid[5]
                mf[row, k] = _nan_min(m04, half[5] - abs(off))


@numba.njit(cache=True)
def _segments_kernel(trig: np.ndarray, k: np.ndarray, u: np.ndarray, extra: int) -> np.ndarray:
    """ViperXBatchIK.segments' arithmetic per pose: trig (n, 10) the cosines and sines of the arm's plane (ux, uy),
    the upper arm's angle, the forearm's, the pitch and the roll; k the shoulder point's x, y, z, l1, l2 and
    the wrist -> pinch distance. points()'s products and sums in its order (elbow = shoulder + l1 (along u, up),
    the wrist the same from the elbow, the approach axis, the pinch), then the interpolation start + u d."""
    n, m = trig.shape[0], len(u)
    out = np.zeros((n, 2 * m + extra, 3))
    for i in range(n):
        ux, uy, spsi, cpsi, cs, ss, cp, sp, sr, cr = (trig[i, 0], trig[i, 1], trig[i, 2], trig[i, 3], trig[i, 4],
                                                      trig[i, 5], trig[i, 6], trig[i, 7], trig[i, 8], trig[i, 9])
        e0, e1, e2 = k[0] + k[3] * (spsi * ux), k[1] + k[3] * (spsi * uy), k[2] + k[3] * cpsi
        w0, w1, w2 = e0 + k[4] * (cs * ux), e1 + k[4] * (cs * uy), e2 + k[4] * -ss
        vx, vy, vz = cp, sr * sp, -cr * sp
        ahead, up = cs * vx + ss * vz, -ss * vx + cs * vz
        a0, a1, a2 = ahead * ux + -uy * vy, ahead * uy + ux * vy, up + 0.0
        p0, p1, p2 = w0 + k[5] * a0, w1 + k[5] * a1, w2 + k[5] * a2
        d0, d1, d2, f0, f1, f2 = w0 - e0, w1 - e1, w2 - e2, p0 - w0, p1 - w1, p2 - w2
        for j in range(m):
            out[i, j, 0], out[i, j, 1], out[i, j, 2] = e0 + u[j] * d0, e1 + u[j] * d1, e2 + u[j] * d2
            out[i, m + j, 0], out[i, m + j, 1], out[i, m + j, 2] = w0 + u[j] * f0, w1 + u[j] * f1, w2 + u[j] * f2
    return out
