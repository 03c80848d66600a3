"""The synthetic hands' skin look (demoforge.lib.synth.hand_skin): the skinned hand is bound to the kinematic
joints, the hand style changes the pixels and not the ground truth, skin tones vary per take."""

from __future__ import annotations

import json

import numpy as np
import pytest

import demoforge.lib  # noqa: F401  (EGL before mujoco)
import demoforge.schemas.synthetic  # noqa: F401
from demoforge.lib.perception.hand_model import hand_from_pinch
from demoforge.lib.synth import render as R
from demoforge.lib.synth import take as TK
from demoforge.schemas.core import read_table_file
from tests.support.standin import STANDIN_XML, StandInDemo


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
