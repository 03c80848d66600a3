"""What the arms' planner derives from an episode before any inverse kinematics, batched over the episodes
of one group (screening.py): the smoothed poses (aloha/__init__.py SMOOTH_SIGMA), the object each hand
holds (trajectories/segmentation.py held_objects), each arm's window (arm_motion.py follow_windows with the
motion/skill segmentation it runs) and the objects' poses (retargeting.py object_poses_at_start,
retarget.py object_trajectories) at given steps.

Each function is the per-episode one's arithmetic on a leading episode axis; a *group* is a set of
episodes with the same length, the same gripper open/close steps and the same held object in each closed
run (augmentation keeps the timing: a database has one group per kind, original and translated episodes
sharing one), so the run structure (which steps are closed, which object a run holds) is the group's.
The windows themselves are computed per episode: they move by a few steps between the episodes of a
group (the skill segments start where a hand comes within 6 cm of its object, and the approach runs the
last 10 cm of a path whose blend differs per episode).
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.optimize import nnls

from demoforge.lib.geometry import pose7_to_transform, transform_inverse, umeyama
from demoforge.lib.sim.robots.arm_motion import APPROACH
from demoforge.lib.trajectories.segmentation import HULL_WEIGHT, NEAREST_KEYPOINT_WEIGHT, SegmentationParams


# a quaternion shorter than this has no direction (the bound lib/geometry's quat_normalize refuses below)
ZERO_NORM = 1e-12
WINDOW_BATCH = 64  # episodes per pass of windows_batch (1.5x faster than 256 at once: memory, not arithmetic)


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of the True runs of a (T,) bool array."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(mask, np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def norm_last(v: np.ndarray) -> np.ndarray:
    """np.linalg.norm(v, axis=-1) for a short last axis, the same sum in the same order (numpy's reduction over
    a few elements adds them one by one) by element-wise operations (a reduction over it costs ten times)."""
    s = v[..., 0] * v[..., 0]
    for j in range(1, v.shape[-1]):
        s += v[..., j] * v[..., j]
    return np.sqrt(s)


def smooth_batch(actions: np.ndarray, sigma: float, episodes: np.ndarray | None = None) -> np.ndarray:
    """keyframes.smooth_actions of each episode of a group (E, T, 2, 8), the same numbers: the gripper's changes
    (the runs smoothed on their own) are the group's; scipy's Gaussian (its weights, its symmetric correlation
    with the ends repeated) done by _smooth_kernel, episode by episode. episodes (E,): the numbers an error
    names them by (default 0 to E - 1)."""
    a = np.ascontiguousarray(actions, float)
    out = a.copy()
    if sigma == 0 or a.shape[1] < 3:
        return out
    opened = a[0, :, :, 7] >= 0.5
    cuts = [0, *(np.flatnonzero(np.any(opened[1:] != opened[:-1], axis=1)) + 1).tolist(), a.shape[1]]
    runs_ = np.array([(s0, s1) for s0, s1 in zip(cuts[:-1], cuts[1:]) if s1 - s0 >= 3], np.int64).reshape(-1, 2)
    bad = _smooth_kernel(a, out, gaussian_weights(float(sigma)), runs_)
    if bad[0]:  # (numpy's planes gave NaN here, and lib/geometry's quat_normalize this error after them)
        raise ValueError(f"smooth_batch: {bad[0]} quaternion(s) have zero norm or non-finite values (the first: "
                         f"episode {bad[1] if episodes is None else episodes[bad[1]]}, step {bad[2]}, arm {bad[3]})")
    return out


def gaussian_weights(sigma: float) -> np.ndarray:
    """(r + 1,) scipy's gaussian_filter1d weights from the centre out: its own filter of a unit impulse (the weights
    exactly: every other term it adds is zero)."""
    from scipy.ndimage import gaussian_filter1d

    r = int(4.0 * sigma + 0.5)  # scipy's radius (truncate 4)
    impulse = np.zeros(2 * r + 1)
    impulse[r] = 1.0
    return gaussian_filter1d(impulse, sigma, mode="constant")[r:]


@numba.njit(cache=True)
def _smooth_kernel(a, out, w, runs_):
    """smooth_batch into out: per episode and arm the quaternions normalised (norm_last's sum) and made
    hemisphere-continuous over the whole episode, then per run [s0, s1) (runs_ (k, 2)) each position and
    quaternion channel correlated with the weights w as scipy's correlate1d does for symmetric weights
    (centre term first, then the pairs from the outermost in, left + right; 'nearest': the run's ends
    repeated, here as padding) and the quaternions normalised again. Each step's sum is its own, so the
    loop runs over the steps innermost (SIMD lanes), a tap at a time. Returns the count of quaternions with no
    length or non-finite values and the first one's (episode, step, arm)."""
    E, T, r = a.shape[0], a.shape[1], len(w) - 1
    bad = np.zeros(4, np.int64)  # quaternions with no length or non-finite values: their count, the first's (e, t, arm)
    qc, prev = np.empty((T, 4)), np.empty(4)  # one arm's continuous quaternions; the step before's, unflipped
    x = np.empty((7, T + 2 * r))  # one run's channels, padded by r repeats of its ends
    acc = np.empty(T)
    for e in range(E):
        for arm in range(2):
            sign = 1.0
            for t in range(T):
                s = a[e, t, arm, 3] * a[e, t, arm, 3]
                for j in range(1, 4):
                    s += a[e, t, arm, 3 + j] * a[e, t, arm, 3 + j]
                n = np.sqrt(s)
                if not n > ZERO_NORM or not np.isfinite(s):  # (no division by it: counted, the first kept)
                    if not bad[0]:
                        bad[1], bad[2], bad[3] = e, t, arm
                    bad[0] += 1
                    n = 1.0
                d = 0.0
                for j in range(4):
                    qj = a[e, t, arm, 3 + j] / n
                    d = qj * prev[j] if j == 0 else d + qj * prev[j]
                    prev[j] = qj
                if t and d < 0.0:  # hemisphere_continuous: the unflipped neighbours' dot
                    sign = -sign
                for j in range(4):
                    qc[t, j] = prev[j] * sign
            for k in range(runs_.shape[0]):
                s0, s1 = runs_[k, 0], runs_[k, 1]
                m = s1 - s0
                for t in range(m + 2 * r):
                    src = min(max(s0 + t - r, s0), s1 - 1)
                    for j in range(3):
                        x[j, t] = a[e, src, arm, j]
                    for j in range(4):
                        x[3 + j, t] = qc[src, j]
                for j in range(7):
                    for t in range(m):
                        acc[t] = x[j, t + r] * w[0]
                    for i in range(r, 0, -1):
                        wi = w[i]
                        for t in range(m):
                            acc[t] += (x[j, t + r - i] + x[j, t + r + i]) * wi
                    for t in range(m):
                        out[e, s0 + t, arm, j] = acc[t]
                for t in range(s0, s1):
                    s = out[e, t, arm, 3] * out[e, t, arm, 3]
                    for j in range(1, 4):
                        s += out[e, t, arm, 3 + j] * out[e, t, arm, 3 + j]
                    n = np.sqrt(s)
                    for j in range(3, 7):
                        out[e, t, arm, j] /= n
    return bad


def held_batch(traj: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray,
               closed_below: float = 0.5) -> np.ndarray:
    """(E, T, 2) segmentation.held_objects of each episode of a group (E, T, 2, 8) with its keypoints (E, K, 3)
    (the runs: the group's). An object's score is its hull distance (at most its nearest keypoint's) plus
    NEAREST_KEYPOINT_WEIGHT times that keypoint's distance, so the hull distances are solved only where the
    bounds (_score_bounds) leave more than one object in the running."""
    E, T = traj.shape[:2]
    ko = np.asarray(keypoint_object, int)
    held = np.full((E, T, 2), -1)
    for arm in range(2):
        for a, b in runs(traj[0, :, arm, 7] < closed_below):  # the group's closed runs
            p = traj[:, a, arm, :3]
            low, high = _score_bounds(keypoints0, ko, p)
            choice = np.argmin(high, axis=1)
            open_rows = np.flatnonzero((low <= high.min(axis=1, keepdims=True)).sum(axis=1) > 1)
            if len(open_rows):
                choice[open_rows] = np.argmin(held_scores(keypoints0[open_rows], ko, p[open_rows]), axis=1)
            held[:, a:b, arm] = choice[:, None]
    return held


def held_scores(kp: np.ndarray, ko: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(n, n_obj) segmentation.grasped_object_scores of n rows (keypoints kp (n, K, 3), pinch points p (n, 3)), the
    same numbers: each object's NNLS system (hull_distance's) and nearest keypoint taken for every row at once,
    only the solve and its residual per row (the per-call set-up cost several times the solve)."""
    n = len(p)
    out = np.empty((n, int(ko.max()) + 1))
    for o in range(out.shape[1]):
        K = np.ascontiguousarray(kp[:, ko == o])  # (n, k, 3), each row's (k, 3) contiguous as hull_distance's
        A = np.concatenate([np.swapaxes(K, 1, 2), np.full((n, 1, K.shape[1]), HULL_WEIGHT)], axis=1)  # (n, 4, k)
        b = np.concatenate([p, np.full((n, 1), HULL_WEIGHT)], axis=1)
        near = np.linalg.norm(K - p[:, None], axis=-1).min(axis=1)
        for e in range(n):
            w, _ = nnls(A[e], b[e])
            # K[e].T: hull_distance's own (3, k) layout, so the product sums in its order
            out[e, o] = float(np.linalg.norm(K[e].T @ w - p[e])) + NEAREST_KEYPOINT_WEIGHT * near[e]
    return out


def _score_bounds(kp: np.ndarray, ko: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) (E, n_obj) bounds of segmentation.grasped_object_scores of pinch points p (E, 3). hull_distance
    solves min |K^T w - p|^2 + (H (sum w - 1))^2 over w >= 0 (H = HULL_WEIGHT) and returns |K^T w - p|: the nearest
    keypoint alone scores its distance squared, so that is at most the nearest keypoint's distance `near`, and
    |sum w - 1| <= near / H; K^T w is then (sum w) times a point of the hull, no nearer to p than the object's
    bounding sphere (centre c, radius r), less |sum w - 1| times the keypoints' largest norm."""
    d = np.linalg.norm(kp - p[:, None], axis=-1)  # (E, K)
    low, high = [], []
    for o in range(int(ko.max()) + 1):
        K = kp[:, ko == o]
        near = d[:, ko == o].min(axis=1)
        c = K.mean(axis=1)
        r = np.linalg.norm(K - c[:, None], axis=-1).max(axis=1)
        slack = 1.01 * near / HULL_WEIGHT * np.linalg.norm(K, axis=-1).max(axis=1) + 1e-9
        hull = np.maximum(np.linalg.norm(p - c, axis=-1) - r - slack, 0.0)
        low.append(hull + NEAREST_KEYPOINT_WEIGHT * near)
        high.append((1.0 + NEAREST_KEYPOINT_WEIGHT) * near)
    return np.stack(low, axis=1), np.stack(high, axis=1)


def keypoints_over_time(traj: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray,
                        held: np.ndarray) -> np.ndarray:
    """(E, T, 3, K) segmentation.object_keypoints_over_time of a group (held (T, 2): the group's), the
    coordinate before the keypoint (each coordinate's keypoints contiguous: the distances below run on
    (E, T) planes without reductions over a 3-axis)."""
    E, T = traj.shape[:2]
    out = np.broadcast_to(np.swapaxes(keypoints0, 1, 2)[:, None], (E, T, 3, keypoints0.shape[1])).copy()
    for arm in range(2):
        for a, b in runs(held[:, arm] >= 0):
            sel = keypoint_object == held[a, arm]
            R0, t0 = rotations(traj[:, a, arm]), traj[:, a, arm, :3]
            rel = np.swapaxes(R0, 1, 2) @ (out[:, a][:, :, sel] - t0[:, :, None])  # (E, 3, k) in the grasp frame
            # one (3 (b - a), 3) @ (3, k) product per episode, not b - a small ones (the same sums, a tenth the time)
            moved = (rotations(traj[:, a:b, arm]).reshape(E, -1, 3) @ rel).reshape(E, b - a, 3, -1) \
                + traj[:, a:b, arm, :3, None]  # (E, b - a, 3, k)
            out[:, a:b, :, sel] = moved
            out[:, b:, :, sel] = moved[:, -1:]
    return out


def rotations(pose8: np.ndarray) -> np.ndarray:
    """(..., 3, 3) of (..., >= 7) poses: lib/geometry's quat_to_matrix of the quaternions normalised by norm_last,
    the same numbers (_rotations_kernel)."""
    q = np.ascontiguousarray(pose8[..., 3:7], float).reshape(-1, 4)
    return _rotations_kernel(q).reshape(pose8.shape[:-1] + (3, 3))


@numba.njit(cache=True)
def _rotations_kernel(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of quaternions q (n, 4) (scalar last) as rotations() made them with numpy:
    divided by norm_last's norm, then by quat_normalize's (np.linalg.norm: the squares summed left to right),
    then quat_to_matrix's products. One loop: numpy's took two dozen passes and stacks."""
    n = q.shape[0]
    out = np.empty((n, 3, 3))
    for i in range(n):
        s = q[i, 0] * q[i, 0]
        s += q[i, 1] * q[i, 1]
        s += q[i, 2] * q[i, 2]
        s += q[i, 3] * q[i, 3]
        r = np.sqrt(s)
        x, y, z, w = q[i, 0] / r, q[i, 1] / r, q[i, 2] / r, q[i, 3] / r
        r = np.sqrt(((x * x + y * y) + z * z) + w * w)
        x, y, z, w = x / r, y / r, z / r, w / r
        xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
        out[i, 0, 0], out[i, 0, 1], out[i, 0, 2] = 1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)
        out[i, 1, 0], out[i, 1, 1], out[i, 1, 2] = 2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)
        out[i, 2, 0], out[i, 2, 1], out[i, 2, 2] = 2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)
    return out


def _proximity_sq(traj: np.ndarray, kpt: np.ndarray, ko: np.ndarray, held: np.ndarray, arm: int) -> np.ndarray:
    """(E, T) the square of segmentation.proximity's signal d of one arm over a group (kpt (E, T, 3, K)): per step
    the nearest keypoint of any object to the hand; while the hand holds an object, its keypoints where the run
    starts (the grasp frame) instead of its own, and its keypoints' nearest approach to each other object's."""
    h = np.asarray(held[:, arm], np.int64)
    first = (h >= 0) & np.concatenate([[True], h[1:] != h[:-1]])
    start = np.maximum.accumulate(np.where(first, np.arange(len(h)), 0))  # each step's held run's first step
    return _proximity_kernel(np.ascontiguousarray(traj[:, :, arm, :3]), np.ascontiguousarray(kpt),
                             np.asarray(ko, np.int64), h, start, int(np.max(ko)) + 1)


@numba.njit(cache=True)
def _proximity_kernel(g, kpt, ko, h, start, n_obj):
    """_proximity_sq's arithmetic (squares summed x, y, z in float64; minima, exact in any order) per episode and
    step: the hand g (E, T, 3), the keypoints kpt (E, T, 3, K), their objects ko (K,), the held object h (T,)
    (-1: none) and the first step of its run start (T,). One compiled loop: numpy's took a pass over memory per
    term and object."""
    E, T, K = kpt.shape[0], kpt.shape[1], kpt.shape[3]
    out = np.empty((E, T))
    per = np.empty(n_obj)
    for e in range(E):
        for t in range(T):
            for o in range(n_obj):
                per[o] = np.inf
            held, a = h[t], start[t]
            for k in range(K):
                o = ko[k]
                src = a if o == held else t  # the held object's keypoints in its grasp frame: where the run starts
                d = _sq_dist(kpt[e, src, 0, k] - g[e, t, 0], kpt[e, src, 1, k] - g[e, t, 1],
                             kpt[e, src, 2, k] - g[e, t, 2])
                if d < per[o]:
                    per[o] = d
            if held >= 0:
                for i in range(K):
                    if ko[i] != held:
                        continue
                    for j in range(K):
                        o2 = ko[j]
                        if o2 == held:
                            continue
                        d = _sq_dist(kpt[e, t, 0, i] - kpt[e, t, 0, j], kpt[e, t, 1, i] - kpt[e, t, 1, j],
                                     kpt[e, t, 2, i] - kpt[e, t, 2, j])
                        if d < per[o2]:
                            per[o2] = d
            best = per[0]
            for o in range(1, n_obj):
                if per[o] < best:
                    best = per[o]
            out[e, t] = best
    return out


@numba.njit(cache=True)
def _sq_dist(dx, dy, dz):
    """A squared distance from its differences, summed x, y, z (numpy's order of the planes it replaced)."""
    return dx * dx + dy * dy + dz * dz


def _hysteresis(d: np.ndarray, enter: float, exit: float) -> np.ndarray:
    """segmentation._hysteresis along axis 1 (of the squared signal, with squared thresholds)."""
    state = np.where(d < enter, 1, np.where(d > exit, 0, -1))
    idx = np.where(state >= 0, np.arange(d.shape[1]), -1)
    last = np.maximum.accumulate(idx, axis=1)
    return np.where(last >= 0, np.take_along_axis(state, np.maximum(last, 0), axis=1), 0).astype(bool)


def _remove_short(mask: np.ndarray, value: bool, min_len: int) -> np.ndarray:
    """segmentation._remove_short along axis 1: runs of `value` shorter than min_len turned over (a run of
    False only between two others; a run of True anywhere). The runs are the input's."""
    E, T = mask.shape
    idx = np.broadcast_to(np.arange(T), (E, T))
    change = np.concatenate([np.ones((E, 1), bool), mask[:, 1:] != mask[:, :-1]], axis=1)
    start = np.maximum.accumulate(np.where(change, idx, 0), axis=1)
    last = np.concatenate([mask[:, 1:] != mask[:, :-1], np.ones((E, 1), bool)], axis=1)
    end = np.minimum.accumulate(np.where(last, idx, T - 1)[:, ::-1], axis=1)[:, ::-1]
    short = (mask == value) & (end - start + 1 < min_len)
    if not value:
        short &= (start > 0) & (end < T - 1)
    return np.where(short, not value, mask)


def skill_masks(traj: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray, held: np.ndarray,
                params: SegmentationParams | None = None) -> np.ndarray:
    """(E, T, 2) segmentation.segment_trajectory's skill frames of each episode of a group (held (T, 2))."""
    p = params or SegmentationParams()
    ko = np.asarray(keypoint_object, int)
    kpt = keypoints_over_time(traj, keypoints0, ko, held)
    E, T = traj.shape[:2]
    out = np.zeros((E, T, 2), bool)
    for arm in range(2):
        mask = _hysteresis(_proximity_sq(traj, kpt, ko, held, arm), p.enter ** 2, p.exit ** 2)
        closed = traj[0, :, arm, 7] < p.closed_below
        for e in np.flatnonzero(np.diff(closed.astype(np.int8))) + 1:
            mask[:, max(0, e - p.grip_margin):min(T, e + p.grip_margin)] = True
        h = held[:, arm]
        if (h >= 0).any():
            g = traj[:, :, arm, :3]
            starts = np.flatnonzero((h >= 0) & np.concatenate([[True], h[:-1] != h[1:]]))
            grasp_of = np.maximum.accumulate(np.where(np.isin(np.arange(T), starts), np.arange(T), 0))
            mask |= (h >= 0) & (norm_last(g - g[:, grasp_of]) < p.carry_distance)
        mask = _remove_short(mask, False, p.min_motion)
        out[..., arm] = _remove_short(mask, True, p.min_skill)
    return out


def windows_batch(traj: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray, held: np.ndarray,
                  approach: float = APPROACH) -> np.ndarray:
    """(E, 2, 2) arm_motion.follow_windows of each episode of a group (held (T, 2): the group's), WINDOW_BATCH
    episodes at a time (their keypoints over time, (E, T, 3, K), stay in the cache)."""
    E, T = traj.shape[:2]
    if E > WINDOW_BATCH:
        return np.concatenate([windows_batch(traj[i:i + WINDOW_BATCH], keypoints0[i:i + WINDOW_BATCH], keypoint_object,
                                             held, approach) for i in range(0, E, WINDOW_BATCH)])
    skill = skill_masks(traj, keypoints0, keypoint_object, held)
    out = np.full((E, 2, 2), T, int)
    for arm in range(2):
        closed = np.flatnonzero(traj[0, :, arm, 7] < 0.5)
        has = skill[..., arm].any(axis=1)
        if not len(closed) and not has.any():
            continue
        first = np.where(has, np.argmax(skill[..., arm], axis=1), T)
        last_end = np.where(has, T - np.argmax(skill[:, ::-1, arm], axis=1), -1)
        start = np.minimum(first, closed[0] if len(closed) else T)
        end = np.minimum(np.maximum(last_end, start + 1), T)
        if len(closed):
            end = np.where(closed[-1] >= end, T, end)
        steps = norm_last(np.diff(traj[:, :, arm, :3], axis=1))
        path = np.concatenate([np.zeros((E, 1)), np.cumsum(steps, axis=1)], axis=1)
        at = np.arange(E)
        w0 = np.sum(path < (path[at, start] - approach)[:, None], axis=1)
        w1 = np.sum(path <= (path[at, end - 1] + approach)[:, None], axis=1)
        none = ~has & (len(closed) == 0)
        out[:, arm, 0] = np.where(none, T, w0)
        out[:, arm, 1] = np.where(none, T, np.minimum(w1, T))
    return out


def object_poses_batch(task, keypoints0: np.ndarray) -> np.ndarray:
    """(E, n_obj, 4, 4) retargeting.object_poses_at_start of each episode's keypoints (E, K, 3)."""
    kp = np.asarray(keypoints0, float)
    owner = task.keypoint_object
    out = np.tile(np.eye(4), (len(kp), len(task.objects), 1, 1))
    for k in range(len(task.objects)):
        _, R, t = umeyama(task.keypoints_local[owner == k], kp[:, owner == k], with_scale=False)
        out[:, k, :3, :3], out[:, k, :3, 3] = R, t
    return out


def object_at_steps(traj: np.ndarray, held: np.ndarray, obj0: np.ndarray, o: int, steps: np.ndarray) -> np.ndarray:
    """(E, S, 4, 4) object o's pose at each episode's steps (E, S) as retarget.object_trajectories moves it:
    at obj0 (E, n_obj, 4, 4) until a hand closes on it, then carried rigidly with that hand (pinch poses
    of the smoothed traj (E, T, 2, 8)), then where released. held (T, 2): the group's."""
    E, T = traj.shape[:2]
    closed = traj[0, :, :, 7] < 0.5
    events = sorted((a, b, arm) for arm in range(2) for a, b in runs(closed[:, arm] & (held[:, arm] >= 0)))
    events = [(a, b, arm) for a, b, arm in events if held[a, arm] == o]
    out = np.broadcast_to(obj0[:, o, None], (E, steps.shape[1], 4, 4)).copy()
    inv_grasps = []
    for k, (a, b, arm) in enumerate(events):  # the object's pose at a: where the earlier events left it
        pose_a = obj0[:, o] if k == 0 else _pose_after(traj, events[:k], inv_grasps, np.full(E, a))
        inv_grasps.append(transform_inverse(transform_inverse(pose_a) @ pose7_to_transform(traj[:, a, arm, :7])))
    if events:
        out = np.where(steps[..., None, None] >= events[0][0],
                       _pose_after(traj, events, inv_grasps, steps), out)
    return out


def _pose_after(traj: np.ndarray, events: list, inv_grasps: list, steps: np.ndarray) -> np.ndarray:
    """(*steps.shape, 4, 4) the object's pose at steps (E,) or (E, S) not before the first event: carried
    by the last event starting at or before the step, or where that event released it."""
    starts = np.array([a for a, _, _ in events])
    k = np.searchsorted(starts, steps, side="right") - 1  # the governing event
    k = np.maximum(k, 0)
    ends = np.array([b for _, b, _ in events])[k]
    arms = np.array([arm for _, _, arm in events])[k]
    t = np.minimum(steps, ends - 1)  # after the release: where it was at the last held step
    e = np.arange(len(traj)).reshape((-1,) + (1,) * (steps.ndim - 1))
    hand = pose7_to_transform(traj[e, t, arms, :7])
    G = np.stack(inv_grasps, axis=1)  # (E, n_events, 4, 4)
    return hand @ G[e, k]


__all__ = ["norm_last", "held_batch", "held_scores", "keypoints_over_time", "object_at_steps",
           "object_poses_batch", "rotations", "runs", "skill_masks", "smooth_batch", "windows_batch"]
