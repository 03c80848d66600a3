"""Motion / skill segmentation of a dual-arm gripper trajectory (thesis 3.2, DemoGen).

Per arm and frame, a proximity signal d(t) (metres):
    d(t) = min( min over objects o not held by this arm of  dist(gripper, keypoints of o at t),
                dist(gripper, keypoints of the held object at its grasp frame),   # still near where it was
                min dist(held object's keypoints at t, other objects' keypoints at t) )   # brings it to them
A frame is "skill" when d < enter (hysteresis: stays skill until d > exit), or within `grip_margin`
frames of a gripper open/close event, or while the arm holds an object that has not moved further
than `carry_distance` from where it was grasped (a hand holding the receiving object in place).
Then skill runs shorter than `min_skill` frames and motion gaps shorter than `min_motion` frames are
removed.  "Held": the gripper is closed (g < 0.5) and the object is the one nearest at the closing frame,
by the distance to its keypoints' convex hull plus a tenth of the distance to its nearest keypoint (the
hull: a stem pinched between its keypoints lies farther from all of them than from the rim of the vase
it stands in; the keypoint: a pinch around a vase lies inside the hulls of the vase and its flowers).
Keypoints may be given per frame (T, K, 3) or at frame 0 only (K, 3): then a held object's keypoints are carried rigidly with the gripper from its grasp frame on and stay
where released (static scene otherwise).  Each segment's object: for skill, the object it is nearest
to / acting on (the other object when the held one is brought to it); for motion, the object of the
next skill (-1 after the last), as the task library labels them.

Manual boundaries (frame indices per arm, as in DemoGen) override the automatic ones: segments
alternate between them starting with "motion" unless first_kind says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from demoforge.lib import geometry as geo
from demoforge.lib.errors import UserError


@dataclass
class Segment:
    """A motion or skill segment of one arm's trajectory (the one definition the project uses)."""

    arm: int
    kind: str  # "motion" | "skill"
    start: int
    end: int  # exclusive
    object: int  # object the arm handles (skill) or moves towards / carries (motion); -1 = none


@dataclass
class SegmentationParams:
    enter: float = 0.06  # m: skill when the proximity signal drops below
    exit: float = 0.08  # m: ... and motion again when it rises above (hysteresis)
    grip_margin: int = 6  # frames around a gripper event that are always skill
    carry_distance: float = 0.05  # m: holding an object within this of its grasp place = skill
    min_skill: int = 8  # frames
    min_motion: int = 8  # frames
    closed_below: float = 0.5  # g < this = closed


def _runs(mask: np.ndarray) -> list[tuple[int, int, bool]]:
    """Maximal runs (start, end exclusive, value) of a 1-D bool array."""
    if len(mask) == 0:
        return []
    ch = np.flatnonzero(np.diff(mask.astype(np.int8))) + 1
    starts = np.concatenate([[0], ch])
    ends = np.concatenate([ch, [len(mask)]])
    return [(int(a), int(b), bool(mask[a])) for a, b in zip(starts, ends)]


def _hysteresis(d: np.ndarray, enter: float, exit: float) -> np.ndarray:
    """Vectorised Schmitt trigger: on below enter, off above exit, else keep the last state (start off)."""
    state = np.where(d < enter, 1, np.where(d > exit, 0, -1))
    idx = np.where(state >= 0, np.arange(len(d)), -1)
    last = np.maximum.accumulate(idx)
    return np.where(last >= 0, state[np.maximum(last, 0)], 0).astype(bool)


def _remove_short(mask: np.ndarray, value: bool, min_len: int) -> np.ndarray:
    out = mask.copy()
    runs = _runs(out)
    for i, (a, b, v) in enumerate(runs):
        if v == value and b - a < min_len and 0 < i < len(runs) - 1:
            out[a:b] = not value
        elif v == value and b - a < min_len and value:  # short skill at an end
            out[a:b] = False
    return out


def hull_distance(points: np.ndarray, p: np.ndarray) -> float:
    """Distance (m) from p (3,) to the convex hull of points (K, 3), flat or degenerate hulls included: the
    nearest convex combination, as a non-negative least-squares problem whose last row weighs sum = 1."""
    P = np.asarray(points, float).T  # (3, K)
    w, _ = nnls(np.vstack([P, np.full(P.shape[1], HULL_WEIGHT)]), np.append(np.asarray(p, float), HULL_WEIGHT))
    return float(np.linalg.norm(P @ w - p))


HULL_WEIGHT = 100.0  # the sum-to-one row's weight: 1e-4 m of slack costs as much as 1 cm off the hull
NEAREST_KEYPOINT_WEIGHT = 0.1  # of the nearest keypoint's distance in the held object's score (see the docstring)


def grasped_object_scores(keypoints: np.ndarray, keypoint_object: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(n_obj,) how far (m) the pinch point p (3,) is from each object (keypoints (K, 3)): the lowest is held."""
    out = []
    for o in range(int(keypoint_object.max()) + 1):
        K = keypoints[keypoint_object == o]
        out.append(hull_distance(K, p) + NEAREST_KEYPOINT_WEIGHT * np.linalg.norm(K - p, axis=-1).min())
    return np.array(out)


def held_objects(trajectory: np.ndarray, keypoints: np.ndarray, keypoint_object: np.ndarray,
                 closed_below: float = 0.5) -> np.ndarray:
    """(T, 2) index of the object each arm holds (-1 = none)."""
    T = trajectory.shape[0]
    kp = keypoints if keypoints.ndim == 3 else keypoints[None]
    held = np.full((T, 2), -1)
    for arm in range(2):
        closed = trajectory[:, arm, 7] < closed_below
        for a, b, v in _runs(closed):
            if not v:
                continue
            K = kp[min(a, len(kp) - 1)]
            held[a:b, arm] = int(np.argmin(grasped_object_scores(K, keypoint_object, trajectory[a, arm, :3])))
    return held


def object_keypoints_over_time(trajectory: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray,
                               held: np.ndarray) -> np.ndarray:
    """(T, K, 3) keypoints from frame-0 keypoints: a held object moves rigidly with its gripper."""
    T = trajectory.shape[0]
    out = np.broadcast_to(keypoints0, (T,) + keypoints0.shape).copy()
    P = geo.pose7_to_transform(trajectory[..., :7])  # (T, 2, 4, 4)
    for arm in range(2):
        for a, b, v in _runs(held[:, arm] >= 0):
            if not v:
                continue
            o = held[a, arm]
            sel = keypoint_object == o
            rel = geo.transform_points(geo.transform_inverse(P[a, arm]), out[a, sel])  # in the grasp frame
            moved = np.einsum("tij,kj->tki", P[a:b, arm, :3, :3], rel) + P[a:b, arm, None, :3, 3]  # (b - a, k, 3)
            out[a:b, sel] = moved
            out[b:, sel] = moved[-1]
    return out


def proximity(trajectory: np.ndarray, keypoints: np.ndarray, keypoint_object: np.ndarray,
              held: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 2) proximity signal d and (T, 2) the object it refers to (see the module docstring)."""
    T = trajectory.shape[0]
    n_obj = int(keypoint_object.max()) + 1
    onehot = keypoint_object[None, :] == np.arange(n_obj)[:, None]  # (n_obj, K)
    d = np.full((T, 2), np.inf)
    which = np.full((T, 2), -1)
    for arm in range(2):
        g = trajectory[:, arm, :3]
        dk = np.linalg.norm(keypoints - g[:, None, :], axis=-1)  # (T, K)
        per_obj = np.where(onehot[None], dk[:, None, :], np.inf).min(-1)  # (T, n_obj)
        h = held[:, arm]
        for o in range(n_obj):
            is_h = h == o
            if not is_h.any():
                continue
            per_obj[is_h, o] = np.inf
            # grasp-place distance: gripper to the held object's keypoints at its grasp frame
            starts = np.flatnonzero(is_h & np.concatenate([[True], ~is_h[:-1]]))
            grasp_of = np.maximum.accumulate(np.where(np.isin(np.arange(T), starts), np.arange(T), 0))
            Kg = keypoints[grasp_of][:, onehot[o]]
            dg = np.linalg.norm(Kg - g[:, None], axis=-1).min(-1)
            per_obj[is_h, o] = dg[is_h]
            # held object brought to another object
            Ko = keypoints[:, onehot[o]]
            for o2 in range(n_obj):
                if o2 == o:
                    continue
                K2 = keypoints[:, onehot[o2]]
                dd = np.linalg.norm(Ko[:, :, None] - K2[:, None], axis=-1).min((1, 2))
                per_obj[is_h, o2] = np.minimum(per_obj[is_h, o2], dd[is_h])
        d[:, arm] = per_obj.min(1)
        which[:, arm] = per_obj.argmin(1)
    return d, which


def segment_trajectory(trajectory: np.ndarray, keypoints: np.ndarray, keypoint_object: np.ndarray,
                       params: SegmentationParams | None = None,
                       manual: dict[int, list[int]] | None = None,
                       first_kind: dict[int, str] | None = None) -> list[Segment]:
    """Motion/skill segments of both arms of a (T, 2, 8) trajectory.  keypoints (T, K, 3) or (K, 3).
    manual: {arm: [boundary frames]} overrides the automatic segmentation of that arm."""
    p = params or SegmentationParams()
    traj = np.asarray(trajectory, float)
    T = traj.shape[0]
    ko = np.asarray(keypoint_object, int)
    kp = np.asarray(keypoints, float)
    held = held_objects(traj, kp, ko, p.closed_below)
    kpt = object_keypoints_over_time(traj, kp, ko, held) if kp.ndim == 2 else kp
    d, which = proximity(traj, kpt, ko, held)
    segs: list[Segment] = []
    for arm in range(2):
        if manual is not None and arm in manual:
            b = sorted({int(x) for x in manual[arm] if 0 < int(x) < T})
            edges = [0] + b + [T]
            kind0 = (first_kind or {}).get(arm, "motion")
            kinds = [kind0 if i % 2 == 0 else ("skill" if kind0 == "motion" else "motion") for i in range(len(edges) - 1)]
            mask = np.zeros(T, bool)
            for (a, e), k in zip(zip(edges[:-1], edges[1:]), kinds):
                mask[a:e] = k == "skill"
        else:
            mask = _hysteresis(d[:, arm], p.enter, p.exit)
            closed = traj[:, arm, 7] < p.closed_below
            ev = np.flatnonzero(np.diff(closed.astype(np.int8))) + 1
            for e in ev:
                mask[max(0, e - p.grip_margin):min(T, e + p.grip_margin)] = True
            # holding an object still near its grasp place (the receiving hand)
            h = held[:, arm]
            if (h >= 0).any():
                g = traj[:, arm, :3]
                starts = np.flatnonzero((h >= 0) & np.concatenate([[True], h[:-1] != h[1:]]))
                grasp_of = np.maximum.accumulate(np.where(np.isin(np.arange(T), starts), np.arange(T), 0))
                moved = np.linalg.norm(g - g[grasp_of], axis=-1)
                mask |= (h >= 0) & (moved < p.carry_distance)
            mask = _remove_short(mask, False, p.min_motion)
            mask = _remove_short(mask, True, p.min_skill)
        runs = _runs(mask)
        arm_segs = []
        for a, e, v in runs:
            if v:
                obj = np.bincount(which[a:e, arm][which[a:e, arm] >= 0], minlength=1).argmax()
                arm_segs.append(Segment(arm, "skill", a, e, int(obj)))
            else:
                arm_segs.append(Segment(arm, "motion", a, e, -1))
        for i, s in enumerate(arm_segs):  # a motion segment heads for the object of the next skill
            if s.kind == "motion" and i + 1 < len(arm_segs):
                s.object = arm_segs[i + 1].object
        segs += arm_segs
    return segs


def fill_invalid_poses(trajectory: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(T, 2, 8) poses with the invalid frames of each arm replaced by the nearest valid frame's
    pose (held before the first and after the last valid frame). Raises if an arm has none."""
    traj = np.array(trajectory, float)
    ok = np.asarray(valid, bool) & np.isfinite(traj).all(-1)
    T = traj.shape[0]
    for arm in range(2):
        good = np.flatnonzero(ok[:, arm])
        if good.size == 0:
            side = ("left", "right")[arm]
            raise UserError(f"the {side} arm's gripper pose is never valid: the {side} hand was not "
                            "detected in any frame; a two-handed demonstration needs both hands in view "
                            "(see `present` in the hand_keypoints table)")
        # index of the nearest valid frame: nearest by position in the sorted list of valid frames
        pos = np.clip(np.searchsorted(good, np.arange(T)), 1, max(good.size - 1, 1))
        left, right = good[pos - 1], good[np.minimum(pos, good.size - 1)]
        nearest = np.where(np.abs(np.arange(T) - left) <= np.abs(right - np.arange(T)), left, right)
        traj[:, arm] = traj[nearest, arm]
    return traj


def infer_object_arm(trajectory: np.ndarray, keypoints: np.ndarray, keypoint_object: np.ndarray) -> np.ndarray:
    """(n_objects,) the arm that holds each object for the most frames (by :func:`held_objects`);
    an object never held goes to the arm that holds nothing else (or arm 0)."""
    ko = np.asarray(keypoint_object, int)
    n_obj = int(ko.max()) + 1
    held = held_objects(np.asarray(trajectory, float), np.asarray(keypoints, float), ko)
    counts = np.array([[np.count_nonzero(held[:, arm] == o) for arm in range(2)] for o in range(n_obj)])
    arm = np.argmax(counts, axis=1)
    for o in range(n_obj):
        if counts[o].max() == 0:
            used = set(arm[[i for i in range(n_obj) if i != o and counts[i].max() > 0]])
            arm[o] = next((a for a in (0, 1) if a not in used), 0)
    return arm


def boundaries(segments, arm: int) -> np.ndarray:
    """Interior boundary frames (segment starts > 0) of one arm."""
    return np.array(sorted(s.start for s in segments if s.arm == arm and s.start > 0), int)


def boundary_error(pred, ref, max_match: int = 30) -> dict:
    """Frame error of matched boundaries, per arm: each reference boundary is matched to the nearest
    predicted boundary of the same arm (one-to-one, greedy by distance, within max_match frames).
    Returns {"errors": array of |frame differences|, "mean", "max", "missed" (unmatched reference),
    "extra" (unmatched predicted)}."""
    errs, missed, extra = [], 0, 0
    for arm in range(2):
        bp, br = boundaries(pred, arm), boundaries(ref, arm)
        if len(br) and len(bp):
            D = np.abs(br[:, None] - bp[None, :])
            pairs = sorted((D[i, j], i, j) for i in range(len(br)) for j in range(len(bp)))
            ui, uj = set(), set()
            for dd, i, j in pairs:
                if dd <= max_match and i not in ui and j not in uj:
                    ui.add(i), uj.add(j), errs.append(int(dd))
            missed += len(br) - len(ui)
            extra += len(bp) - len(uj)
        else:
            missed += len(br)
            extra += len(bp)
    e = np.array(errs, float)
    return {"errors": e, "mean": float(e.mean()) if len(e) else float("nan"),
            "max": float(e.max()) if len(e) else float("nan"), "missed": missed, "extra": extra}


__all__ = ["Segment", "SegmentationParams", "segment_trajectory", "held_objects", "object_keypoints_over_time",
           "proximity", "boundaries", "boundary_error"]
