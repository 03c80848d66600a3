"""A kinematic human hand (pure numpy, vectorised over frames) for synthetic demonstrations.

Two hands, left and right, mirror images of each other, with adult proportions (palm about 9.5 cm
from the wrist to the middle-finger MCP, fingers 7-9.5 cm, thumb 10 cm from its CMC joint), the 21
joints in MediaPipe order (0 wrist; 1-4 thumb CMC/MCP/IP/tip; 5-8 index; 9-12 middle; 13-16 ring;
17-20 pinky) and a capsule body model (:func:`hand_capsules`) for rendering.

Hand-local frame (the frame ``wrist_T`` maps to the world): origin at the wrist (joint 0),
x = forward (wrist towards the middle-finger MCP), z = dorsal (out of the back of the hand),
y = z cross x. For the right hand y points to the thumb side, for the left hand to the little-finger
side: the left hand's local joints are the right hand's with local y negated, so a left hand is the
mirror image of a right hand and both local frames are right-handed.

Posing:

* :func:`hand_joints` -- forward kinematics from a wrist pose and per-finger flexion in [0, 1]
  (thumb, index, middle, ring, pinky).
* :func:`hand_from_pinch` -- the inverse used by the synthetic generator: given the pinch (gripper)
  frame of docs/architecture.md and the thumb-index aperture, a natural hand whose thumb tip (4) and index
  tip (8) lie exactly at ``origin -/+ aperture/2 * x``, whose base midpoint ((0 + 1) / 2) lies on the
  pinch's -z axis, and whose other fingers curl as the aperture shrinks. The thesis's mapping
  (:func:`pinch_from_joints`) applied to the result gives back the requested frame.

How :func:`hand_from_pinch` is solved (closed form plus a fixed-iteration, vectorised bisection):
the thesis's z axis (base midpoint B -> fingertip midpoint) is perpendicular to the thumb->index
line exactly when both tips are equidistant from B. The index finger is posed by forward kinematics
with a flexion that decreases with the aperture; the thumb tip is then the point at distance
``aperture`` from the index tip on the sphere about B through the index tip (a circle), the one
closest to a natural thumb pose; the thumb reaches it with an analytic planar 3-link IK in its
(abducted) flexion plane, its IP joint coupled to its MCP joint. This gives the hand in its local
frame together with the local pinch frame P_loc; the wrist pose is ``pinch_T @ inv(P_loc)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demoforge.lib.joints import FINGER_JOINTS, FINGER_NAMES, HAND_CONNECTIONS, N_JOINTS

#: Skeleton edges (parent, child): MediaPipe's HAND_CONNECTIONS.
HAND_BONES: list[tuple[int, int]] = list(HAND_CONNECTIONS)

# --- geometry of the right hand at scale 1, hand-local frame (m) ---------------------------------
_THUMB_CMC = np.array([0.033, 0.022, -0.014])
_MCP = np.array([
    [0.090, 0.026, 0.000],   # index
    [0.095, 0.006, 0.000],   # middle
    [0.088, -0.013, -0.002],  # ring
    [0.077, -0.030, -0.005],  # pinky
])
#: Phalanx lengths (proximal, middle, distal-to-tip) per finger; thumb: metacarpal, proximal, distal.
_LENGTHS = np.array([
    [0.044, 0.032, 0.028],  # thumb (CMC->MCP, MCP->IP, IP->tip)
    [0.040, 0.024, 0.021],  # index
    [0.045, 0.028, 0.022],  # middle
    [0.042, 0.027, 0.022],  # ring
    [0.033, 0.020, 0.020],  # pinky
])
#: Neutral spread (rotation about the palm normal towards the thumb side), radians, per long finger.
_SPREAD = np.radians([6.0, 0.0, -6.0, -13.0])
#: Flexion angle at flexion 1 for (MCP, PIP, DIP) of the long fingers, radians.
_FINGER_FLEX = np.radians([80.0, 100.0, 65.0])
#: Thumb: rest direction of the metacarpal and the direction it flexes towards (hand-local, right).
_THUMB_DIR = np.array([0.55, 0.62, -0.55])
_THUMB_FLEXDIR = np.array([0.25, -0.70, -0.65])
_THUMB_REST = np.radians([10.0, 5.0, 5.0])
_THUMB_FLEX = np.radians([25.0, 40.0, 55.0])
#: Thumb IK coupling: IP angle = k * MCP angle.
_THUMB_K = 1.2
_THUMB_MAX = np.radians(75.0)

#: Capsule radii (m, at scale 1): per bone of :data:`HAND_BONES`-like list in :func:`hand_capsules`.
_R_PROX, _R_MID, _R_DIST, _R_THUMB_META = 0.0095, 0.0082, 0.0068, 0.0115
_R_PALM = 0.0115

_SKIN_TONES = np.array([
    [0.96, 0.80, 0.69], [0.91, 0.72, 0.60], [0.84, 0.63, 0.50],
    [0.76, 0.55, 0.42], [0.63, 0.44, 0.32], [0.48, 0.33, 0.24],
])
#: Sleeve colours (cloth): navy, grey, black, white, dark green, denim, maroon, beige.
_SLEEVE_COLOURS = np.array([
    [0.12, 0.16, 0.30], [0.45, 0.45, 0.47], [0.08, 0.08, 0.09], [0.88, 0.88, 0.86],
    [0.16, 0.30, 0.20], [0.27, 0.38, 0.55], [0.42, 0.12, 0.15], [0.76, 0.70, 0.58],
])


@dataclass(frozen=True)
class HandStyle:
    """Per-demonstrator hand parameters.

    scale: uniform size factor (1.0 = palm 9.5 cm wrist to middle MCP). spread: factor on the
    neutral finger spread. flexion_bias: added to the curl of middle/ring/pinky (and the thumb's rest
    curl in :func:`hand_joints`). skin_rgba: colour of the skin. sleeve_rgba: colour of the sleeve
    (the "skin" look of demoforge.lib.synth.render only).
    """

    scale: float = 1.0
    spread: float = 1.0
    flexion_bias: float = 0.0
    skin_rgba: tuple[float, float, float, float] = (0.91, 0.72, 0.60, 1.0)
    sleeve_rgba: tuple[float, float, float, float] = (0.12, 0.16, 0.30, 1.0)


def sample_style(rng: np.random.Generator) -> HandStyle:
    """A random plausible adult hand: scale 0.9-1.1, spread 0.6-1.4, bias -0.1..0.15, one of six skin
    tones, one of eight sleeve colours (drawn last, so the other fields are those of older versions)."""
    tone = _SKIN_TONES[rng.integers(len(_SKIN_TONES))] * rng.uniform(0.95, 1.03)
    scale = float(rng.uniform(0.9, 1.1))
    spread = float(rng.uniform(0.6, 1.4))
    bias = float(rng.uniform(-0.1, 0.15))
    sleeve = _SLEEVE_COLOURS[rng.integers(len(_SLEEVE_COLOURS))]
    return HandStyle(
        scale=scale, spread=spread, flexion_bias=bias,
        skin_rgba=tuple(float(c) for c in np.clip(tone, 0, 1)) + (1.0,),
        sleeve_rgba=tuple(float(c) for c in sleeve) + (1.0,),
    )


def _side_index(side) -> int:
    if isinstance(side, str):
        s = side.lower()
        if s in ("left", "l"):
            return 0
        if s in ("right", "r"):
            return 1
        raise ValueError(f"side must be 'left'/'right' or 0/1, got {side!r}")
    s = int(side)
    if s not in (0, 1):
        raise ValueError(f"side must be 'left'/'right' or 0/1, got {side!r}")
    return s


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _orth(v: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Unit part of v perpendicular to the unit vector ref."""
    return _unit(v - np.sum(v * ref, axis=-1, keepdims=True) * ref)


def _chain(base, f, n, lengths, angles):
    """Planar 3-link chain in the plane (f, n) from base; angles (..., 3) bend from f towards n.

    Returns (..., 3, 3): the three child joint positions.
    """
    cum = np.cumsum(angles, axis=-1)                                  # (..., 3)
    dirs = np.cos(cum)[..., None] * f[..., None, :] + np.sin(cum)[..., None] * n[..., None, :]
    return base[..., None, :] + np.cumsum(lengths[..., :, None] * dirs, axis=-2)


def _finger_frames(style: HandStyle):
    """Forward directions (4, 3) of the long fingers and the palmar normal, right hand local."""
    ang = _SPREAD * style.spread
    f = np.stack([np.cos(ang), np.sin(ang), np.zeros(4)], axis=-1)
    n = np.array([0.0, 0.0, -1.0])
    return f, n


def thumb_frame():
    f = _unit(_THUMB_DIR)
    n = _orth(_THUMB_FLEXDIR, f)
    return f, n


def _local_joints_right(flexion: np.ndarray, style: HandStyle) -> np.ndarray:
    """(..., 21, 3) right-hand local joints from flexion (..., 5)."""
    s = style.scale
    flexion = np.asarray(flexion, dtype=float)
    batch = flexion.shape[:-1]
    out = np.zeros(batch + (N_JOINTS, 3))
    cmc = _THUMB_CMC * s
    out[..., 1, :] = cmc
    tf, tn = thumb_frame()
    ft = flexion[..., 0]
    tang = _THUMB_REST + ft[..., None] * _THUMB_FLEX
    out[..., 2:5, :] = _chain(np.broadcast_to(cmc, batch + (3,)), np.broadcast_to(tf, batch + (3,)),
                             np.broadcast_to(tn, batch + (3,)), _LENGTHS[0] * s, tang)
    ff, fn = _finger_frames(style)
    for i in range(4):
        fl = flexion[..., i + 1]
        ang = fl[..., None] * _FINGER_FLEX
        base = np.broadcast_to(_MCP[i] * s, batch + (3,))
        j = FINGER_JOINTS[i + 1]
        out[..., j[0], :] = base
        out[..., j[1]:j[3] + 1, :] = _chain(base, np.broadcast_to(ff[i], batch + (3,)),
                                            np.broadcast_to(fn, batch + (3,)), _LENGTHS[i + 1] * s, ang)
    return out


_MIRROR_LOCAL = np.array([1.0, -1.0, 1.0])


def _to_side(local_right: np.ndarray, side: int) -> np.ndarray:
    return local_right if side == 1 else local_right * _MIRROR_LOCAL


def _apply(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply (..., 4, 4) transforms to (..., k, 3) points."""
    return np.einsum("...ij,...kj->...ki", T[..., :3, :3], pts) + T[..., None, :3, 3]


def hand_joints(wrist_T, flexion, side, style: HandStyle | None = None) -> np.ndarray:
    """World joints (..., 21, 3) of a hand with wrist pose ``wrist_T`` (..., 4, 4, hand-local to world).

    flexion: (..., 5) per finger (thumb, index, middle, ring, pinky) in [0, 1], or a scalar/(...)
    value used for every finger. side: "left"/"right" or 0/1.
    """
    style = style or HandStyle()
    sd = _side_index(side)
    wrist_T = np.asarray(wrist_T, dtype=float)
    flexion = np.clip(np.asarray(flexion, dtype=float), 0.0, 1.0)
    if flexion.ndim == 0 or flexion.shape[-1] != 5:
        flexion = np.repeat(flexion[..., None], 5, axis=-1)
    batch = np.broadcast_shapes(wrist_T.shape[:-2], flexion.shape[:-1])
    flexion = np.broadcast_to(flexion, batch + (5,))
    local = _to_side(_local_joints_right(flexion, style), sd)
    return _apply(np.broadcast_to(wrist_T, batch + (4, 4)), local)


# --- inverse: hand from a pinch frame --------------------------------------------------------------

def _index_flexion(aperture):
    """Index flexion used for a pinch of the given aperture (closed pinch: curled; wide: straighter)."""
    return np.clip(0.60 - 0.6 * aperture, 0.5, 0.6)


def _thumb_flexion(aperture):
    return np.clip(0.75 - 5.0 * aperture, 0.0, 0.75)


def _other_flexion(aperture, style: HandStyle):
    """Curl of middle, ring, pinky (..., 3): closes around the object as the aperture shrinks."""
    base = np.clip(0.80 - 6.0 * aperture, 0.12, 0.80) + style.flexion_bias
    return np.clip(base[..., None] + np.array([0.0, 0.06, 0.12]), 0.0, 1.0)


def _thumb_ik(target, style: HandStyle, n_iter: int = 48):
    """Thumb joints 2, 3, 4 (..., 3, 3) reaching ``target`` (..., 3), right-hand local frame.

    The thumb is a planar chain (metacarpal, proximal, distal) from its CMC joint in the plane
    through its flexion direction n, abducted about n so the plane contains the target; the IP
    angle is coupled to the MCP angle. The MCP angle solves reach(theta) = |target - CMC| by
    bisection (reach decreases monotonically in theta on [0, max]); the CMC angle then aims the chain.
    """
    s = style.scale
    L = _LENGTHS[0] * s
    cmc = _THUMB_CMC * s
    f0, n = thumb_frame()
    l = np.cross(n, f0)
    d = target - cmc
    psi = np.arctan2(d @ l, d @ f0)
    f = np.cos(psi)[..., None] * f0 + np.sin(psi)[..., None] * l      # abducted forward, still ⟂ n
    u, w = np.sum(d * f, axis=-1), d @ n
    dist = np.hypot(u, w)

    def reach(th):
        vx = L[0] + L[1] * np.cos(th) + L[2] * np.cos((1 + _THUMB_K) * th)
        vy = L[1] * np.sin(th) + L[2] * np.sin((1 + _THUMB_K) * th)
        return vx, vy

    lo = np.zeros_like(dist)
    hi = np.full_like(dist, _THUMB_MAX)
    for _ in range(n_iter):
        mid = 0.5 * (lo + hi)
        vx, vy = reach(mid)
        too_far = np.hypot(vx, vy) > dist   # still reaching too far: bend more
        lo = np.where(too_far, mid, lo)
        hi = np.where(too_far, hi, mid)
    th2 = 0.5 * (lo + hi)
    vx, vy = reach(th2)
    th1 = np.arctan2(w, u) - np.arctan2(vy, vx)
    angles = np.stack([th1, th2, _THUMB_K * th2], axis=-1)
    batch = target.shape[:-1]
    return _chain(np.broadcast_to(cmc, batch + (3,)), f, np.broadcast_to(n, batch + (3,)), L, angles)


def _local_pinch_hand(aperture: np.ndarray, style: HandStyle):
    """Right-hand local joints (..., 21, 3) and local pinch frame (..., 4, 4) for an aperture."""
    a = np.asarray(aperture, dtype=float)
    batch = a.shape
    fl = np.zeros(batch + (5,))
    fl[..., 0] = _thumb_flexion(a)
    fl[..., 1] = _index_flexion(a)
    fl[..., 2:] = _other_flexion(a, style)
    J = _local_joints_right(fl, style)
    B = 0.5 * (J[..., 0, :] + J[..., 1, :])
    idx = J[..., 8, :]
    t_nat = J[..., 4, :]
    r = np.linalg.norm(idx - B, axis=-1)
    e = (idx - B) / r[..., None]
    # Circle {X : |X - B| = r, |X - idx| = a}: centre c = B + e (r - a^2 / 2r), radius a sqrt(1 - a^2/4r^2).
    c = B + e * (r - a * a / (2 * r))[..., None]
    v = t_nat - c
    v = v - np.sum(v * e, axis=-1, keepdims=True) * e
    u = _unit(v)
    x = e * (a / (2 * r))[..., None] - np.sqrt(np.clip(1 - a * a / (4 * r * r), 0, 1))[..., None] * u
    x = _unit(x)
    thumb_tip = idx - a[..., None] * x
    J[..., 2:5, :] = _thumb_ik(thumb_tip, style)
    # Exact local pinch frame from the construction (x ⟂ z by the equidistance of the tips from B).
    m = idx - 0.5 * a[..., None] * x
    z = _unit(m - B)
    x = _orth(x, z)
    y = np.cross(z, x)
    P = np.zeros(batch + (4, 4))
    P[..., :3, 0], P[..., :3, 1], P[..., :3, 2], P[..., :3, 3] = x, y, z, m
    P[..., 3, 3] = 1.0
    return J, P


def _inv_T(T):
    R, t = T[..., :3, :3], T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def hand_from_pinch(pinch_T, aperture, side, style: HandStyle | None = None):
    """A natural hand for a pinch frame: returns (joints (..., 21, 3) world, wrist_T (..., 4, 4)).

    pinch_T: (..., 4, 4) world pose of the pinch frame (origin = thumb/index tip midpoint, z =
    approach, x = thumb tip -> index tip, y = z x x). aperture: (...) thumb-index tip distance, m
    (0 to about 0.14; clipped there). side: "left"/"right" or 0/1. The thumb tip (4) lands at
    origin - aperture/2 x and the index tip (8) at origin + aperture/2 x (to float precision while
    the thumb can reach, i.e. over the whole clipped aperture range), the base midpoint on -z.
    """
    style = style or HandStyle()
    sd = _side_index(side)
    pinch_T = np.asarray(pinch_T, dtype=float)
    aperture = np.asarray(aperture, dtype=float)
    batch = np.broadcast_shapes(pinch_T.shape[:-2], aperture.shape)
    a = np.clip(np.broadcast_to(aperture, batch), 0.0, 0.14 * style.scale)
    J, P = _local_pinch_hand(a, style)
    if sd == 0:
        J = J * _MIRROR_LOCAL
        P = P.copy()
        M = np.diag([1.0, -1.0, 1.0])
        # Mirror the frame: position and x, z mirror; y = z x x flips sign to stay right-handed.
        P[..., :3, :3] = M @ P[..., :3, :3] @ np.diag([1.0, -1.0, 1.0])
        P[..., :3, 3] = P[..., :3, 3] * _MIRROR_LOCAL
    wrist_T = np.broadcast_to(pinch_T, batch + (4, 4)) @ _inv_T(P)
    return _apply(wrist_T, J), wrist_T


def pinch_from_joints(joints: np.ndarray):
    """The thesis's mapping (Sec. 3.1.3) from joints (..., 21, 3) to (pinch_T (..., 4, 4), aperture).

    Origin = midpoint of thumb tip and index tip; z = unit vector from the base midpoint
    ((0 + 1) / 2) to that origin (what Rodrigues' rotation aligns the gripper axis with);
    x = thumb tip -> index tip made perpendicular to z; y = z x x. Aperture = tip distance.
    """
    j = np.asarray(joints, dtype=float)
    t, i = j[..., 4, :], j[..., 8, :]
    o = 0.5 * (t + i)
    b = 0.5 * (j[..., 0, :] + j[..., 1, :])
    z = _unit(o - b)
    v = i - t
    v = v - np.sum(v * z, axis=-1, keepdims=True) * z
    # tips together: x is undefined; take any direction perpendicular to z (keeps the result finite)
    helper = np.where(np.abs(z[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    degenerate = np.linalg.norm(v, axis=-1, keepdims=True) < 1e-12
    v = np.where(degenerate, np.cross(z, helper), v)
    x = _unit(v)
    y = np.cross(z, x)
    T = np.zeros(j.shape[:-2] + (4, 4))
    T[..., :3, 0], T[..., :3, 1], T[..., :3, 2], T[..., :3, 3] = x, y, z, o
    T[..., 3, 3] = 1.0
    return T, np.linalg.norm(i - t, axis=-1)


# --- capsule body model ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Capsule:
    """One capsule of the body model: segment from joint ``a`` to joint ``b`` (or a fixed offset
    along it), radius in m. ``end_inset``: the segment stops this far (m) short of joint b, so that
    a fingertip capsule's surface ends at the tip keypoint."""

    a: int
    b: int
    radius: float
    end_inset: float = 0.0
    name: str = ""


def hand_capsules(style: HandStyle | None = None) -> list[Capsule]:
    """The capsules of one hand (same list for left and right), radii scaled with the hand."""
    s = (style or HandStyle()).scale
    caps = [
        # palm: metacarpals fanning from the wrist, plus the thenar web
        Capsule(0, 5, _R_PALM * s, name="palm_index"),
        Capsule(0, 9, _R_PALM * s, name="palm_middle"),
        Capsule(0, 13, _R_PALM * s, name="palm_ring"),
        Capsule(0, 17, _R_PALM * s, name="palm_pinky"),
        Capsule(1, 5, 0.010 * s, name="palm_web"),
        Capsule(5, 17, 0.0095 * s, name="palm_knuckles"),
        Capsule(0, 1, 0.012 * s, name="thumb_base"),
        Capsule(1, 2, _R_THUMB_META * s, name="thumb_meta"),
        Capsule(2, 3, _R_PROX * s, name="thumb_prox"),
        Capsule(3, 4, 0.0078 * s, end_inset=0.3 * 0.0078 * s, name="thumb_dist"),
    ]
    for fi, fname in enumerate(FINGER_NAMES[1:], start=1):
        m, p, d, t = FINGER_JOINTS[fi]
        shrink = 0.9 if fname == "pinky" else 1.0
        caps += [
            Capsule(m, p, _R_PROX * s * shrink, name=f"{fname}_prox"),
            Capsule(p, d, _R_MID * s * shrink, name=f"{fname}_mid"),
            Capsule(d, t, _R_DIST * s * shrink, end_inset=0.3 * _R_DIST * s * shrink, name=f"{fname}_dist"),
        ]
    return caps


def joint_radii(style: HandStyle | None = None) -> np.ndarray:
    """(21,) flesh radius around each joint (m): the largest capsule radius touching it."""
    r = np.zeros(N_JOINTS)
    for c in hand_capsules(style):
        r[c.a] = max(r[c.a], c.radius)
        r[c.b] = max(r[c.b], c.radius)
    return r


def capsule_segments(joints: np.ndarray, style: HandStyle | None = None):
    """Segment endpoints (..., n_caps, 2, 3) of :func:`hand_capsules` for joints (..., 21, 3)."""
    caps = hand_capsules(style)
    a = joints[..., [c.a for c in caps], :]
    b = joints[..., [c.b for c in caps], :]
    inset = np.array([c.end_inset for c in caps])
    d = b - a
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    b = b - d / np.maximum(length, 1e-12) * inset[:, None]
    return np.stack([a, b], axis=-2)


#: Joints that are rigid in the hand-local frame whatever the flexion: wrist, thumb CMC, the four MCPs.
PALM_JOINTS: tuple[int, ...] = (0, 1, 5, 9, 13, 17)


def palm_local(side, style: HandStyle | None = None) -> np.ndarray:
    """(len(PALM_JOINTS), 3) hand-local positions of :data:`PALM_JOINTS` (flexion-independent)."""
    local = _to_side(_local_joints_right(np.zeros(5), style or HandStyle()), _side_index(side))
    return local[list(PALM_JOINTS)]


def wrist_pose_from_joints(joints: np.ndarray, side, style: HandStyle | None = None) -> np.ndarray:
    """(..., 4, 4) wrist pose (hand-local to world) of joints (..., 21, 3) posed by this model.

    The palm joints are rigid in the hand-local frame, so the rotation is the Kabsch fit of
    :func:`palm_local` onto them (exact, to float precision, for joints from :func:`hand_joints` or
    :func:`hand_from_pinch` with the same style and side).
    """
    J = np.asarray(joints, dtype=float)[..., list(PALM_JOINTS), :]
    L = palm_local(side, style)
    jc, lc = J.mean(-2, keepdims=True), L.mean(0)
    H = np.einsum("ki,...kj->...ij", L - lc, J - jc)             # cross-covariance local -> world
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    T = np.zeros(J.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = jc[..., 0, :] - np.einsum("...ij,j->...i", R, lc)
    T[..., 3, 3] = 1.0
    return T


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """(..., len(HAND_BONES)) lengths of the skeleton edges."""
    p = np.array([b[0] for b in HAND_BONES])
    c = np.array([b[1] for b in HAND_BONES])
    return np.linalg.norm(joints[..., c, :] - joints[..., p, :], axis=-1)


__all__ = [
    "HAND_BONES", "N_JOINTS", "FINGER_NAMES", "FINGER_JOINTS", "HandStyle", "sample_style",
    "hand_joints", "hand_from_pinch", "pinch_from_joints", "Capsule", "hand_capsules",
    "joint_radii", "capsule_segments", "bone_lengths", "PALM_JOINTS", "palm_local", "wrist_pose_from_joints",
]

