"""ARCTIC loader: ground-truth hand joints of the egocentric (or an allocentric) view, re-indexed
to the project's 21-joint order, for the thesis's keypoint evaluation (section 4.2, 5.1.1).

ARCTIC's licence forbids redistributing its data: a user downloads it and points ``--arctic-root``
(``ArcticDataset(root)``) at the download. Nothing of ARCTIC is bundled here; tests use a tiny
fake tree in the same layout (tests/support/arctic_fixture.py).

Layout read (ARCTIC's documentation; see "what could not be confirmed" below)::

    <root>/meta/misc.json                         per subject "sXX": {
                                                    "world2cam":  per allocentric view 4x4,
                                                    "intris_mat": per allocentric view 3x3,
                                                    "image_size": per view [w, h],
                                                    "ioi_offset": int }
    <root>/outputs/processed_verts/seqs/sXX/<seq>.npy      (or data/arctic_data/data/processed_verts/
                                                    seqs, processed_verts/seqs, processed/seqs,
                                                    or an explicit ``seqs_dir``)
        np.load(allow_pickle=True).item() -> dict:
          "cam_coord": {"joints.right", "joints.left": (T, V, 21, 3) m, camera frame of each view;
                        validity flags (optional): "is_valid", "left_valid", "right_valid" (T, V)}
          "2d":        {"joints.right", "joints.left": (T, V, 21, 2) px}
          "params":    {"K_ego": (T, 3, 3), "world2ego": (T, 4, 4)}  (view 0, per frame)
    <root>/images/sXX/<seq>/<view>/%05d.jpg       (or data/arctic_data/data/images/...)
        image index = frame index + ioi_offset; the first and last 10 frames are skipped
        (ARCTIC's own convention: their mocap and images are not used).

View 0 is the undistorted egocentric camera, whose intrinsics/extrinsics move with the head and are
therefore per frame (``params.K_ego`` / ``params.world2ego``); views 1..8 are the static allocentric
cameras of misc.json (``intris_mat`` / ``world2cam`` hold 8 entries = views 1..8; a 9-entry list is
indexed by the view itself).

Joint order. ARCTIC's joints come from the MANO layer (smplx): MANO's 16 joints (0 wrist, 1-3 index,
4-6 middle, 7-9 pinky, 10-12 ring, 13-15 thumb) followed by the 5 fingertips smplx appends in the
order thumb, index, middle, ring, pinky (16-20). The standard MANO -> OpenPose re-indexing
``MANO_TO_OPENPOSE = [0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20]``
(the one HaMeR and FrankMocap use) gives the fixed order of docs/architecture.md: output joint j is ARCTIC
joint ``MANO_TO_OPENPOSE[j]`` (e.g. output 1-4 thumb CMC..tip = ARCTIC 13, 14, 15, 16).
``joint_order="openpose"`` skips the re-indexing if a release turns out to be in OpenPose order
already; :meth:`ArcticTake.bone_length_check` is a data-driven check of which order fits.

Could not be confirmed without the data (no copy of ARCTIC is available to this project): the
exact folder of the processed sequences in a given release, whether the validity flags live in
``cam_coord`` (assumed, with a fallback to the top level and to ``params``), whether ``image_size``
has 9 (all views) or 8 entries, and that the processed joints are not already in OpenPose order.
Every key and path is checked, and a missing one raises :class:`ArcticError` naming it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from demoforge.lib.joints import PARENTS

__all__ = [
    "ArcticError",
    "ArcticDataset",
    "ArcticTake",
    "THESIS_TAKES",
    "OBJECTS",
    "MANO_TO_OPENPOSE",
    "SEQS_DIR_CANDIDATES",
    "IMAGES_DIR_CANDIDATES",
    "MISC_CANDIDATES",
    "SKIP_FRAMES",
    "mano_to_openpose",
    "object_of",
]

#: The 18 egocentric takes of the thesis (section 5.1.1: three takes of each of six objects).
THESIS_TAKES: tuple[str, ...] = (
    "box_grab_01", "box_use_01", "box_use_02",
    "capsulemachine_use_01", "capsulemachine_use_02", "capsulemachine_grab_01",
    "espressomachine_grab_01", "espressomachine_use_01", "espressomachine_use_02",
    "ketchup_grab_01", "ketchup_use_01", "ketchup_use_02",
    "phone_grab_01", "phone_use_01", "phone_use_02",
    "scissors_use_01", "scissors_use_02", "scissors_grab_01",
)
OBJECTS: tuple[str, ...] = ("box", "capsulemachine", "espressomachine", "ketchup", "phone", "scissors")

#: output joint j (MediaPipe/OpenPose order) = ARCTIC/MANO(+tips) joint MANO_TO_OPENPOSE[j]
MANO_TO_OPENPOSE: tuple[int, ...] = (0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20)

#: frames skipped at each end of a sequence (ARCTIC's convention)
SKIP_FRAMES = 10

SEQS_DIR_CANDIDATES: tuple[str, ...] = (
    "outputs/processed_verts/seqs",
    "data/arctic_data/data/processed_verts/seqs",
    "arctic_data/data/processed_verts/seqs",
    "processed_verts/seqs",
    "data/arctic_data/data/processed/seqs",
    "processed/seqs",
    "seqs",
)
IMAGES_DIR_CANDIDATES: tuple[str, ...] = (
    "images",
    "data/arctic_data/data/images",
    "arctic_data/data/images",
)
MISC_CANDIDATES: tuple[str, ...] = (
    "meta/misc.json",
    "data/arctic_data/data/meta/misc.json",
    "arctic_data/data/meta/misc.json",
)

_DOWNLOAD_HINT = ("download ARCTIC (https://github.com/zc-alexfan/arctic, docs/data: "
                  "'meta', the processed sequences 'processed_verts/seqs' (or run its "
                  "scripts_data/process_seqs.py) and 'images' (or 'cropped_images')) and point "
                  "--arctic-root at the folder that holds them")


class ArcticError(RuntimeError):
    """Something of the ARCTIC download is missing or malformed (the message names it)."""


def mano_to_openpose(joints: np.ndarray, axis: int = -2) -> np.ndarray:
    """Re-index ARCTIC/MANO(+tips) joints (21 along ``axis``) to the MediaPipe/OpenPose order."""
    a = np.asarray(joints)
    if a.shape[axis] != 21:
        raise ValueError(f"expected 21 joints along axis {axis}, got shape {a.shape}")
    return np.take(a, np.asarray(MANO_TO_OPENPOSE), axis=axis)


def object_of(seq: str) -> str:
    """'capsulemachine_use_01' -> 'capsulemachine'."""
    return seq.split("_", 1)[0]


@dataclass
class ArcticTake:
    """One ARCTIC sequence seen from one view. Hand slot 0 = left, 1 = right (docs/architecture.md)."""

    name: str                      # "<subject>/<seq>"
    subject: str
    seq: str
    object: str
    view: int
    joints_cam: np.ndarray         # (T, 2, 21, 3) m, camera frame of the view, MediaPipe order
    joints_px: np.ndarray          # (T, 2, 21, 2) px
    valid: np.ndarray              # (T, 2) bool
    K: np.ndarray                  # (T, 3, 3) (egocentric, per frame) or (3, 3)
    image_size: tuple[int, int]    # (w, h)
    image_paths: np.ndarray        # (T,) str
    frame_indices: np.ndarray      # (T,) int, index into the processed sequence
    world2cam: np.ndarray | None = None   # (T, 4, 4) or (4, 4) when available
    ioi_offset: int = 0
    valid_source: str = ""         # which flags made ``valid``
    notes: list[str] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return int(self.frame_indices.shape[0])

    @property
    def take(self) -> str:
        return self.seq

    def reprojection_error_px(self) -> float:
        """Median distance (px) between ``joints_px`` and the projection of ``joints_cam`` with K over
        valid hands: a check that joints, K and 2D belong together (about 0 on consistent data)."""
        K = self.K if self.K.ndim == 3 else np.broadcast_to(self.K, (self.n_frames, 3, 3))
        uvw = np.einsum("tij,thkj->thki", K, self.joints_cam)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = uvw[..., :2] / uvw[..., 2:3]
            e = np.linalg.norm(uv - self.joints_px, axis=-1)[self.valid]
        e = e[np.isfinite(e)]
        return float(np.median(e)) if e.size else float("nan")

    def bone_length_check(self) -> dict[str, float]:
        """Which joint order fits the data: the temporal coefficient of variation of the 20 bone
        lengths of the kinematic tree (demoforge.lib.joints.PARENTS) for the loaded order and for the raw
        (un-re-indexed) order. Rigid bones vary little; a wrong order connects non-adjacent joints
        whose distance changes with the pose. Returns {"loaded": cv, "raw_as_openpose": cv}."""

        def cv(j):
            ch = np.arange(1, 21)
            L = np.linalg.norm(j[..., ch, :] - j[..., PARENTS[ch], :], axis=-1)  # (T, 2, 20)
            L = np.where(self.valid[..., None], L, np.nan)
            with np.errstate(invalid="ignore", divide="ignore"):
                return float(np.nanmean(np.nanstd(L, axis=0) / np.nanmean(L, axis=0)))

        inv = np.argsort(np.asarray(MANO_TO_OPENPOSE))
        return {"loaded": cv(self.joints_cam), "raw_as_openpose": cv(self.joints_cam[..., inv, :])}


def _get(d: dict, key: str, where: str):
    if not isinstance(d, dict) or key not in d:
        have = sorted(d.keys()) if isinstance(d, dict) else type(d).__name__
        raise ArcticError(f"{where}: missing key {key!r} (has {have}); {_DOWNLOAD_HINT}")
    return d[key]


class ArcticDataset:
    """An ARCTIC download at ``root``.

    Args:
        root: the folder the user downloaded ARCTIC into (``--arctic-root``).
        seqs_dir: explicit folder of the processed sequences (holding ``sXX/<seq>.npy``); default:
            the first of :data:`SEQS_DIR_CANDIDATES` under root that exists.
        images_dir: explicit images folder (holding ``sXX/<seq>/<view>/%05d.jpg``); default: the
            first of :data:`IMAGES_DIR_CANDIDATES` that exists.
        misc_path: explicit meta/misc.json.
        joint_order: "mano" (ARCTIC's MANO + tips order, re-indexed on read; default) or
            "openpose" (already in the fixed order: no re-indexing).
    """

    def __init__(self, root: str | os.PathLike, *, seqs_dir: str | os.PathLike | None = None,
                 images_dir: str | os.PathLike | None = None, misc_path: str | os.PathLike | None = None,
                 joint_order: str = "mano"):
        self.root = Path(root)
        if not self.root.is_dir():
            raise ArcticError(f"ARCTIC root {self.root} does not exist; {_DOWNLOAD_HINT}")
        if joint_order not in ("mano", "openpose"):
            raise ValueError(f"joint_order must be 'mano' or 'openpose', got {joint_order!r}")
        self.joint_order = joint_order
        self.seqs_dir = self._locate(seqs_dir, SEQS_DIR_CANDIDATES, "processed sequences folder (sXX/<seq>.npy)")
        self._images_dir = Path(images_dir) if images_dir is not None else None
        self._misc_path = Path(misc_path) if misc_path is not None else None
        self._misc: dict | None = None

    # -- paths ------------------------------------------------------------------------------------
    def _locate(self, explicit, candidates, what: str, must_be_dir: bool = True) -> Path:
        if explicit is not None:
            p = Path(explicit)
            if not (p.is_dir() if must_be_dir else p.is_file()):
                raise ArcticError(f"{what}: {p} does not exist; {_DOWNLOAD_HINT}")
            return p
        for c in candidates:
            p = self.root / c
            if p.is_dir() if must_be_dir else p.is_file():
                return p
        tried = ", ".join(str(self.root / c) for c in candidates)
        raise ArcticError(f"ARCTIC {what} not found under {self.root} (tried {tried}); {_DOWNLOAD_HINT}")

    @property
    def images_dir(self) -> Path:
        if self._images_dir is None:
            self._images_dir = self._locate(None, IMAGES_DIR_CANDIDATES, "images folder (sXX/<seq>/<view>/%05d.jpg)")
        elif not self._images_dir.is_dir():
            raise ArcticError(f"images folder {self._images_dir} does not exist; {_DOWNLOAD_HINT}")
        return self._images_dir

    @property
    def misc_path(self) -> Path:
        if self._misc_path is None:
            self._misc_path = self._locate(None, MISC_CANDIDATES, "meta/misc.json", must_be_dir=False)
        return self._misc_path

    @property
    def misc(self) -> dict:
        if self._misc is None:
            p = self.misc_path
            if not p.is_file():
                raise ArcticError(f"{p} does not exist; {_DOWNLOAD_HINT}")
            try:
                self._misc = json.loads(p.read_text())
            except (OSError, ValueError) as e:
                raise ArcticError(f"{p}: cannot read as JSON ({e})") from e
        return self._misc

    # -- listing ----------------------------------------------------------------------------------
    def subjects(self) -> list[str]:
        """Subjects (sXX) that have a processed-sequences folder."""
        return sorted(p.name for p in self.seqs_dir.iterdir() if p.is_dir())

    def sequences(self, subject: str) -> list[str]:
        d = self.seqs_dir / subject
        if not d.is_dir():
            raise ArcticError(f"subject folder {d} does not exist (subjects: {self.subjects()}); {_DOWNLOAD_HINT}")
        return sorted(p.stem for p in d.glob("*.npy"))

    def find(self, seq: str) -> list[str]:
        """Subjects that have sequence ``seq`` (the thesis does not say which subject it used)."""
        return [s for s in self.subjects() if (self.seqs_dir / s / f"{seq}.npy").is_file()]

    def seq_path(self, subject: str, seq: str) -> Path:
        return self.seqs_dir / subject / f"{seq}.npy"

    # -- loading ----------------------------------------------------------------------------------
    def load_raw(self, subject: str, seq: str) -> dict:
        """The processed sequence's dict (np.load(allow_pickle=True).item())."""
        p = self.seq_path(subject, seq)
        if not p.is_file():
            have = self.find(seq)
            hint = f" (subjects that have {seq}: {have})" if have else ""
            raise ArcticError(f"processed sequence {p} does not exist{hint}; {_DOWNLOAD_HINT}")
        try:
            obj = np.load(p, allow_pickle=True)
            data = obj.item() if isinstance(obj, np.ndarray) and obj.dtype == object else obj
        except Exception as e:  # noqa: BLE001  (corrupt / truncated download)
            raise ArcticError(f"{p}: cannot load as a pickled dict ({type(e).__name__}: {e})") from e
        if not isinstance(data, dict):
            raise ArcticError(f"{p}: expected a pickled dict, got {type(data).__name__}")
        return data

    def load(self, subject: str | None, seq: str, view: int = 0, stride: int = 1, *,
             require_images: bool = True, skip: int = SKIP_FRAMES) -> ArcticTake:
        """Load one sequence from one view (0 = egocentric).

        subject None: the first subject that has ``seq`` (see :meth:`find`). Frames ``skip ..
        T - skip - 1`` are kept (ARCTIC's first/last 10 frames skipped), every ``stride``-th.
        ``require_images``: raise if an image file is missing (else only noted in ``notes``).
        """
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        if subject is None:
            subs = self.find(seq)
            if not subs:
                raise ArcticError(f"no subject under {self.seqs_dir} has {seq}.npy; {_DOWNLOAD_HINT}")
            subject = subs[0]
        path = self.seq_path(subject, seq)
        data = self.load_raw(subject, seq)
        where = str(path)
        cam = _get(data, "cam_coord", where)
        d2 = _get(data, "2d", where)
        raw3 = {h: np.asarray(_get(cam, f"joints.{h}", f"{where}['cam_coord']"), np.float64) for h in ("left", "right")}
        raw2 = {h: np.asarray(_get(d2, f"joints.{h}", f"{where}['2d']"), np.float64) for h in ("left", "right")}
        for h in ("left", "right"):
            for name, a, D in (("cam_coord", raw3[h], 3), ("2d", raw2[h], 2)):
                if a.ndim != 4 or a.shape[2:] != (21, D):
                    raise ArcticError(f"{where}['{name}']['joints.{h}']: expected (T, views, 21, {D}), got {a.shape}")
        T_all, V = raw3["right"].shape[:2]
        for h in ("left", "right"):
            for name, a in (("cam_coord", raw3[h]), ("2d", raw2[h])):
                if a.shape[:2] != (T_all, V):
                    raise ArcticError(f"{where}['{name}']['joints.{h}'] has (T, views) {a.shape[:2]}, "
                                      f"expected {(T_all, V)} like cam_coord joints.right")
        if not 0 <= view < V:
            raise ArcticError(f"{where}: view {view} out of range (the sequence has {V} views)")
        if T_all <= 2 * skip:
            raise ArcticError(f"{where}: {T_all} frames, fewer than the {2 * skip} skipped at the ends")
        frames = np.arange(skip, T_all - skip, stride, dtype=np.int64)

        # misc.json
        misc = self.misc
        ms = _get(misc, subject, str(self.misc_path))
        mwhere = f"{self.misc_path}['{subject}']"
        ioi = int(_get(ms, "ioi_offset", mwhere))
        sizes = _get(ms, "image_size", mwhere)
        size = self._per_view(sizes, view, V, f"{mwhere}['image_size']")
        image_size = (int(size[0]), int(size[1]))
        notes: list[str] = []

        # camera
        if view == 0:
            params = _get(data, "params", where)
            K = np.asarray(_get(params, "K_ego", f"{where}['params']"), np.float64)
            if K.shape == (3, 3):
                K = np.broadcast_to(K, (T_all, 3, 3))
            if K.shape != (T_all, 3, 3):
                raise ArcticError(f"{where}['params']['K_ego']: expected ({T_all}, 3, 3), got {K.shape}")
            K = K[frames].copy()
            w2c = params.get("world2ego")
            if w2c is not None:
                w2c = np.asarray(w2c, np.float64)
                w2c = w2c[frames].copy() if w2c.shape == (T_all, 4, 4) else None
            if w2c is None:
                notes.append("params['world2ego'] absent or malformed: world2cam not loaded (not needed for camera-frame joints)")
        else:
            K = np.asarray(self._per_view(_get(ms, "intris_mat", mwhere), view, V, f"{mwhere}['intris_mat']"), np.float64)
            if K.shape != (3, 3):
                raise ArcticError(f"{mwhere}['intris_mat'][view {view}]: expected 3x3, got {K.shape}")
            w2c = ms.get("world2cam")
            w2c = (np.asarray(self._per_view(w2c, view, V, f"{mwhere}['world2cam']"), np.float64)
                   if w2c is not None else None)

        # joints, re-indexed
        def pick(a):
            a = a[frames, view]
            return mano_to_openpose(a, axis=-2) if self.joint_order == "mano" else a
        joints_cam = np.stack([pick(raw3["left"]), pick(raw3["right"])], axis=1)
        joints_px = np.stack([pick(raw2["left"]), pick(raw2["right"])], axis=1)

        # validity
        valid, source = self._validity(data, frames, view, T_all, V, where)
        valid &= np.isfinite(joints_cam).all(axis=(2, 3)) & np.isfinite(joints_px).all(axis=(2, 3))

        # images
        img_dir = None
        try:
            img_dir = self.images_dir / subject / seq / str(view)
        except ArcticError:
            if require_images:
                raise
            notes.append("images folder not found: image_paths point to a missing folder")
            img_dir = self.root / "images" / subject / seq / str(view)
        paths = np.array([str(img_dir / f"{int(f) + ioi:05d}.jpg") for f in frames], dtype=object)
        missing = [p for p in paths if not os.path.isfile(p)]
        if missing:
            msg = (f"{len(missing)} of {len(paths)} images missing, first {missing[0]} "
                   f"(image index = frame + ioi_offset {ioi})")
            if require_images:
                raise ArcticError(f"{msg}; {_DOWNLOAD_HINT}")
            notes.append(msg)

        return ArcticTake(name=f"{subject}/{seq}", subject=subject, seq=seq, object=object_of(seq), view=view,
                          joints_cam=joints_cam, joints_px=joints_px, valid=valid, K=K,
                          image_size=image_size, image_paths=paths, frame_indices=frames,
                          world2cam=w2c, ioi_offset=ioi, valid_source=source, notes=notes)

    @staticmethod
    def _per_view(lst, view: int, V: int, where: str):
        """Entry of a per-view list: 9 entries (all views) -> [view]; 8 (allocentric only) -> [view-1]."""
        n = len(lst)
        if n == V:
            return lst[view]
        if n == V - 1 and view >= 1:
            return lst[view - 1]
        raise ArcticError(f"{where}: {n} entries, cannot pick view {view} of a {V}-view sequence")

    @staticmethod
    def _validity(data: dict, frames: np.ndarray, view: int, T_all: int, V: int, where: str):
        """(T, 2) validity from the flags that exist: is_valid & left_valid / right_valid, looked up
        in cam_coord, then the top level, then params; each may be (T, V) or (T,)."""
        def find(key):
            for sec in ("cam_coord", None, "params"):
                d = data if sec is None else data.get(sec)
                if isinstance(d, dict) and key in d:
                    a = np.asarray(d[key])
                    if a.shape == (T_all, V):
                        a = a[:, view]
                    elif a.shape != (T_all,):
                        raise ArcticError(f"{where}['{sec or ''}']['{key}']: expected ({T_all}, {V}) or "
                                          f"({T_all},), got {a.shape}")
                    return a[frames].astype(np.float64) > 0.5, f"{sec + '.' if sec else ''}{key}"
            return None, None
        valid = np.ones((len(frames), 2), bool)
        used = []
        isv, s = find("is_valid")
        if isv is not None:
            valid &= isv[:, None]
            used.append(s)
        for h, key in ((0, "left_valid"), (1, "right_valid")):
            a, s = find(key)
            if a is not None:
                valid[:, h] &= a
                used.append(s)
        return valid, ("+".join(used) if used else "none (all frames with finite joints)")
