"""Object-centric retargeting: what an arm keeps of a demonstrated window is the held object's motion,
not the human wrist's angle.

    objs = object_trajectories(hand, closed, held, obj0)        # (T, n_obj, 4, 4) the objects as demonstrated
    turned = turn_grasp(hand[:, arm], objs[:, o], theta, flip)   # the same object motion, grasped turned by theta
    lifted = lift_above_table(hand, half_width, spec, clearance=0.005)

Inside a window the held object moves rigidly with the hand: with the object's pose O(t) (static before
the grasp and after the release, carried by the hand while it is closed on it), the grasp is
G = O(t)^-1 P(t), constant while held. An object that a turn R_z(theta) about its own symmetry axis
maps onto itself (TaskObject.symmetry) can be grasped as G' = R_z(theta) G just as well: the hand's
pose becomes P'(t) = O(t) R_z(theta) O(t)^-1 P(t) at every step of the window, and the object moves
exactly as demonstrated. Before the grasp and after the release the same formula turns the approach
and the retreat about the object's axis at its place, so the hand comes in from the new side. A
parallel gripper also grasps the same way turned half a turn about its own approach axis (`flip`).
Which turn an arm uses is the robot's choice (e.g. aloha/grasp_choice.py: joint margins over the
whole window); a turn of 0 without a flip is the demonstration itself.
"""

from __future__ import annotations

import numpy as np

from demoforge.lib.geometry import transform_inverse

#: degrees between the turns tried for an object that any turn maps onto itself
TURN_STEP_DEG = 15.0
#: the gripper frame turned half a turn about its approach axis (z): x and y reversed
HALF_TURN = np.diag([-1.0, -1.0, 1.0, 1.0])


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of the True runs of a (T,) bool array."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def object_trajectories(hand: np.ndarray, closed: np.ndarray, held: np.ndarray, obj0: np.ndarray) -> np.ndarray:
    """(T, n_obj, 4, 4) every object's pose over an episode: at obj0 (n_obj, 4, 4) until a hand closes on it
    (held (T, 2): the object each hand holds, -1 none; closed (T, 2)), then carried rigidly with that hand
    (hand (T, 2, 4, 4) pinch poses) until it opens, then where it was released."""
    T = len(hand)
    out = np.repeat(np.asarray(obj0, float)[None], T, axis=0)
    events = sorted((a, b, arm) for arm in range(2) for a, b in _runs(closed[:, arm] & (held[:, arm] >= 0)))
    for a, b, arm in events:
        o = int(held[a, arm])
        grasp = transform_inverse(out[a, o]) @ hand[a, arm]  # the hand in the object's frame at the grasp
        out[a:b, o] = hand[a:b, arm] @ transform_inverse(grasp)
        out[b:, o] = out[b - 1, o]
    return out


def rot_z(theta: np.ndarray) -> np.ndarray:
    """(..., 4, 4) turns by theta (...) rad about z."""
    theta = np.asarray(theta, float)
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(theta.shape + (4, 4))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1] = c, -s, s, c
    R[..., 2, 2] = R[..., 3, 3] = 1.0
    return R


def turn_grasp(hand: np.ndarray, obj: np.ndarray | None, theta, flip: bool = False) -> np.ndarray:
    """(T, 4, 4) one hand's poses (T, 4, 4) with its grasp of the object whose poses are obj (T, 4, 4)
    turned by theta rad (a number, or (T,) per step) about the object's z axis (see the module docstring),
    and half a turn about the gripper's approach axis if flip. obj None (the hand holds nothing): only the flip."""
    out = np.asarray(hand, float)
    if obj is not None and np.any(theta):
        out = obj @ rot_z(theta) @ transform_inverse(obj) @ out
    return out @ HALF_TURN if flip else out


def grasp_turns(symmetry: int, step_deg: float = TURN_STEP_DEG) -> np.ndarray:
    """The turns (rad) about an object's axis that map it onto itself, the demonstrated grasp (0) first and
    then by size: any turn in `step_deg` steps (symmetry 0) or the n turns of 360 / n degrees."""
    n = int(round(360.0 / step_deg)) if symmetry == 0 else max(int(symmetry), 1)
    turns = 2.0 * np.pi * np.arange(n) / n
    turns = np.where(turns > np.pi + 1e-9, turns - 2.0 * np.pi, turns)
    return turns[np.argsort(np.abs(turns), kind="stable")]


def finger_half_width(g: np.ndarray, held_width: np.ndarray, opening: float) -> np.ndarray:
    """(T,) how far each finger's pad stands from the pinch axis: half the opening while open, half the held
    object's width while closed on it."""
    return np.where(np.asarray(g) < 0.5, 0.5 * np.asarray(held_width, float), 0.5 * opening)


def lowest_finger_z(hand: np.ndarray, half_width: np.ndarray, spec) -> np.ndarray:
    """(T,) the lowest point of the two fingertips (pads and finger links, spec a GripperSpec) for pinch poses
    hand (T, 4, 4) opened half_width (T,) each side."""
    xo = half_width[:, None] + 2.0 * spec.pad_half[0] + spec.finger_thick  # the finger's outer face
    xs = np.stack([-xo[:, 0], -half_width, half_width, xo[:, 0]], axis=1)  # (T, 4)
    ys = np.array([-spec.pad_half[1], spec.pad_half[1]])
    R = hand[:, :3, :3]
    z = (hand[:, 2, 3][:, None, None] + R[:, 2, 0][:, None, None] * xs[:, :, None]
         + R[:, 2, 1][:, None, None] * ys[None, None, :] + R[:, 2, 2][:, None, None] * spec.tip_offset)
    return z.reshape(len(hand), -1).min(axis=1)


def lift_above_table(hand: np.ndarray, half_width: np.ndarray, spec, clearance: float, table_z: float = 0.0,
                     ramp: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """(hand poses (T, 4, 4) raised where a fingertip would come closer to the table top than `clearance`
    metres, lift (T,) m): the lift is held over `ramp` steps either side and eased in and out, so the
    target does not jump."""
    low = lowest_finger_z(hand, half_width, spec)
    need = np.maximum(table_z + clearance - low, 0.0)
    if not need.any():
        return hand, need
    T = len(need)
    padded = np.concatenate([np.zeros(ramp), need, np.zeros(ramp)])
    held = np.lib.stride_tricks.sliding_window_view(padded, 2 * ramp + 1).max(axis=1)  # (T,)
    w = np.hanning(2 * ramp + 3)[1:-1]
    eased = np.convolve(np.concatenate([np.zeros(ramp), held, np.zeros(ramp)]), w / w.sum(), mode="valid")[:T]
    lift = np.maximum(eased, need)
    out = hand.copy()
    out[:, 2, 3] += lift
    return out, lift


__all__ = ["HALF_TURN", "TURN_STEP_DEG", "finger_half_width", "grasp_turns", "lift_above_table", "lowest_finger_z",
           "object_trajectories", "rot_z", "turn_grasp"]
