"""A tiny fake ARCTIC tree in the documented layout (ARCTIC's licence forbids copying its data).

    <root>/meta/misc.json
    <root>/outputs/processed_verts/seqs/<subject>/<seq>.npy    pickled dict (cam_coord, 2d, params)
    <root>/images/<subject>/<seq>/<view>/%05d.jpg              image index = frame + ioi_offset,
                                                                frames SKIP .. T-SKIP-1 only

Joints are stored in ARCTIC's MANO(+tips) order: a simple hand in the fixed (OpenPose) order is
made first and scattered to MANO order with the inverse of demoforge.lib.evaluation.arctic.MANO_TO_OPENPOSE, so a correct
loader gives the hand back. ``distinct=True`` stores joint k of the MANO order as (k, 100 + k, 1000 + k)
mm-like values instead (a direct re-indexing check).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from demoforge.lib.evaluation.arctic import MANO_TO_OPENPOSE

FOCAL = 2431.5  # the thesis's egocentric focal length


def openpose_hand(side: str, t: int) -> np.ndarray:
    """(21, 3) a hand in the fixed order: wrist, then 5 fingers of 4 joints, 2.5 cm bones, the fingers
    curling with t (bone lengths constant in time, distances of non-adjacent joints not)."""
    sgn = -1.0 if side == "left" else 1.0
    base = np.array([0.12 * sgn + 0.002 * t, 0.05, 0.60])
    curl = 0.15 * t
    j = np.zeros((21, 3))
    j[0] = base
    for f in range(5):
        d = np.array([sgn * np.cos(np.radians(30 * f - 60)), -np.sin(np.radians(30 * f - 60)) - 1.0, 0.0])
        d /= np.linalg.norm(d)
        p = base.copy()
        for k in range(4):
            a = curl * k
            p = p + 0.025 * (np.cos(a) * d + np.sin(a) * np.array([0.0, 0.0, -1.0]))
            j[1 + 4 * f + k] = p
    return j


def K_ego(t: int) -> np.ndarray:
    return np.array([[FOCAL + t, 0.0, 500.0], [0.0, FOCAL + t, 400.0], [0.0, 0.0, 1.0]])


def make_seq(T: int = 30, V: int = 2, distinct: bool = False) -> dict:
    inv = np.argsort(np.asarray(MANO_TO_OPENPOSE))       # op order -> mano: mano[k] = op[inv[k]]
    out3 = {}
    out2 = {}
    Ks = np.stack([K_ego(t) for t in range(T)])
    K_allo = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    for side in ("left", "right"):
        j3 = np.zeros((T, V, 21, 3))
        for t in range(T):
            op = openpose_hand(side, t)
            for v in range(V):
                j3[t, v] = op[inv] + np.array([0.0, 0.0, 0.1 * v])
        if distinct:
            k = np.arange(21, dtype=float)
            j3[:] = np.stack([k, 100 + k, 1000 + k], -1) * (1.0 if side == "right" else -1.0)
        j2 = np.zeros((T, V, 21, 2))
        for v in range(V):
            for t in range(T):
                K = Ks[t] if v == 0 else K_allo
                uvw = j3[t, v] @ K.T
                with np.errstate(divide="ignore", invalid="ignore"):
                    j2[t, v] = uvw[:, :2] / uvw[:, 2:3]
        out3[f"joints.{side}"] = j3
        out2[f"joints.{side}"] = j2
    is_valid = np.ones((T, V))
    left_valid = np.ones((T, V))
    right_valid = np.ones((T, V))
    left_valid[12, :] = 0            # frame 12: left hand invalid
    is_valid[13, :] = 0              # frame 13: both invalid
    return {
        "cam_coord": {**out3, "is_valid": is_valid, "left_valid": left_valid, "right_valid": right_valid},
        "2d": out2,
        "params": {"K_ego": Ks, "world2ego": np.tile(np.eye(4), (T, 1, 1))},
        "world_coord": {},
    }


def build_arctic_tree(root, subject: str = "s01", seqs=("box_grab_01",), T: int = 30, V: int = 2,
                      ioi_offset: int = 2, distinct: bool = False, images: bool = True,
                      drop_keys: tuple[tuple[str, ...], ...] = (), skip: int = 10) -> Path:
    """Write the fake tree under ``root``; ``drop_keys``: key paths to delete from the seq dicts,
    e.g. (("cam_coord", "joints.left"),)."""
    import cv2

    root = Path(root)
    misc = {subject: {
        "world2cam": [np.eye(4).tolist() for _ in range(V - 1)],
        "intris_mat": [[[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]] for _ in range(V - 1)],
        "image_size": [[1000, 800]] + [[640, 480]] * (V - 1),
        "ioi_offset": ioi_offset,
    }}
    (root / "meta").mkdir(parents=True, exist_ok=True)
    (root / "meta" / "misc.json").write_text(json.dumps(misc))
    sd = root / "outputs" / "processed_verts" / "seqs" / subject
    sd.mkdir(parents=True, exist_ok=True)
    img = np.full((8, 8, 3), 128, np.uint8)
    for seq in seqs:
        d = make_seq(T, V, distinct)
        for path in drop_keys:
            node = d
            for k in path[:-1]:
                node = node[k]
            del node[path[-1]]
        np.save(sd / f"{seq}.npy", np.array(d, dtype=object), allow_pickle=True)
        if images:
            for v in range(V):
                idir = root / "images" / subject / seq / str(v)
                idir.mkdir(parents=True, exist_ok=True)
                for f in range(skip, T - skip):
                    cv2.imwrite(str(idir / f"{f + ioi_offset:05d}.jpg"), img)
    return root
