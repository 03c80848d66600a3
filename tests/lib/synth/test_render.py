"""Rendering synthetic takes (demoforge.lib.synth.render): the camera, and ground-truth joints marked visible
landing on hand pixels (segmentation and skin colour) with the rendered depth there matching the joints'
camera z within the flesh radius + a few mm. (The take layout: test_take.py; the skin look: test_hand_skin.py.)"""

from __future__ import annotations

import numpy as np
import pytest

import demoforge.lib  # noqa: F401  (EGL before mujoco)
import demoforge.schemas.synthetic  # noqa: F401
from demoforge.lib.perception.hand_model import HandStyle, hand_from_pinch
from demoforge.lib.synth import render as R
from tests.support.standin import STANDIN_XML, StandInDemo


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
