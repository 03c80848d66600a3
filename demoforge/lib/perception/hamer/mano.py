"""MANO forward kinematics in torch (pose, shape, global orientation -> vertices and 21 joints).

The maths is smplx's linear blend skinning (smplx/lbs.py: blend shapes, joint regression, pose
correctives from (R - I), rigid transforms down the kinematic tree, skinning) as used by HaMeR's
MANO wrapper (hamer/models/mano_wrapper.py of github.com/geopavlakos/hamer): smplx.MANOLayer fed
rotation matrices (pose2rot=False, so no PCA and no hand mean), 16 regressed joints, plus five
fingertip vertices (smplx/vertex_ids.py ``vertex_ids['mano']``: thumb 744, index 320, middle 443,
ring 554, pinky 671), re-indexed to OpenPose order with
``mano_to_openpose = [0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20]``,
which is demoforge's fixed MediaPipe order (lib/joints.py).

MANO's 16 joints: 0 wrist, 1-3 index, 4-6 middle, 7-9 pinky, 10-12 ring, 13-15 thumb.

The MANO model file is licensed (mano.is.tue.mpg.de) and never downloaded here: pass the local path
of ``MANO_RIGHT.pkl`` (the official pickle; its chumpy arrays are read without chumpy) or of an
``.npz`` with the same keys: ``v_template`` (V, 3), ``shapedirs`` (V, 3, S), ``posedirs`` (V, 3, 135),
``J_regressor`` (16, V, dense or scipy sparse), ``weights`` (V, 16), ``kintree_table`` (2, 16),
optional ``f`` (faces).
"""

from __future__ import annotations

import os
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from demoforge.lib.errors import UserError

__all__ = ["MANO_TIP_VERTEX_IDS", "MANO_TO_OPENPOSE", "MANO_PARENTS", "ManoModelData", "MANOError",
           "load_mano_model", "ManoLayer", "axis_angle_to_rotmat"]

#: smplx vertex_ids['mano'] (thumb, index, middle, ring, pinky fingertip vertices)
MANO_TIP_VERTEX_IDS = (744, 320, 443, 554, 671)
#: HaMeR's mano_to_openpose: output joint j = [16 MANO joints + 5 tips][MANO_TO_OPENPOSE[j]]
MANO_TO_OPENPOSE = (0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20)
#: MANO's kinematic tree (kintree_table[0] with the root's 2**32 - 1 as -1)
MANO_PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)
N_MANO_JOINTS = 16


class MANOError(UserError):
    """The MANO model file is missing or not a MANO model."""


class _ChumpyStub:
    """Stands in for chumpy objects while unpickling the official MANO pickle without chumpy."""

    def __new__(cls, *args, **kwargs):  # noqa: D102 - pickle calls cls.__new__(cls)
        return object.__new__(cls)

    def __setstate__(self, state):
        if isinstance(state, dict):
            self.__dict__.update(state)
        else:
            self.__dict__["_state"] = state


class _MANOUnpickler(pickle.Unpickler):
    """numpy arrays and scipy sparse matrices load as themselves, chumpy arrays as stubs whose value
    is in ``x``; any other callable is refused (a model file needs none)."""

    def find_class(self, module: str, name: str):
        root = module.split(".")[0]
        if root == "chumpy":
            return _ChumpyStub
        ok = ((root == "numpy" and (name in ("_reconstruct", "ndarray", "dtype", "scalar") or name.endswith("DType")))
              or (module.startswith("scipy.sparse") and name.endswith(("_matrix", "_array")))
              or (module in ("builtins", "__builtin__") and name in ("object", "set", "frozenset", "tuple", "list",
                                                                     "dict", "slice", "bytes", "bytearray"))
              or (module in ("copy_reg", "copyreg") and name == "_reconstructor")
              or (module == "_codecs" and name == "encode"))
        if ok:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"MANO pickle refers to {module}.{name}, which a MANO model file never "
                                     "needs; refusing to load it")


def _to_array(obj, key: str, path: Path) -> np.ndarray:
    if isinstance(obj, _ChumpyStub):
        if "x" in obj.__dict__:
            obj = obj.__dict__["x"]
        else:
            raise MANOError(f"{path}: '{key}' is a chumpy expression without a stored value; convert the "
                            "model to .npz with chumpy installed (np.savez(out, **{k: np.array(v) ...}))")
    if hasattr(obj, "toarray"):  # scipy sparse (J_regressor)
        obj = obj.toarray()
    return np.asarray(obj, dtype=np.float64)


@dataclass
class ManoModelData:
    """The arrays of a MANO hand model (float64 numpy), in the official file's layout."""

    v_template: np.ndarray     # (V, 3)
    shapedirs: np.ndarray      # (V, 3, S)
    posedirs: np.ndarray       # (V, 3, 9 * 15)
    J_regressor: np.ndarray    # (16, V)
    weights: np.ndarray        # (V, 16)
    parents: np.ndarray        # (16,) int, -1 for the root
    faces: np.ndarray | None = None

    def validate(self, source: str = "MANO model") -> "ManoModelData":
        V = self.v_template.shape[0]
        checks = [
            (self.v_template.shape == (V, 3), f"v_template {self.v_template.shape}, expected (V, 3)"),
            (self.shapedirs.ndim == 3 and self.shapedirs.shape[:2] == (V, 3),
             f"shapedirs {self.shapedirs.shape}, expected ({V}, 3, S)"),
            (self.posedirs.shape == (V, 3, 9 * (N_MANO_JOINTS - 1)),
             f"posedirs {self.posedirs.shape}, expected ({V}, 3, 135)"),
            (self.J_regressor.shape == (N_MANO_JOINTS, V), f"J_regressor {self.J_regressor.shape}, expected (16, {V})"),
            (self.weights.shape == (V, N_MANO_JOINTS), f"weights {self.weights.shape}, expected ({V}, 16)"),
            (self.parents.shape == (N_MANO_JOINTS,), f"kintree_table parents {self.parents.shape}, expected (16,)"),
            (V > max(MANO_TIP_VERTEX_IDS), f"{V} vertices; the fingertip vertex ids need at least {max(MANO_TIP_VERTEX_IDS) + 1}"),
        ]
        bad = [msg for ok, msg in checks if not ok]
        if bad:
            raise MANOError(f"{source} is not a MANO hand model: " + "; ".join(bad))
        p = self.parents
        if p[0] != -1 or np.any(p[1:] < 0) or np.any(p[1:] >= np.arange(1, N_MANO_JOINTS)):
            raise MANOError(f"{source}: kintree_table must list parents before children with the root first, got {p.tolist()}")
        return self


def load_mano_model(path: str | os.PathLike) -> ManoModelData:
    """Read a MANO right-hand model (official ``MANO_RIGHT.pkl`` or an ``.npz`` with the same keys)."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise MANOError(f"MANO model file not found: {path}. HaMeR needs the MANO right-hand model "
                        "(MANO_RIGHT.pkl from https://mano.is.tue.mpg.de, licensed, not downloaded by demoforge)")
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                raw = {k: z[k] for k in z.files}
        else:
            with open(path, "rb") as fh:
                raw = _MANOUnpickler(fh, encoding="latin1").load()
    except (pickle.UnpicklingError, EOFError, ValueError, OSError) as e:
        raise MANOError(f"cannot read MANO model {path}: {e}") from e
    if not isinstance(raw, dict):
        raise MANOError(f"{path} holds a {type(raw).__name__}, not a MANO model dictionary")
    missing = [k for k in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table") if k not in raw]
    if missing:
        raise MANOError(f"{path} is missing MANO keys {missing} (has {sorted(raw)})")
    arr = {k: _to_array(raw[k], k, path) for k in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights")}
    kin = np.asarray(raw["kintree_table"]).astype(np.int64)
    parents = kin[0].copy()
    parents[0] = -1  # stored as 2**32 - 1
    faces = np.asarray(raw["f"], dtype=np.int64) if "f" in raw else None
    if arr["shapedirs"].ndim == 2:  # flattened (V*3, S)
        arr["shapedirs"] = arr["shapedirs"].reshape(-1, 3, arr["shapedirs"].shape[-1])
    return ManoModelData(parents=parents, faces=faces, **arr).validate(str(path))


def axis_angle_to_rotmat(aa: torch.Tensor) -> torch.Tensor:
    """Rodrigues: (..., 3) axis-angle -> (..., 3, 3), stable at zero angle."""
    theta = torch.linalg.norm(aa, dim=-1, keepdim=True)
    axis = aa / theta.clamp_min(1e-12)
    x, y, z = axis.unbind(-1)
    zero = torch.zeros_like(x)
    Kx = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*aa.shape[:-1], 3, 3)
    s, c = torch.sin(theta)[..., None], torch.cos(theta)[..., None]
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand_as(Kx)
    return eye + s * Kx + (1 - c) * (Kx @ Kx)


class ManoLayer(nn.Module):
    """MANO as a torch module: rotation matrices + betas -> vertices and 21 joints (MediaPipe order).

    Buffers are non-persistent: they come from the MANO file, not from the HaMeR checkpoint.
    """

    def __init__(self, model: ManoModelData, dtype: torch.dtype = torch.float32):
        super().__init__()
        model.validate()
        V = model.v_template.shape[0]
        t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
        self.register_buffer("v_template", t(model.v_template), persistent=False)
        self.register_buffer("shapedirs", t(model.shapedirs), persistent=False)
        # (135, V*3) as in smplx: pose_feature (B, 135) @ posedirs -> (B, V*3)
        self.register_buffer("posedirs", t(model.posedirs.reshape(V * 3, -1).T), persistent=False)
        self.register_buffer("J_regressor", t(model.J_regressor), persistent=False)
        self.register_buffer("lbs_weights", t(model.weights), persistent=False)
        self.register_buffer("tip_ids", torch.tensor(MANO_TIP_VERTEX_IDS, dtype=torch.long), persistent=False)
        self.register_buffer("joint_map", torch.tensor(MANO_TO_OPENPOSE, dtype=torch.long), persistent=False)
        self.parents = [int(p) for p in model.parents]
        self.num_betas = model.shapedirs.shape[-1]

    def forward(self, global_orient: torch.Tensor, hand_pose: torch.Tensor,
                betas: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Args: global_orient (B, 3, 3) or (B, 1, 3, 3); hand_pose (B, 15, 3, 3); betas (B, <=S) or None.

        Returns (vertices (B, V, 3), joints (B, 21, 3)) in MANO's metric model frame (metres).
        """
        B = hand_pose.shape[0]
        dtype, dev = self.v_template.dtype, self.v_template.device
        rot = torch.cat([global_orient.reshape(B, 1, 3, 3), hand_pose.reshape(B, -1, 3, 3)], 1).to(dtype)
        if rot.shape[1] != N_MANO_JOINTS:
            raise ValueError(f"hand_pose must hold 15 joint rotations, got {rot.shape[1] - 1}")
        v = self.v_template.expand(B, -1, -1)
        if betas is not None:
            betas = betas.to(dtype)
            nb = betas.shape[-1]
            if nb > self.num_betas:
                raise ValueError(f"{nb} betas but the MANO model has {self.num_betas} shape directions")
            v = v + torch.einsum("bl,vkl->bvk", betas, self.shapedirs[..., :nb])
        J = torch.einsum("jv,bvk->bjk", self.J_regressor, v)                       # (B, 16, 3)
        eye = torch.eye(3, dtype=dtype, device=dev)
        pose_feature = (rot[:, 1:] - eye).reshape(B, -1)
        v_posed = v + (pose_feature @ self.posedirs).reshape(B, -1, 3)
        # rigid transforms down the tree (smplx batch_rigid_transform)
        rel = J.clone()
        rel[:, 1:] = J[:, 1:] - J[:, self.parents[1:]]
        local = torch.zeros(B, N_MANO_JOINTS, 4, 4, dtype=dtype, device=dev)
        local[..., :3, :3] = rot
        local[..., :3, 3] = rel
        local[..., 3, 3] = 1.0
        chain = [local[:, 0]]
        for i in range(1, N_MANO_JOINTS):
            chain.append(chain[self.parents[i]] @ local[:, i])
        G = torch.stack(chain, 1)                                                 # (B, 16, 4, 4)
        posed_joints = G[..., :3, 3]
        # remove the rest-pose joint location so G acts on rest-pose vertices
        A = G.clone()
        A[..., :3, 3] = G[..., :3, 3] - (G[..., :3, :3] @ J[..., None])[..., 0]
        T = torch.einsum("vj,bjmn->bvmn", self.lbs_weights, A)                    # (B, V, 4, 4)
        verts = (T[..., :3, :3] @ v_posed[..., None])[..., 0] + T[..., :3, 3]
        tips = verts[:, self.tip_ids]
        joints = torch.cat([posed_joints, tips], 1)[:, self.joint_map]
        return verts, joints
