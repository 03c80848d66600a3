"""Synthetic takes: rendering, visibility, the take layout and its ground truth.

Renders one short take (a few frames) with the real task library when it is importable, and a
minimal stand-in scene/demo otherwise (both when the library is there). Checks that ground-truth
joints marked visible land on hand pixels (segmentation and skin colour), that the rendered depth
there matches the joints' camera z within the flesh radius + a few mm, that camera.json round-trips,
that every GT table validates and reads back, and that the annotated 2D object keypoints are the
projections of the world keypoints.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import demoforge.lib  # noqa: F401  (EGL before mujoco)
import demoforge.schemas.synthetic  # noqa: F401
from demoforge.lib.perception.hand_model import HandStyle, hand_from_pinch
from demoforge.lib.synth import render as R
from demoforge.lib.synth import take as TK
from demoforge.schemas.core import read_table_file, validate
from tests.support.standin import STANDIN_XML, StandInDemo


def _real_task():
    from demoforge.lib.task_library import TASK_NAMES  # a broken task library is an error here, not a skip

    return "pouring" if "pouring" in TASK_NAMES else TASK_NAMES[0]


@pytest.fixture(scope="module")
def standin_take(tmp_path_factory):
    out = tmp_path_factory.mktemp("standin_take")
    calls = []
    summary = TK.write_take(
        out, task_name="standin", seed=3, mirror=False, scene_xml=STANDIN_XML,
        object_names=["cup", "bowl"], keypoint_names=[f"kp{i}" for i in range(11)],
        demo=StandInDemo(6), progress=lambda d, t: calls.append((d, t)),
    )
    return out, summary, calls


@pytest.fixture(scope="module")
def real_take(tmp_path_factory):
    name = _real_task()
    out = tmp_path_factory.mktemp("real_take")
    summary = TK.generate_take(name, seed=1, mirror=False, out_dir=out, max_frames=40)
    return out, summary, name


# --- camera -------------------------------------------------------------------------------------

def test_camera_pose_and_fov():
    K = R.camera_K()
    T = R.camera_T_world_camera()
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)
    # optical axis hits the target; image x horizontal; image y points down in the world
    uv, z = R.project(np.array(R.CAMERA_TARGET), K, T)
    assert np.allclose(uv, [K[0, 2], K[1, 2]], atol=1e-9) and z > 0
    assert abs(T[2, 0]) < 1e-12 and T[2, 1] < 0
    assert np.isclose(240.0 / np.tan(np.radians(R.camera_fovy_deg()) / 2), R.FY)


def test_rendered_depth_matches_K_and_pose():
    """A table point back-projected from rendered depth lands on the table plane (z = 0)."""
    r = R.SceneRenderer(STANDIN_XML, ["cup", "bowl"])
    try:
        fr = r.render_state(StandInDemo(2).object_poses[0], None, segmentation=True)
        import mujoco

        table = mujoco.mj_name2id(r.model, mujoco.mjtObj.mjOBJ_GEOM, "table")
        v, u = np.nonzero(fr.segmentation == table)
        d = fr.depth[v, u]
        pc = np.linalg.solve(R.camera_K(), np.stack([u, v, np.ones_like(u)]).astype(float)) * d
        T = R.camera_T_world_camera()
        pw = T[:3, :3] @ pc + T[:3, 3:4]
        assert np.percentile(np.abs(pw[2]), 99) < 1e-4   # exact depth and exact K/pose
        # the cup's top centre projects where the cup is rendered
        uv, _ = R.project(np.array([0.15, 0.30, 0.10]), R.camera_K(), T)
        cup_geom = r.model.body_geomadr[mujoco.mj_name2id(r.model, mujoco.mjtObj.mjOBJ_BODY, "cup")]
        assert fr.segmentation[int(round(uv[1])) + 2, int(round(uv[0]))] == cup_geom
    finally:
        r.close()


# --- visibility, skin pixels, depth ------------------------------------------------------------

def _styles_of(out: Path) -> list[HandStyle]:
    st = json.loads((out / "take.json").read_text())["hand_styles"]
    return [HandStyle(**{**st[s], "skin_rgba": tuple(st[s]["skin_rgba"])}) for s in ("left", "right")]


@pytest.mark.parametrize("hand_style", ["capsule", "skin"])
def test_visibility_against_segmentation_and_exact_depth(hand_style):
    """Joints marked visible lie on their own hand's pixels and the exact depth there is the flesh."""
    demo = StandInDemo(5)
    styles = (HandStyle(), HandStyle(scale=0.95, spread=1.2))
    K, T = R.camera_K(), R.camera_T_world_camera()
    J = np.stack([hand_from_pinch(demo.pinch_poses[:, h], demo.aperture[:, h], h, styles[h])[0]
                  for h in range(2)], axis=1)
    r = R.SceneRenderer(STANDIN_XML, ["cup", "bowl"], styles, hand_style=hand_style)
    hits = n_vis = n_all = 0
    excess = []   # (z - depth) - r at visible joints, m: how far in front of the flesh the surface is
    try:
        for t in range(len(J)):
            fr = r.render_state(demo.object_poses[t], J[t], segmentation=True)
            vis, px, pc = R.joint_visibility(J[t], fr.depth, K, T, r.joint_radii)
            n_all += vis.size
            for h in range(2):
                mask = r.hand_mask(fr.segmentation, h)
                for j in np.nonzero(vis[h])[0]:
                    u, v = int(round(px[h, j, 0])), int(round(px[h, j, 1]))
                    n_vis += 1
                    hits += bool(mask[v, u])
                    excess.append(pc[h, j, 2] - fr.depth[v, u] - r.joint_radii[h, j])
    finally:
        r.close()
    excess = np.array(excess)
    within3 = float(np.mean(np.abs(excess) <= 0.003))
    print(f"visible {n_vis}/{n_all}; on own-hand pixels {hits / n_vis:.3f}; depth within r+3mm {within3:.3f}; "
          f"(z - depth - r) median {np.median(excess) * 1e3:.1f} mm, p95 {np.percentile(excess, 95) * 1e3:.1f} mm, "
          f"min {excess.min() * 1e3:.1f} mm")
    # the skin look's palm and forearm hide more joints (this stand-in's forearms run back towards
    # the camera) and its palm is a slab a few mm thicker over the knuckles than the capsules
    assert n_vis / n_all > (0.5 if hand_style == "capsule" else 0.2)
    assert hits / n_vis > 0.95
    # The surface seen at a visible joint is its own flesh: never behind the joint's far side, and
    # at most 1 cm (the visibility tolerance) + 1 mm further in front than the flesh radius. At flexed
    # knuckles seen obliquely the union of two capsules puts the surface up to ~r/cos in front.
    assert excess.min() > -2 * r.joint_radii.max()
    assert excess.max() <= 0.011
    assert np.percentile(excess, 95) < 0.009
    if hand_style == "capsule":
        assert within3 > 0.5


def _check_take(out: Path, summary, n_check: int = 4):
    """Layout, camera.json, GT tables, annotations, and skin/depth at visible joints in the files."""
    import cv2

    take = json.loads((out / "take.json").read_text())
    n = take["n_frames"]
    assert n == summary.n_frames and take["detector_provenance"] == "ground truth (synthetic)"
    assert len(list((out / "rgb").glob("*.png"))) == n and len(list((out / "depth").glob("*.npy"))) == n
    assert (out / "rgb.mp4").stat().st_size > 0
    cap = cv2.VideoCapture(str(out / "rgb.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == n
    cap.release()

    cam = json.loads((out / "camera.json").read_text())
    assert np.allclose(cam["K"], R.camera_K()) and np.allclose(cam["T_world_camera"], R.camera_T_world_camera())
    assert (cam["width"], cam["height"], cam["fps"], cam["depth_unit"]) == (640, 480, 30.0, "m")

    tables = {}
    for name in demoforge.schemas.synthetic.GT_TABLES:
        t = read_table_file(name, out / "ground_truth" / f"{name}.parquet")
        validate(name, t)
        tables[name] = t.to_pydict()
    hj = tables["gt_hand_joints"]
    assert len(hj["frame"]) == 2 * n and all(hj["present"])
    kp = tables["gt_object_keypoints"]
    assert len(kp["frame"]) == n

    # annotations: 2D keypoints are the projections of the world keypoints of frame 0
    ann = json.loads((out / "annotations.json").read_text())
    uv, _ = R.project(np.array(kp["keypoints_world"][0]), np.array(cam["K"]), np.array(cam["T_world_camera"]))
    assert np.allclose(ann["object_keypoints_2d"]["uv"], uv, atol=1e-9)
    assert len(ann["object_keypoints_2d"]["names"]) == 11
    gr = tables["gt_gripper"]
    for side in ("left", "right"):
        closed = np.array([c for c, h in zip(gr["closed"], gr["hand"]) if h == side])
        assert ann["gripper_closed_ranges"][side] == TK.closed_ranges(closed)

    # the thesis mapping of the GT joints gives back the GT gripper pose
    from demoforge.lib.geometry import transform_to_pose8
    from demoforge.lib.perception.hand_model import pinch_from_joints

    Tp, ap = pinch_from_joints(np.array(hj["joints_world"]))
    p8 = transform_to_pose8(Tp, np.array(gr["pose"])[:, 7])
    assert np.allclose(p8[:, :3], np.array(gr["pose"])[:, :3], atol=1e-9)
    assert np.allclose(np.abs((p8[:, 3:7] * np.array(gr["pose"])[:, 3:7]).sum(-1)), 1.0, atol=1e-9)
    # ... and its aperture, up to the hand model's clip at 0.14 m x the hand's scale (hand_from_pinch)
    cap = np.array([0.14 * _styles_of(out)[("left", "right").index(h)].scale for h in gr["hand"]])
    assert np.allclose(ap, np.minimum(gr["aperture"], cap), atol=1e-9)

    # visible joints on skin-coloured pixels of the PNGs; noisy depth there near the flesh
    styles = _styles_of(out)
    from demoforge.lib.perception.hand_model import joint_radii

    skin_hits = depth_hits = n_vis = n_all = 0
    check = set(np.linspace(0, n - 1, n_check).round().astype(int).tolist())
    for i, f in enumerate(hj["frame"]):
        if f not in check:
            continue
        h = 0 if hj["hand"][i] == "left" else 1
        rgb = cv2.imread(str(out / "rgb" / f"{f:06d}.png"))[..., ::-1].astype(float) / 255.0
        depth = np.load(out / "depth" / f"{f:06d}.npy")
        assert depth.dtype == np.float32 and depth.shape == (480, 640)
        vis, px = np.array(hj["visible"][i]), np.array(hj["joints_px"][i])
        zc = np.array(hj["joints_camera"][i])[:, 2]
        radii = joint_radii(styles[h])
        skin = np.array(styles[h].skin_rgba[:3])
        from demoforge.lib.synth.hand_skin import nail_rgba

        nail = np.array(nail_rgba(styles[h].skin_rgba)[:3])      # a fingertip joint may be seen on its nail
        n_all += 21
        for j in np.nonzero(vis)[0]:
            u, v = int(round(px[j, 0])), int(round(px[j, 1]))
            n_vis += 1
            c = rgb[v, u]
            # shaded skin keeps the skin's chromaticity
            chroma = c / max(c.sum(), 1e-6)
            skin_hits += bool(min(np.abs(chroma - skin / skin.sum()).max(), np.abs(chroma - nail / nail.sum()).max()) < 0.05)
            d = depth[v, u]
            depth_hits += bool(d == 0 or abs(d - zc[j]) <= radii[j] + 0.005 + 3 * (0.001 + 0.002 * d * d))
    print(f"{out.name}: visible {n_vis}/{n_all}; skin-coloured {skin_hits / n_vis:.3f}; "
          f"noisy depth ok {depth_hits / n_vis:.3f}; {summary.frames_per_second:.1f} frames/s")
    # the rest is self-occluded (a head camera sees the backs of hands); the skin look's palm and
    # forearm hide more (the stand-in's forearms run back towards the camera, over the hands)
    assert n_vis / n_all > (0.3 if take.get("hand_style") == "capsule" else 0.15)
    assert skin_hits / n_vis > 0.9
    assert depth_hits / n_vis > 0.95


def test_standin_take(standin_take):
    out, summary, calls = standin_take
    assert calls == [(i + 1, 6) for i in range(6)]
    _check_take(out, summary)
    segs = read_table_file("gt_segments", out / "ground_truth" / "gt_segments.parquet").to_pydict()
    assert segs["object"] == ["bowl", "cup", None] and segs["hand"] == ["left", "right", "right"]


def test_take_write_error_surfaces(tmp_path, monkeypatch):
    """Frames are written on a background thread: a failing write must still stop the take with that
    error (and no progress past the last frame written), not vanish in the thread."""
    import cv2

    real_imwrite = cv2.imwrite

    def flaky_imwrite(path, img, *args):
        if path.endswith("000003.png"):
            raise OSError("disk full (injected)")
        return real_imwrite(path, img, *args)

    monkeypatch.setattr(cv2, "imwrite", flaky_imwrite)
    calls = []
    with pytest.raises(OSError, match="disk full"):
        TK.write_take(tmp_path / "t", task_name="standin", seed=3, mirror=False, scene_xml=STANDIN_XML,
                      object_names=["cup", "bowl"], keypoint_names=[f"kp{i}" for i in range(11)],
                      demo=StandInDemo(8), progress=lambda d, t: calls.append((d, t)))
    assert calls == [(i + 1, 8) for i in range(3)]
    assert sorted(p.name for p in (tmp_path / "t" / "rgb").iterdir()) == [f"{i:06d}.png" for i in range(3)]


def test_real_task_take(real_take):
    out, summary, name = real_take
    _check_take(out, summary)
    # everything of interest is in view: all object keypoints and nearly all hand joints
    kp = read_table_file("gt_object_keypoints", out / "ground_truth" / "gt_object_keypoints.parquet").to_pydict()
    px = np.array(kp["keypoints_px"])
    assert ((px[..., 0] >= 0) & (px[..., 0] < 640) & (px[..., 1] >= 0) & (px[..., 1] < 480)).all()


# --- the skin look ------------------------------------------------------------------------------

def test_skinned_hand_is_bound_to_the_kinematic_joints():
    """The skin look's bodies sit exactly on the kinematic hand: the palm body's pose maps the
    hand-local palm joints onto the posed joints, every capsule spans its two joints, and the
    forearm starts at the wrist joint."""
    import mujoco

    from demoforge.lib.perception.hand_model import (
        PALM_JOINTS, capsule_segments, hand_capsules, palm_local, sample_style,
    )

    demo = StandInDemo(4)
    rng = np.random.default_rng(5)
    styles = (sample_style(rng), sample_style(rng))
    J = np.stack([hand_from_pinch(demo.pinch_poses[:, h], demo.aperture[:, h], h, styles[h])[0]
                  for h in range(2)], axis=1)
    r = R.SceneRenderer(STANDIN_XML, ["cup", "bowl"], styles, hand_style="skin")
    try:
        for t in range(len(J)):
            r.set_state(demo.object_poses[t], J[t])
            m, d = r.model, r.data
            for h, side in enumerate(("left", "right")):
                bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{R.HAND_PREFIX}_{side}_wrist")
                Rw, pw = d.xmat[bid].reshape(3, 3), d.xpos[bid]
                assert np.allclose(palm_local(side, styles[h]) @ Rw.T + pw, J[t, h, list(PALM_JOINTS)], atol=1e-9)
                fid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{R.HAND_PREFIX}_{side}_forearm")
                assert np.allclose(d.xpos[fid], J[t, h, 0], atol=1e-12)
                seg = capsule_segments(J[t, h], styles[h])
                g = r._geoms[h]
                axis = d.geom_xmat[g].reshape(-1, 3, 3)[:, :, 2]
                half = m.geom_size[g, 1][:, None]
                assert np.allclose(d.geom_xpos[g] - half * axis, seg[:, 0], atol=1e-9)
                assert np.allclose(d.geom_xpos[g] + half * axis, seg[:, 1], atol=1e-9)
                # each nail lies on the back of its distal phalanx, just outside the flesh
                from demoforge.lib.synth.hand_skin import NAIL_JOINTS

                for k, (a, b) in enumerate(NAIL_JOINTS):
                    nid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{R.HAND_PREFIX}_{side}_nail{k}")
                    p, u = d.xpos[nid] - J[t, h, a], J[t, h, b] - J[t, h, a]
                    along = p @ u / (u @ u)
                    radial = np.linalg.norm(p - along * u)
                    r_dist = [c.radius for c in hand_capsules(styles[h]) if (c.a, c.b) == (a, b)][0]
                    assert 0.5 < along < 1.0 and r_dist - 0.001 < radial < r_dist
    finally:
        r.close()


def test_hand_style_changes_the_pixels_not_the_ground_truth(tmp_path):
    """A take rendered with the skin look and with the older capsule look has the same ground truth
    joints; the skin look draws more skin (palm, forearm) and a sleeve."""
    import cv2

    kw = dict(task_name="standin", seed=4, mirror=False, scene_xml=STANDIN_XML, object_names=["cup", "bowl"],
              keypoint_names=[f"kp{i}" for i in range(11)], video=False)
    TK.write_take(tmp_path / "skin", demo=StandInDemo(3), hand_style="skin", **kw)
    TK.write_take(tmp_path / "capsule", demo=StandInDemo(3), hand_style="capsule", **kw)
    gt = {k: read_table_file("gt_hand_joints", tmp_path / k / "ground_truth" / "gt_hand_joints.parquet").to_pydict()
          for k in ("skin", "capsule")}
    assert np.array_equal(np.array(gt["skin"]["joints_world"]), np.array(gt["capsule"]["joints_world"]))
    assert np.array_equal(np.array(gt["skin"]["joints_px"]), np.array(gt["capsule"]["joints_px"]))
    for k in ("skin", "capsule"):
        assert json.loads((tmp_path / k / "take.json").read_text())["hand_style"] == k
    a = cv2.imread(str(tmp_path / "skin" / "rgb" / "000001.png")).astype(int)
    b = cv2.imread(str(tmp_path / "capsule" / "rgb" / "000001.png")).astype(int)
    assert (np.abs(a - b).sum(-1) > 30).mean() > 0.01      # a forearm and a sleeve are >1 % of the image
    with pytest.raises(ValueError, match="hand_style"):
        R.SceneRenderer(STANDIN_XML, ["cup", "bowl"], hand_style="mesh")


def test_skin_tones_vary_per_take():
    """At least three skin tones (and several sleeve colours) over the default seeds."""
    tones = {tuple(np.round(TK.hand_styles_for(s)[0].skin_rgba[:3], 1)) for s in range(12)}
    sleeves = {TK.hand_styles_for(s)[0].sleeve_rgba for s in range(12)}
    assert len(tones) >= 3 and len(sleeves) >= 3
