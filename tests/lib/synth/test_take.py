"""Synthetic takes (demoforge.lib.synth.take): the take layout and its ground truth, written for a minimal stand-in
scene/demo and for a real task of the task library: camera.json round-trips, every GT table validates and reads
back, the annotated 2D object keypoints are the projections of the world keypoints; a failed write surfaces."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import demoforge.lib  # noqa: F401  (EGL before mujoco)
import demoforge.schemas.synthetic  # noqa: F401
from demoforge.lib.perception.hand_model import HandStyle
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


def _styles_of(out: Path) -> list[HandStyle]:
    st = json.loads((out / "take.json").read_text())["hand_styles"]
    return [HandStyle(**{**st[s], "skin_rgba": tuple(st[s]["skin_rgba"])}) for s in ("left", "right")]


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
