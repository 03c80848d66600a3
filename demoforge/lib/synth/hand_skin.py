"""The "skin" look of the synthetic hands: a palm, a forearm and a sleeve around the kinematic hand.

The capsule hand of :mod:`demoforge.lib.perception.hand_model` (fingers and palm rays) stays as it is; this module adds
three closed, smoothly shaded surfaces that are rigid in the hand-local frame (wrist at the origin,
x towards the fingers, z out of the back of the hand), so they ride on ONE body whose pose is the
exact rigid fit of the palm joints (:func:`demoforge.lib.perception.hand_model.wrist_pose_from_joints`). Nothing here
moves a joint: the 21 ground-truth joints are the kinematic hand's, the surfaces are only drawn.

* palm: the convex hull of spheres around the wrist (widened to a real wrist's ~5 cm), the thumb's
  CMC joint, the four MCP joints and a palmar bulge -- a rounded slab about 2.5 cm thick that fills
  the gaps between the capsule rays (a detector looks for a palm), set towards the palmar side so
  the knuckles stand out on the back;
* forearm: a tapered elliptical tube 25 cm long behind the wrist (5 x 3.4 cm at the wrist);
* sleeve: a wider elliptical tube from 7 cm behind the wrist, in cloth colour (HandStyle.sleeve_rgba).

Each finger has a nail (:func:`nail_poses`): a flat, lighter ellipsoid just proud of the back of
its distal phalanx, one of the few cues that tell the back of a hand from the palm of the other
hand in an image.

The palm is rigid with the hand. The forearm and sleeve ride on a second body at the wrist that
points towards the demonstrator's shoulder (:data:`SHOULDERS`, on the camera's side of the table)
as far as a wrist can bend (:data:`MAX_WRIST_BEND`) -- a forearm rigidly behind the hand would
cross the other arm whenever a scripted grasp comes from the side.

Each surface is a triangle mesh with its own outward faces and area-weighted vertex normals (smooth
shading), sizes scaled with ``HandStyle.scale``; a left hand's meshes are the right hand's mirrored
in local y, like its joints.
"""

from __future__ import annotations

import numpy as np

from demoforge.lib.perception.hand_model import HandStyle, hand_capsules, palm_local, thumb_frame

#: Parts of the skin look: (name, colour from the style: "skin" or "sleeve", body: "hand" or "forearm").
PARTS: tuple[tuple[str, str, str], ...] = (("palm", "skin", "hand"), ("forearm", "skin", "forearm"),
                                           ("sleeve", "sleeve", "forearm"))
#: World points (m, table frame) the forearms point to: the demonstrator's shoulders, left and right,
#: on the camera's side of the table.
SHOULDERS = np.array([[-0.20, -0.45, 0.35], [0.20, -0.45, 0.35]])
#: Largest angle (rad) between the forearm and the hand's backward axis (a wrist's flexion range).
MAX_WRIST_BEND = np.radians(65.0)


def forearm_pose(wrist_T: np.ndarray, side: int) -> np.ndarray:
    """(..., 4, 4) pose of the forearm body (origin at the wrist, x from elbow towards the wrist,
    y the hand's y made perpendicular) for hand poses (..., 4, 4): pointing back at the shoulder,
    turned at most :data:`MAX_WRIST_BEND` away from the hand's -x."""
    W = np.asarray(wrist_T, float)
    back = -W[..., :3, 0]
    u = SHOULDERS[side] - W[..., :3, 3]
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    cos = np.clip(np.sum(back * u, -1), -1.0, 1.0)
    theta = np.arccos(cos)
    perp = u - cos[..., None] * back
    n = np.linalg.norm(perp, axis=-1, keepdims=True)
    perp = np.where(n > 1e-9, perp / np.maximum(n, 1e-12), 0.0)
    a = np.minimum(theta, MAX_WRIST_BEND)[..., None]
    d = np.cos(a) * back + np.sin(a) * perp                   # forearm direction, wrist -> elbow
    x = -d
    y = W[..., :3, 1] - np.sum(W[..., :3, 1] * x, -1, keepdims=True) * x
    y = y / np.maximum(np.linalg.norm(y, axis=-1, keepdims=True), 1e-12)
    z = np.cross(x, y)
    T = np.zeros(W.shape)
    T[..., :3, 0], T[..., :3, 1], T[..., :3, 2], T[..., :3, 3] = x, y, z, W[..., :3, 3]
    T[..., 3, 3] = 1.0
    return T


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    th = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], -1)


def _ring(x: float, half_w: float, half_t: float, z0: float, n: int = 40) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([np.full(n, x), half_w * np.cos(a), z0 + half_t * np.sin(a)], -1)


def _point_sets(side, style: HandStyle) -> dict[str, np.ndarray]:
    """Right/left hand-local point clouds whose convex hulls are the parts (m)."""
    s = style.scale
    mirror = np.array([1.0, -1.0, 1.0]) if side in (0, "left", "l") else np.ones(3)
    P = palm_local("right", style)                      # wrist, CMC, 4 MCPs (right-hand local)
    sph = _fibonacci_sphere(60)
    centres = np.concatenate([P, np.array([
        [0.004, 0.023, -0.004], [0.004, -0.023, -0.004],   # wrist width (radius + pisiform side)
        [0.050, 0.000, -0.004], [0.045, -0.022, -0.004],   # palmar bulge, hypothenar
    ]) * s])
    radii = np.array([0.012, 0.013, 0.0105, 0.0105, 0.0105, 0.0100, 0.0125, 0.0125, 0.0135, 0.0125]) * s
    # Real palms are thin on the back (skin over the metacarpals, knuckles standing out) and padded
    # on the palmar side: the slab sits 2 mm palmar of the joints, 7 mm under the knuckles so their
    # capsules show. A slab centred on the joints made MediaPipe read the back of a right hand as
    # the palm of a left one (handedness 0.17 on empty_vase frames, 0.67 with this shape).
    centres[:, 2] -= 0.002 * s
    centres[2:6, 2] -= 0.005 * s
    palm = (centres[:, None, :] + radii[:, None, None] * sph[None]).reshape(-1, 3)
    forearm = np.concatenate([
        _ring(-0.002 * s, 0.025 * s, 0.016 * s, -0.003 * s), _ring(-0.10 * s, 0.030 * s, 0.021 * s, -0.004 * s),
        _ring(-0.25 * s, 0.032 * s, 0.026 * s, -0.006 * s)])
    sleeve = np.concatenate([
        _ring(-0.07 * s, 0.041 * s, 0.033 * s, -0.004 * s), _ring(-0.16 * s, 0.044 * s, 0.036 * s, -0.005 * s),
        _ring(-0.30 * s, 0.046 * s, 0.040 * s, -0.006 * s)])
    return {k: v * mirror for k, v in (("palm", palm), ("forearm", forearm), ("sleeve", sleeve))}


def hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (n, 3), faces (m, 3) outward counter-clockwise, vertex normals (n, 3)) of the convex
    hull of ``points``; normals are area-weighted means of the faces' (smooth shading)."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(points)
    used = np.unique(hull.simplices)
    remap = np.full(len(points), -1)
    remap[used] = np.arange(len(used))
    V = points[used]
    F = remap[hull.simplices]
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    centre = V.mean(0)
    flip = np.einsum("ij,ij->i", n, (a + b + c) / 3 - centre) < 0
    F[flip] = F[flip][:, [0, 2, 1]]
    n[flip] *= -1
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], n)
    N /= np.linalg.norm(N, axis=-1, keepdims=True)
    return V, F, N


def skin_meshes(side, style: HandStyle | None = None) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """{part: (vertices, faces, normals)} in the hand-local frame of ``side`` ("left"/"right")."""
    style = style or HandStyle()
    return {k: hull_mesh(v) for k, v in _point_sets(side, style).items()}


def mesh_name(prefix: str, side: str, part: str, style: HandStyle) -> str:
    """Asset name of a part: the scale is in the name because the mesh depends on it."""
    return f"{prefix}_{side}_{part}_s{round(style.scale * 10000):05d}"


def mesh_asset_xml(name: str, mesh: tuple[np.ndarray, np.ndarray, np.ndarray]) -> str:
    V, F, N = mesh
    f = lambda a, fmt: " ".join(fmt % x for x in np.asarray(a).ravel())  # noqa: E731
    return (f'<mesh name="{name}" vertex="{f(V, "%.6g")}" normal="{f(N, "%.5g")}" '
            f'face="{f(F, "%d")}"/>')


#: Nails on the fingertips (a back-of-hand cue); half-sizes (m, scale 1) along the phalanx, across,
#: thickness, thumb first.
NAILS = True
NAIL_JOINTS = ((3, 4), (7, 8), (11, 12), (15, 16), (19, 20))
NAIL_SIZE = np.array([[0.0070, 0.0065, 0.0012]] + [[0.0062, 0.0055, 0.0012]] * 3 + [[0.0052, 0.0046, 0.0011]])
NAIL_COLOUR = np.array([0.97, 0.90, 0.88])


def nail_rgba(skin) -> tuple[float, float, float, float]:
    c = np.asarray(skin[:3], float)
    return tuple(float(x) for x in np.clip(c + 0.6 * (NAIL_COLOUR - c), 0, 1)) + (1.0,)


def nail_poses(joints: np.ndarray, wrist_T: np.ndarray, side, style: HandStyle | None = None) -> np.ndarray:
    """(5, 4, 4) poses of the nails (x along the distal phalanx towards the tip, z out of the nail)
    of one hand's joints (21, 3) with its wrist pose (4, 4): on the back of each distal phalanx,
    centred a third of its length from the tip, at the phalanx's flesh radius."""
    style = style or HandStyle()
    J = np.asarray(joints, float)
    R = np.asarray(wrist_T, float)[:3, :3]
    mirror = np.array([1.0, -1.0, 1.0]) if side in (0, "left", "l") else np.ones(3)
    _, n_thumb = thumb_frame()
    # a finger bends towards its palmar side; the nail faces the other way
    back = np.stack([-(R @ (n_thumb * mirror))] + [R[:, 2]] * 4)
    base, tip = J[[a for a, _ in NAIL_JOINTS]], J[[b for _, b in NAIL_JOINTS]]
    u = tip - base
    length = np.linalg.norm(u, axis=-1, keepdims=True)
    u = u / np.maximum(length, 1e-12)
    z = back - np.sum(back * u, -1, keepdims=True) * u
    z = z / np.maximum(np.linalg.norm(z, axis=-1, keepdims=True), 1e-12)
    caps = {c.name: c.radius for c in hand_capsules(style)}
    r = np.array([caps[f"{f}_dist"] for f in ("thumb", "index", "middle", "ring", "pinky")])
    T = np.zeros((5, 4, 4))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2] = u, np.cross(z, u), z
    T[:, :3, 3] = tip - u * (0.35 * length) + z * (r - 0.0003 * style.scale)[:, None]   # just proud of the skin
    T[:, 3, 3] = 1.0
    return T


__all__ = ["NAILS", "NAIL_JOINTS", "NAIL_SIZE", "nail_rgba", "nail_poses", "PARTS", "SHOULDERS", "MAX_WRIST_BEND", "forearm_pose", "hull_mesh", "skin_meshes", "mesh_name", "mesh_asset_xml"]
