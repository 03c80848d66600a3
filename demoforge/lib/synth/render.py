"""Offscreen MuJoCo rendering of a task scene with two capsule hands, seen by the head camera.

Camera (the thesis's set-up: an RGB-D camera above the workspace, angled down at the table, where a
dual-arm robot's head camera sits): 640 x 480, fx = fy = 570.3422, cx = 319.5, cy = 239.5 (the
exact image centre in the pixel-centre convention, which is where MuJoCo puts the principal point),
at :data:`CAMERA_POS` = (0, -0.40, 0.90) m in the world (table) frame, looking at
:data:`CAMERA_TARGET` = (0, 0.25, 0) with no roll (chosen so that, over the scripted demos of all six
tasks, >= 98 % of hand joints and >= 94 % of object keypoints project into the image). ``T_world_camera`` maps OpenCV camera coordinates
(x right, y down, z forward) to the world. A MuJoCo camera looks along its -z with y up, so its
``xyaxes`` are (x_cv, -y_cv); its ``fovy`` = 2 atan(height / (2 fy)) makes the rendered image match
K exactly.

Depth: MuJoCo's depth buffer (reversed-Z, ``mjDEPTH_ZEROFAR``) is converted exactly as
``mujoco.Renderer`` does, which yields the distance along the camera's optical axis (the OpenCV z),
not the ray length; :func:`add_depth_noise` adds a realistic sensor model on top (0.0 = invalid).

Hands: ``hand_style="capsule"`` (default) draws the kinematic hand's capsules; ``"skin"`` adds a
palm, a forearm, a sleeve and nails (:mod:`demoforge.lib.synth.hand_skin`) on extra mocap bodies, the palm's
placed at the exact rigid fit of the palm joints. The joints, and so the ground truth, are the same
in both. (Skin is not the default: under its palm and forearm the depth at the wrist and thumb-base
anchors differs from what demoforge.lib.ingest.alignment's surface offset assumes; docs/results/issue-19-detection.md.)

Quaternions are scalar-first (MuJoCo's order) only inside this module, at the simulator boundary.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

import mujoco

from demoforge.lib.geometry import project_points
from demoforge.lib.perception.hand_model import (
    HandStyle, capsule_segments, hand_capsules, joint_radii, wrist_pose_from_joints,
)
from demoforge.lib.synth import hand_skin
from demoforge.lib.synth.hand_skin import (NAIL_SIZE, PARTS, forearm_pose, mesh_asset_xml, mesh_name, nail_poses,
                                           nail_rgba, skin_meshes)
from demoforge.lib.task_library.objects import SIM_ONLY_GROUP

WIDTH, HEIGHT = 640, 480
FX = FY = 570.3422
CX, CY = 319.5, 239.5
CAMERA_POS = (0.0, -0.40, 0.90)
CAMERA_TARGET = (0.0, 0.25, 0.0)
CAMERA_NAME = "demoforge_head_cam"
HAND_PREFIX = "demoforge_hand"
SIDES = ("left", "right")
#: Looks of the synthetic hands: "skin" (palm, forearm, sleeve) or "capsule" (the default; see docs/takes.md).
HAND_STYLES = ("skin", "capsule")
DEFAULT_HAND_STYLE = "capsule"


def _check_hand_style(hand_style: str) -> str:
    if hand_style not in HAND_STYLES:
        raise ValueError(f"hand_style must be one of {', '.join(HAND_STYLES)}, got {hand_style!r}")
    return hand_style


# --- camera --------------------------------------------------------------------------------------

def camera_K() -> np.ndarray:
    """3 x 3 intrinsics of the head camera."""
    return np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])


def camera_T_world_camera(pos=CAMERA_POS, target=CAMERA_TARGET) -> np.ndarray:
    """4 x 4 camera-to-world transform (OpenCV camera axes) of a camera at ``pos`` looking at ``target``
    with its image x axis horizontal (no roll)."""
    pos, target = np.asarray(pos, float), np.asarray(target, float)
    z = target - pos
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, pos
    return T


def camera_fovy_deg(fy: float = FY, height: int = HEIGHT) -> float:
    """MuJoCo's vertical field of view (degrees) that gives focal length ``fy`` at ``height`` rows."""
    return float(np.degrees(2.0 * np.arctan(height / (2.0 * fy))))


def camera_xml(T_world_camera: np.ndarray | None = None, fy: float = FY, height: int = HEIGHT,
               name: str = CAMERA_NAME) -> str:
    """The MJCF ``<camera>`` element for an OpenCV camera pose (MuJoCo camera: -z forward, y up)."""
    T = camera_T_world_camera() if T_world_camera is None else np.asarray(T_world_camera)
    x, y, p = T[:3, 0], -T[:3, 1], T[:3, 3]
    f = lambda v: " ".join(f"{c:.9g}" for c in v)  # noqa: E731
    return (f'<camera name="{name}" mode="fixed" pos="{f(p)}" xyaxes="{f(x)} {f(y)}" '
            f'fovy="{camera_fovy_deg(fy, height):.9g}"/>')


def world_to_camera(points: np.ndarray, T_world_camera: np.ndarray) -> np.ndarray:
    """World points (..., 3) to OpenCV camera coordinates (..., 3)."""
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    return (np.asarray(points) - t) @ R


def project(points_world: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray):
    """Pixel coordinates (..., 2) (OpenCV: pixel centres at integers) and camera z (...) of world points."""
    pc = world_to_camera(points_world, T_world_camera)
    return project_points(pc, K), pc[..., 2]


# --- a calibration board on the table --------------------------------------------------------------

BOARD_LIFT_M = 0.0005  # above the table top: drawn on it without z-fighting; 0.5 mm is below what calibration resolves


def board_xml(spec, png_path: str, origin_xy=(0.0, 0.0)) -> tuple[str, str]:
    """(asset, worldbody) MJCF of a printed ChArUco board (demoforge.lib.calibration.board.BoardSpec,
    its image at ``png_path``) lying face up on the table, centred at ``origin_xy``, its printed top
    edge towards +y: the pose demoforge.lib.calibration.board.T_world_board describes."""
    w, h = spec.size_m
    asset = (f'<texture name="demoforge_board_tex" type="2d" file="{png_path}"/>'
             f'<material name="demoforge_board_mat" texture="demoforge_board_tex" texrepeat="1 1" texuniform="false"/>')
    geom = (f'<geom name="demoforge_board" type="plane" pos="{origin_xy[0]:.9g} {origin_xy[1]:.9g} {BOARD_LIFT_M}" '
            f'size="{w / 2:.9g} {h / 2:.9g} 0.01" material="demoforge_board_mat" contype="0" conaffinity="0"/>')
    return asset, geom


# --- hands in MJCF -------------------------------------------------------------------------------

def _hand_body_names(side: str, n: int) -> list[str]:
    return [f"{HAND_PREFIX}_{side}_{i:02d}" for i in range(n)]


def _wrist_body_name(side: str, body: str = "hand") -> str:
    return f"{HAND_PREFIX}_{side}_wrist" if body == "hand" else f"{HAND_PREFIX}_{side}_forearm"


def _rgba(c) -> str:
    return " ".join(f"{x:.4g}" for x in c)


def hands_xml(styles: Sequence[HandStyle] = (HandStyle(), HandStyle()), hand_style: str = DEFAULT_HAND_STYLE) -> str:
    """Mocap bodies (one capsule each, no contacts) of both hands, for the scene's worldbody; with
    ``hand_style="skin"`` also one mocap body per hand carrying the palm, forearm and sleeve meshes
    (:func:`hands_assets_xml` defines them)."""
    _check_hand_style(hand_style)
    out = []
    for side, style in zip(SIDES, styles):
        caps = hand_capsules(style)
        rgba = _rgba(style.skin_rgba)
        for name, cap in zip(_hand_body_names(side, len(caps)), caps):
            out.append(
                f'<body name="{name}" mocap="true" pos="0 0 -5">'
                f'<geom name="{name}_geom" type="capsule" size="{cap.radius:.6g} 0.01" contype="0" '
                f'conaffinity="0" group="1" rgba="{rgba}" material="{HAND_PREFIX}_skin"/></body>'
            )
        if hand_style == "skin":
            for body in ("hand", "forearm"):
                wb = _wrist_body_name(side, body)
                geoms = "".join(
                    f'<geom name="{wb}_{part}" type="mesh" mesh="{mesh_name(HAND_PREFIX, side, part, style)}" '
                    f'contype="0" conaffinity="0" group="1" mass="0" '
                    f'rgba="{_rgba(style.skin_rgba if colour == "skin" else style.sleeve_rgba)}" '
                    f'material="{HAND_PREFIX}_{colour}"/>' for part, colour, b in PARTS if b == body)
                out.append(f'<body name="{wb}" mocap="true" pos="0 0 -5">{geoms}</body>')
            for k, size in enumerate(NAIL_SIZE * style.scale if hand_skin.NAILS else []):
                nb = f"{HAND_PREFIX}_{side}_nail{k}"
                out.append(f'<body name="{nb}" mocap="true" pos="0 0 -5"><geom name="{nb}_geom" type="ellipsoid" '
                           f'size="{size[0]:.6g} {size[1]:.6g} {size[2]:.6g}" contype="0" conaffinity="0" group="1" '
                           f'rgba="{_rgba(nail_rgba(style.skin_rgba))}" material="{HAND_PREFIX}_nail"/></body>')
    return "\n".join(out)


def hands_assets_xml(styles: Sequence[HandStyle] = (HandStyle(), HandStyle()),
                     hand_style: str = DEFAULT_HAND_STYLE) -> str:
    """The hands' materials and (skin look) meshes, for the scene's ``<asset>``."""
    _check_hand_style(hand_style)
    out = [f'<material name="{HAND_PREFIX}_skin" specular="0.15" shininess="0.2" reflectance="0"/>']
    if hand_style == "skin":
        out.append(f'<material name="{HAND_PREFIX}_sleeve" specular="0.05" shininess="0.05" reflectance="0"/>')
        out.append(f'<material name="{HAND_PREFIX}_nail" specular="0.5" shininess="0.7" reflectance="0"/>')
        seen = set()
        for side, style in zip(SIDES, styles):
            for part, mesh in skin_meshes(side, style).items():
                name = mesh_name(HAND_PREFIX, side, part, style)
                if name not in seen:
                    seen.add(name)
                    out.append(mesh_asset_xml(name, mesh))
    return "\n".join(out)


def extra_worldbody_xml(styles: Sequence[HandStyle] = (HandStyle(), HandStyle()),
                        T_world_camera: np.ndarray | None = None, hand_style: str = DEFAULT_HAND_STYLE) -> str:
    """Everything this module adds to a task scene's worldbody: the head camera and both hands."""
    return camera_xml(T_world_camera) + "\n" + hands_xml(styles, hand_style)


def _insert(xml: str, closing: str, text: str) -> str:
    i = xml.rfind(closing)
    if i < 0:
        raise ValueError(f"scene MJCF has no {closing}")
    return xml[:i] + text + "\n" + xml[i:]


def with_camera_and_hands(scene_xml: str, styles: Sequence[HandStyle],
                          T_world_camera: np.ndarray | None = None, hand_style: str = DEFAULT_HAND_STYLE) -> str:
    """Add the head camera, the hands and their assets to an MJCF scene unless already there."""
    xml = scene_xml
    if f'name="{CAMERA_NAME}"' not in xml:
        xml = _insert(xml, "</worldbody>", camera_xml(T_world_camera))
    if f'{HAND_PREFIX}_left_00' not in xml:
        xml = _insert(xml, "</worldbody>", hands_xml(styles, hand_style))
    if f'name="{HAND_PREFIX}_skin"' not in xml:
        assets = hands_assets_xml(styles, hand_style)
        if "</asset>" in xml:
            xml = _insert(xml, "</asset>", assets)
        else:
            xml = _insert(xml, "</worldbody>", "")  # validate it has a worldbody
            i = xml.find("<worldbody")
            xml = xml[:i] + f"<asset>{assets}</asset>\n" + xml[i:]
    return xml


def _quat_z_to(d: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions (n, 4) rotating +z onto the unit vectors d (n, 3)."""
    w = 1.0 + d[:, 2]
    q = np.stack([w, -d[:, 1], d[:, 0], np.zeros(len(d))], axis=-1)
    flip = w < 1e-9
    q[flip] = [0.0, 1.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions (4,) / (n, 4) of rotation matrices (3, 3) / (n, 3, 3)."""
    from scipy.spatial.transform import Rotation

    return np.roll(Rotation.from_matrix(R).as_quat(), 1, axis=-1)   # scalar-last -> scalar-first


# --- depth sensor model --------------------------------------------------------------------------

def add_depth_noise(depth: np.ndarray, rng: np.random.Generator, sigma0: float = 0.001,
                    sigma2: float = 0.002, n_holes: tuple[int, int] = (2, 8),
                    edge_jump: float = 0.03, edge_dropout: float = 0.6) -> np.ndarray:
    """A structured-light/ToF-like depth map from an exact one (float32 m; 0.0 = invalid).

    Gaussian noise with sigma = sigma0 + sigma2 z^2, a few random invalid blobs (ellipses of 3-15 px)
    and invalid pixels at depth discontinuities (neighbour differs by more than ``edge_jump`` m),
    each edge pixel dropped with probability ``edge_dropout``.
    """
    import cv2

    d = depth.astype(np.float32, copy=True)
    valid = d > 0
    noise = rng.standard_normal(d.shape).astype(np.float32)
    d[valid] += (sigma0 + sigma2 * d[valid] ** 2) * noise[valid]
    # depth edges
    pad = np.pad(depth, 1, mode="edge")
    jump = np.zeros(depth.shape, bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        jump |= np.abs(pad[dy:dy + depth.shape[0], dx:dx + depth.shape[1]] - depth) > edge_jump
    drop = jump & (rng.random(depth.shape) < edge_dropout)
    # blobs
    mask = np.zeros(depth.shape, np.uint8)
    h, w = depth.shape
    for _ in range(int(rng.integers(n_holes[0], n_holes[1] + 1))):
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        ax = (int(rng.integers(3, 16)), int(rng.integers(3, 16)))
        cv2.ellipse(mask, c, ax, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    d[drop | (mask > 0) | ~valid] = 0.0
    d[d < 0] = 0.0
    return d


# --- renderer ------------------------------------------------------------------------------------

@dataclass
class Frame:
    rgb: np.ndarray            # (H, W, 3) uint8
    depth: np.ndarray          # (H, W) float32, m along the camera z; exact (no noise)
    segmentation: np.ndarray | None = None  # (H, W) int32 geom id, -1 = background


class SceneRenderer:
    """Renders a MuJoCo scene with two hands from the head camera.

    scene_xml: an MJCF string (e.g. ``task.scene_xml(placement)``); the head camera and the hand
    mocap bodies are appended to its worldbody unless already present (pass
    :func:`extra_worldbody_xml` as the task's ``extra_worldbody`` to put them there yourself).
    object_names: bodies with a free joint whose pose :meth:`render` sets, in this order.
    Shadows, reflections and the skybox are off (speed; a head camera over a table sees no sky).
    hand_style: "skin" (palm, forearm, sleeve) or "capsule"; it must match the scene's hands when
    ``scene_xml`` already has them.
    """

    def __init__(self, scene_xml: str, object_names: Sequence[str] = (),
                 styles: Sequence[HandStyle] = (HandStyle(), HandStyle()),
                 width: int = WIDTH, height: int = HEIGHT,
                 T_world_camera: np.ndarray | None = None, multisamples: int = 0,
                 blur_sigma: float = 0.0, hand_style: str = DEFAULT_HAND_STYLE):
        self.blur_sigma = float(blur_sigma)
        self.styles = tuple(styles)
        self.hand_style = _check_hand_style(hand_style)
        self.width, self.height = width, height
        self.T_world_camera = camera_T_world_camera() if T_world_camera is None else np.asarray(T_world_camera)
        xml = with_camera_and_hands(scene_xml, self.styles, self.T_world_camera, self.hand_style)
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.model.vis.global_.offwidth = max(self.model.vis.global_.offwidth, width)
        self.model.vis.global_.offheight = max(self.model.vis.global_.offheight, height)
        # No multisampling by default: 3-4x faster with the software (EGL/llvmpipe) renderer; a mild
        # blur (``blur_sigma``, px) stands in for anti-aliasing and lens blur.
        self.model.vis.quality.offsamples = int(multisamples)
        self.data = mujoco.MjData(self.model)
        self.cam_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME)
        # objects: free joints' qpos addresses
        self.object_names = list(object_names)
        self._obj_qpos = []
        for name in self.object_names:
            bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)
            if bid < 0:
                raise ValueError(f"scene has no body named {name!r}")
            jid = self.model.body_jntadr[bid]
            if jid < 0 or self.model.jnt_type[jid] != mujoco.mjtJoint.mjJNT_FREE:
                raise ValueError(f"body {name!r} has no free joint")
            self._obj_qpos.append(int(self.model.jnt_qposadr[jid]))
        # hands: mocap ids and geom ids per side
        self._caps = [hand_capsules(s) for s in self.styles]
        self._mocap, self._geoms = [], []
        for side, caps in zip(SIDES, self._caps):
            names = _hand_body_names(side, len(caps))
            bids = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, n) for n in names]
            self._mocap.append(np.array([self.model.body_mocapid[b] for b in bids]))
            self._geoms.append(np.array([self.model.body_geomadr[b] for b in bids]))
        # skin look: one mocap body per hand with the palm/forearm/sleeve meshes
        self._wrist_mocap, self._forearm_mocap, self._nail_mocap = [], [], []
        self._mask_geoms = list(self._geoms)
        for h, side in enumerate(SIDES):
            bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, _wrist_body_name(side))
            fid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, _wrist_body_name(side, "forearm"))
            if (bid >= 0 and fid >= 0) != (self.hand_style == "skin"):
                raise ValueError(f"scene's hands do not have the {self.hand_style!r} look (hand_style)")
            if bid >= 0:
                self._wrist_mocap.append(int(self.model.body_mocapid[bid]))
                self._forearm_mocap.append(int(self.model.body_mocapid[fid]))
                # palm and forearm are hand pixels; the sleeve (the forearm body's last geom) is cloth
                palm = self.model.body_geomadr[bid]
                forearm = self.model.body_geomadr[fid]
                nails = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, f"{HAND_PREFIX}_{side}_nail{k}")
                         for k in range(5)]
                nails = [b for b in nails if b >= 0]
                self._nail_mocap.append(np.array([self.model.body_mocapid[b] for b in nails], int))
                self._mask_geoms[h] = np.concatenate([self._geoms[h], [palm, forearm],
                                                      [self.model.body_geomadr[b] for b in nails]]).astype(int)
        self.hand_geom_ids = np.concatenate(self._mask_geoms)
        self.joint_radii = np.stack([joint_radii(s) for s in self.styles])  # (2, 21)

        self._renderer = mujoco.Renderer(self.model, height=height, width=width)
        self._option = mujoco.MjvOption()

        self._option.geomgroup[SIM_ONLY_GROUP] = 0  # the un-simulated liquid is not drawn
        scn = self._renderer.scene
        scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        scn.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False
        self._rgb = np.empty((height, width, 3), np.uint8)
        self._zbuf = np.empty((height, width), np.float32)

    # -- state ----------------------------------------------------------------------------------
    def set_state(self, object_poses: np.ndarray | None = None, hand_joints: np.ndarray | None = None,
                  hand_present: Sequence[bool] = (True, True)) -> None:
        """Object poses (n_objects, 4, 4) world and hand joints (2, 21, 3) world; then mj_forward."""
        m, d = self.model, self.data
        if object_poses is not None:
            from scipy.spatial.transform import Rotation

            poses = np.asarray(object_poses, float)
            q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()          # scalar-last
            for adr, p, qq in zip(self._obj_qpos, poses, q):
                d.qpos[adr:adr + 3] = p[:3, 3]
                d.qpos[adr + 3:adr + 7] = [qq[3], qq[0], qq[1], qq[2]]   # scalar-first at the boundary
        if hand_joints is not None:
            for h in range(2):
                if not hand_present[h]:
                    d.mocap_pos[self._mocap[h]] = [0.0, 0.0, -5.0]
                    if self._wrist_mocap:
                        d.mocap_pos[[self._wrist_mocap[h], self._forearm_mocap[h]]] = [0.0, 0.0, -5.0]
                        d.mocap_pos[self._nail_mocap[h]] = [0.0, 0.0, -5.0]
                    continue
                if self._wrist_mocap:
                    W = wrist_pose_from_joints(np.asarray(hand_joints[h], float), SIDES[h], self.styles[h])
                    F = forearm_pose(W, h)
                    d.mocap_pos[self._wrist_mocap[h]] = W[:3, 3]
                    d.mocap_quat[self._wrist_mocap[h]] = _quat_from_matrix(W[:3, :3])
                    d.mocap_pos[self._forearm_mocap[h]] = F[:3, 3]
                    d.mocap_quat[self._forearm_mocap[h]] = _quat_from_matrix(F[:3, :3])
                    if len(self._nail_mocap[h]):
                        N = nail_poses(hand_joints[h], W, h, self.styles[h])
                        d.mocap_pos[self._nail_mocap[h]] = N[:, :3, 3]
                        d.mocap_quat[self._nail_mocap[h]] = _quat_from_matrix(N[:, :3, :3])
                seg = capsule_segments(np.asarray(hand_joints[h], float), self.styles[h])  # (n, 2, 3)
                a, b = seg[:, 0], seg[:, 1]
                v = b - a
                L = np.linalg.norm(v, axis=-1)
                dirs = v / np.maximum(L, 1e-12)[:, None]
                d.mocap_pos[self._mocap[h]] = 0.5 * (a + b)
                d.mocap_quat[self._mocap[h]] = _quat_z_to(dirs)
                m.geom_size[self._geoms[h], 1] = np.maximum(0.5 * L, 1e-6)
        mujoco.mj_forward(m, d)

    # -- rendering ------------------------------------------------------------------------------
    def render(self, segmentation: bool = False) -> Frame:
        """RGB and exact depth (0 where nothing is hit, i.e. beyond the far plane) of the current state.

        Two passes of ``mujoco.Renderer``: colour, then depth (its depth pass renders with flat ID
        colours and converts the reversed-Z buffer to metric depth along the optical axis; measured
        exact to 1e-7 m on a plane, where reading the depth of the shaded pass is off by 0.5 mm).
        """
        r = self._renderer
        r.update_scene(self.data, camera=self.cam_id, scene_option=self._option)
        rgb = r.render(out=self._rgb).copy()
        if self.blur_sigma > 0:
            import cv2

            rgb = cv2.GaussianBlur(rgb, (0, 0), self.blur_sigma)
        r.enable_depth_rendering()
        depth = r.render(out=self._zbuf).copy()
        r.disable_depth_rendering()
        far = self.model.vis.map.zfar * self.model.stat.extent
        depth[~np.isfinite(depth) | (depth >= far * 0.999)] = 0.0
        seg = None
        if segmentation:
            r.enable_segmentation_rendering()
            s = r.render()
            r.disable_segmentation_rendering()
            seg = np.where(s[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), s[..., 0], -1).astype(np.int32)
        return Frame(rgb=rgb, depth=depth, segmentation=seg)

    def render_state(self, object_poses=None, hand_joints=None, hand_present=(True, True),
                     segmentation: bool = False) -> Frame:
        self.set_state(object_poses, hand_joints, hand_present)
        return self.render(segmentation=segmentation)

    def hand_mask(self, seg: np.ndarray, side: int | None = None) -> np.ndarray:
        """Pixels showing a hand (capsules, and the palm and forearm of the skin look; of one side, or
        either) from a segmentation image."""
        ids = self.hand_geom_ids if side is None else self._mask_geoms[side]
        return np.isin(seg, ids)

    def close(self) -> None:
        self._renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# --- visibility ----------------------------------------------------------------------------------

def joint_visibility(joints_world: np.ndarray, depth: np.ndarray, K: np.ndarray,
                     T_world_camera: np.ndarray, radii: np.ndarray, margin: float = 0.01):
    """Per-joint visibility by a depth test against the exact rendered depth.

    joints_world (..., 21, 3); radii broadcastable to (..., 21): the flesh radius around each joint.
    A joint is visible when it projects inside the image, lies in front of the camera, and the
    rendered depth at its (rounded) pixel is not more than radius + margin in front of the joint's
    camera z. Returns (visible (..., 21) bool, px (..., 21, 2), camera points (..., 21, 3)).
    """
    pc = world_to_camera(joints_world, T_world_camera)
    z = pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        px = (pc[..., :2] / z[..., None]) * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    h, w = depth.shape
    ui = np.rint(np.nan_to_num(px[..., 0], nan=-1)).astype(int)
    vi = np.rint(np.nan_to_num(px[..., 1], nan=-1)).astype(int)
    inside = (z > 0) & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    dz = depth[np.clip(vi, 0, h - 1), np.clip(ui, 0, w - 1)]
    occluded = (dz > 0) & (dz < z - (np.asarray(radii) + margin))
    return inside & ~occluded, px, pc


__all__ = [
    "WIDTH", "HEIGHT", "FX", "FY", "CX", "CY", "CAMERA_POS", "CAMERA_TARGET", "CAMERA_NAME",
    "board_xml", "camera_K", "camera_T_world_camera", "camera_fovy_deg", "camera_xml", "world_to_camera", "project",
    "HAND_STYLES", "DEFAULT_HAND_STYLE", "hands_xml", "hands_assets_xml", "extra_worldbody_xml", "with_camera_and_hands", "add_depth_noise", "Frame",
    "SceneRenderer", "joint_visibility",
]

