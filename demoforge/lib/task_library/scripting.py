"""How the scripted takes of the six tasks move: rest poses, per-take timing style, grasp and release
sequences, pinch points, and the objects' named keypoints. The tasks themselves (scenes, placements,
scripts, success predicates) are in tasks.py."""

from __future__ import annotations

import math

import numpy as np

from demoforge.lib.trajectories.keyframes import KeyframeSettings

from .base import UP, Track, inv_pose, side_pinch, translated, unit

HOME = (np.array([-0.27, -0.14, 0.20]), np.array([0.27, -0.14, 0.20]))
SHOULDER = (np.array([-0.2, -0.32]), np.array([0.2, -0.32]))
AP_REST = 0.06


# the tasks whose skills are grasps and carries, not paths (stirring, prying a lid) keep their
# database's successes with coarser keyframes than the default: 30 mm, 0.3 rad after a 3-step
# smoothing (scripts/measure_keyframes.py; docs/results/issue-21-keyframes.md)
CARRY_KEYFRAMES = KeyframeSettings(0.03, 0.3, 3.0)


class Style:
    """Per-take timing and path style."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.speed = rng.uniform(0.85, 1.1)

    def d(self, seconds: float) -> float:
        return float(seconds * self.speed * self.rng.uniform(0.9, 1.1))

    def u(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))

    def jitter(self, scale: float) -> np.ndarray:
        return self.rng.uniform(-scale, scale, 3)


def home_pose(arm: int, st: Style) -> np.ndarray:
    return side_pinch(HOME[arm] + st.jitter(0.02), [0.0, 1.0], arm, pitch=0.5)


def approach_dir(arm: int, target, st: Style) -> np.ndarray:
    d = unit(np.asarray(target[:2]) - SHOULDER[arm])
    a = math.atan2(d[1], d[0]) + st.u(-0.12, 0.12)
    return np.array([math.cos(a), math.sin(a)])


def open_width(width: float) -> float:
    return min(width + 0.04, 0.13)


def grasp_sequence(tr: Track, grasp: np.ndarray, obj: int, width: float, st: Style,
                   back: float = 0.07, up: float = 0.03, jitter: float = 0.01) -> None:
    """reach (motion) -> approach, close (skill); the hand holds `obj` afterwards."""
    pre = translated(grasp, -grasp[:3, 2] * back + UP * up + st.jitter(jitter))
    tr.move(st.d(1.0), pre, open_width(width), "motion", obj)
    tr.move(st.d(0.6), grasp, open_width(width), "skill", obj)
    tr.move(st.d(0.3), grasp, width, "skill", obj)
    tr.grip(obj)


def release_sequence(tr: Track, obj: int, width: float, st: Style, arm: int, retreat=None) -> None:
    """open, back off (skill) -> home (motion)."""
    tr.release()
    tr.move(st.d(0.3), None, open_width(width), "skill", obj)
    if retreat is None:
        retreat = -tr.pose[:3, 2] * 0.06 + UP * 0.04
    tr.move(st.d(0.5), translated(tr.pose, retreat), None, "skill", obj)
    tr.move(st.d(1.0), home_pose(arm, st), AP_REST, "motion", -1)


def holder_script(tr: Track, grasp: np.ndarray, obj: int, width: float, st: Style, lift: float, **approach):
    """The receiving object's hand: grasp, lift slightly; returns a function finishing the track.
    `approach`: keyword arguments of grasp_sequence (back, up, jitter)."""
    grasp_sequence(tr, grasp, obj, width, st, **approach)
    tr.move(st.d(0.5), translated(grasp, [0, 0, lift]), None, "skill", obj)

    def finish(t_done: float):
        tr.until(t_done, "skill", obj)
        tr.move(st.d(0.5), translated(grasp, [0, 0, 0.002]), None, "skill", obj)
        release_sequence(tr, obj, width, st, arm=1)

    return finish


def pinch_for(obj_pose: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """Pinch pose that puts a held object (relative pose rel = P^-1 T) at obj_pose."""
    return obj_pose @ inv_pose(rel)


def _kp(*items):
    return tuple((n, tuple(float(v) for v in p)) for n, p in items)


def _rim4(prefix, r, z, ry=None):
    ry = r if ry is None else ry
    return [(f"{prefix}_rim_front", (0, -ry, z)), (f"{prefix}_rim_back", (0, ry, z)),
            (f"{prefix}_rim_left", (-r, 0, z)), (f"{prefix}_rim_right", (r, 0, z))]


# Keypoints (object frame) of the resizable objects as functions of their dimensions, so that a resized
# object (Task.variant) carries keypoints that follow its geometry; the defaults use the module constants.
def _bottle_kp(b):
    return _kp(("bottle_base", (0, 0, 0)), ("bottle_left", (-b["R"], 0, b["side_z"])),
               ("bottle_right", (b["R"], 0, b["side_z"])), ("bottle_shoulder", (0, 0, b["body_h"])),
               ("bottle_mouth", (0, 0, b["h"])))


def _cup_kp(c):
    return _kp(("cup_base", (0, 0, 0)), ("cup_center", (0, 0, c["h"] / 2)), *_rim4("cup", c["R"], c["h"]))


def _can_kp(c):
    return _kp(("can_bottom", (0, 0, 0)), ("can_center", (0, 0, c["h"] / 2)), ("can_top", (0, 0, c["h"])),
               ("can_left", (-c["R"], 0, c["h"] / 2)), ("can_right", (c["R"], 0, c["h"] / 2)))


def _bin_kp(b):
    return _kp(("bin_base", (0, 0, 0)), ("bin_center", (0, 0, b["h"] / 2)), *_rim4("bin", b["half"], b["h"]))


def _whisk_kp(w):
    return _kp(("whisk_end", (0, 0, 0)), ("whisk_handle", (0, 0, w["grasp_z"])),
               ("whisk_neck", (0, 0, w["handle_len"])),
               ("whisk_head", (0, 0, w["head_z"])), ("whisk_tip", (0, 0, w["head_z"] + w["head_r"])))


def _bowl_kp(b):
    return _kp(("bowl_base", (0, 0, 0)), ("bowl_center", (0, 0, b["center_z"])), *_rim4("bowl", b["r_top"], b["h"]))


def _tilt_deg(T: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip(T[2, 2], -1, 1)))
