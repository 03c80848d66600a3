"""Rendering (demoforge.lib.sim.render): the pinhole camera draws points where K projects them."""

from __future__ import annotations

import numpy as np

from tests.support.camera import look_at


def test_pinhole_camera_draws_points_where_k_projects_them():
    """A MuJoCo scene camera set from K and T_world_camera draws small spheres at the pixels the
    pinhole model predicts (off-centre principal point, different fx and fy)."""
    import mujoco

    from demoforge.lib.sim.render import pinhole_gl_camera

    pts = np.array([[0.1, 0.2, 0.05], [-0.15, 0.35, 0.0], [0.05, 0.05, 0.1]])
    colors = ["1 0 0 1", "0 1 0 1", "0 0 1 1"]
    geoms = "".join(f'<geom type="sphere" size="0.008" pos="{" ".join(map(str, p))}" rgba="{c}"/>'
                    for p, c in zip(pts, colors))
    m = mujoco.MjModel.from_xml_string(f'<mujoco><worldbody><light pos="0 0 3"/>{geoms}</worldbody></mujoco>')
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    W, H = 320, 200
    K = np.array([[250.0, 0, 140], [0, 270, 115], [0, 0, 1]])
    T = look_at(np.array([0.05, -0.6, 0.7]), np.array([0.0, 0.3, 0.0]))
    with mujoco.Renderer(m, H, W) as r:
        r.update_scene(d)
        for c in r.scene.camera:
            pinhole_gl_camera(c, K, T, W, H)
        img = r.render().astype(int)
    for ch, p in enumerate(pts):
        pc_ = (p - T[:3, 3]) @ T[:3, :3]
        uv = pc_[:2] / pc_[2] * [K[0, 0], K[1, 1]] + K[:2, 2]
        others = [c for c in range(3) if c != ch]
        v, u = np.nonzero((img[..., ch] > 100) & (img[..., others[0]] < 60) & (img[..., others[1]] < 60))
        assert len(u) >= 4
        np.testing.assert_allclose([u.mean() + 0.5, v.mean() + 0.5], uv, atol=1.0)
