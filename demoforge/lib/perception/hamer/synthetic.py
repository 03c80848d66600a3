"""A small synthetic MANO-like model (same file layout as MANO_RIGHT.pkl) with known geometry.

For tests and benchmarks that must not need the licensed MANO file. 778 vertices so that the
fingertip vertex ids of smplx (744, 320, 443, 554, 671) exist: vertex j (< 16) sits on joint j and
is its only regressor vertex; the fingertip vertices sit one bone beyond each finger's last joint
and follow that joint; every other vertex is a point near a random joint and follows it.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np

from demoforge.lib.perception.hamer.mano import MANO_PARENTS, MANO_TIP_VERTEX_IDS, MANO_TO_OPENPOSE, ManoModelData

#: a flat right hand in MANO's frame (metres): wrist at the origin, fingers along +x, thumb towards +z
_FINGER_BASES = {  # MANO joint index of the finger's first joint -> (base position, direction)
    1: ((0.095, 0.0, 0.020), (1.0, 0.0, 0.0)),     # index
    4: ((0.095, 0.0, 0.000), (1.0, 0.0, 0.0)),     # middle
    7: ((0.080, 0.0, -0.040), (1.0, 0.0, -0.1)),   # pinky
    10: ((0.090, 0.0, -0.020), (1.0, 0.0, -0.05)),  # ring
    13: ((0.025, 0.0, 0.030), (0.6, 0.0, 0.8)),    # thumb
}
#: fingertip vertex per finger (MANO first joint index) in smplx's order thumb, index, middle, ring, pinky
_TIP_OF = {13: MANO_TIP_VERTEX_IDS[0], 1: MANO_TIP_VERTEX_IDS[1], 4: MANO_TIP_VERTEX_IDS[2],
           10: MANO_TIP_VERTEX_IDS[3], 7: MANO_TIP_VERTEX_IDS[4]}


def synthetic_mano(seed: int = 0, n_verts: int = 778, n_betas: int = 10, bone: float = 0.03,
                   posedirs_scale: float = 0.0) -> tuple[ManoModelData, np.ndarray]:
    """The model and its rest joints (21, 3) in MediaPipe order (16 MANO joints + tips, re-indexed)."""
    rng = np.random.default_rng(seed)
    J = np.zeros((16, 3))
    tips = {}
    for first, (base, d) in _FINGER_BASES.items():
        d = np.asarray(d) / np.linalg.norm(d)
        for k in range(3):
            J[first + k] = np.asarray(base) + k * bone * d
        tips[first] = J[first + 2] + bone * d
    V = n_verts
    owner = rng.integers(0, 16, V)
    v = J[owner] + rng.normal(0, 0.004, (V, 3))
    v[:16] = J
    owner[:16] = np.arange(16)
    for first, vid in _TIP_OF.items():
        v[vid] = tips[first]
        owner[vid] = first + 2
    weights = np.zeros((V, 16))
    weights[np.arange(V), owner] = 1.0
    J_reg = np.zeros((16, V))
    J_reg[np.arange(16), np.arange(16)] = 1.0
    shapedirs = rng.normal(0, 0.002, (V, 3, n_betas))
    posedirs = rng.normal(0, posedirs_scale, (V, 3, 135)) if posedirs_scale > 0 else np.zeros((V, 3, 135))
    model = ManoModelData(v_template=v, shapedirs=shapedirs, posedirs=posedirs, J_regressor=J_reg,
                          weights=weights, parents=np.array(MANO_PARENTS), faces=np.zeros((0, 3), np.int64))
    rest21 = np.concatenate([J, np.stack([tips[f] for f in (13, 1, 4, 10, 7)])])[list(MANO_TO_OPENPOSE)]
    return model.validate("synthetic MANO"), rest21


def write_synthetic_mano(path: str | os.PathLike, model: ManoModelData, sparse_regressor: bool = True) -> Path:
    """Write ``model`` like the official pickle (dict; kintree_table with 2**32 - 1 for the root;
    J_regressor as scipy sparse when asked) or as ``.npz`` when the path ends in .npz."""
    path = Path(path)
    kintree = np.stack([np.where(model.parents < 0, 2**32 - 1, model.parents), np.arange(16)]).astype(np.int64)
    data = {"v_template": model.v_template, "shapedirs": model.shapedirs, "posedirs": model.posedirs,
            "weights": model.weights, "kintree_table": kintree, "f": model.faces,
            "hands_components": np.eye(45), "hands_mean": np.zeros(45)}
    tmp = path.with_name(path.name + ".tmp")
    if path.suffix == ".npz":
        with open(tmp, "wb") as fh:
            np.savez(fh, J_regressor=model.J_regressor, **data)
    else:
        if sparse_regressor:
            import scipy.sparse as sp
            data["J_regressor"] = sp.csc_matrix(model.J_regressor)
        else:
            data["J_regressor"] = model.J_regressor
        with open(tmp, "wb") as fh:
            pickle.dump(data, fh, protocol=2)
    os.replace(tmp, path)
    return path
