"""Detection measured against synthetic ground truth (lib/evaluation/detection.py): matching,
handedness, pixel errors and PCK on hand-made candidates, and end to end on a short rendered take
with a detector that reads the ground truth (every number known in advance)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from demoforge.lib.evaluation.detection import box_size, evaluate_detection, match_frame, per_task, score_take


def _gt(T=4):
    rng = np.random.default_rng(0)
    base = np.stack([np.array([200.0, 240.0]), np.array([440.0, 240.0])])        # left, right centres
    px = base[None, :, None, :] + rng.uniform(-40, 40, (T, 2, 21, 2))
    in_view = np.ones((T, 2, 21), bool)
    visible = in_view.copy()
    visible[:, :, :3] = False                                                      # some hidden joints
    holding = np.zeros((T, 2), bool)
    holding[2:, 1] = True
    return {"px": px, "in_view": in_view, "visible": visible, "holding": holding}


def _cand(px, side):
    return SimpleNamespace(joints_px=np.asarray(px), handedness=side)


def test_perfect_detections_score_perfectly():
    gt = _gt()
    cands = [[_cand(gt["px"][t, 1], "right"), _cand(gt["px"][t, 0], "left")] for t in range(4)]
    rows = {r["subset"]: r for r in score_take(cands, gt)}
    a = rows["all"]
    assert (a["hand_frames"], a["detected"], a["detection_rate"], a["handedness_acc"]) == (8, 8, 1.0, 1.0)
    assert a["mpjpe_2d_px"] == 0.0 and a["pck05"] == 1.0 and a["spurious_per_frame"] == 0.0
    o = rows["occluded"]                                   # right hand holding in frames 2, 3
    assert (o["hand_frames"], o["detected"]) == (2, 2)


def test_swapped_labels_missed_hands_offsets_and_spurious():
    gt = _gt()
    size = box_size(gt["px"])
    cands = []
    for t in range(4):
        c = [_cand(gt["px"][t, 0] + [0.1 * size[t, 0], 0.0], "right")]    # left hand, wrong label, offset
        if t < 2:
            c.append(_cand(gt["px"][t, 1] + [600.0, 600.0], "right"))        # far from everything
        cands.append(c)
    rows = {r["subset"]: r for r in score_take(cands, gt)}
    a = rows["all"]
    assert a["detected"] == 4 and a["detection_rate"] == 0.5 and a["handedness_acc"] == 0.0
    assert a["pck05"] == 0.0 and a["pck15"] == 1.0                 # every joint off by 0.1 x the box
    assert np.isclose(a["mpjpe_2d_px"], np.mean(0.1 * size[:, 0]))
    assert a["spurious_per_frame"] == 0.5
    assert rows["occluded"]["detected"] == 0


def test_hands_mostly_out_of_view_do_not_count():
    gt = _gt()
    gt["in_view"][:, 0, :5] = False                      # 16/21 = 76 % in view: not eligible
    rows = {r["subset"]: r for r in score_take([[] for _ in range(4)], gt)}
    assert rows["all"]["hand_frames"] == 4 and rows["all"]["detected"] == 0
    assert np.isnan(rows["all"]["handedness_acc"])


def test_match_frame_is_one_to_one():
    gt = _gt(1)
    px = gt["px"][0]
    m = match_frame(np.stack([px[0], px[0] + 1.0]), px, gt["in_view"][0], box_size(px))
    assert m[0] == 0 and m[1] == -1                        # the second candidate sits on the left hand too


def test_per_task_pools_counts():
    rows = [{"task": "t", "hand_style": "skin", "detector": "d", "running_mode": "video", "subset": "all",
             "hand_frames": n, "detected": k, "handedness_acc": h, "mpjpe_2d_px": e, "pck05": 0.5, "pck15": 1.0,
             "spurious_per_frame": 0.0} for n, k, h, e in ((10, 5, 1.0, 2.0), (10, 10, 0.4, 5.0))]
    (r,) = per_task(rows)
    assert r["detection_rate"] == 0.75 and np.isclose(r["handedness_acc"], 0.6) and np.isclose(r["mpjpe_2d_px"], 4.0)


@pytest.fixture
def oracle(monkeypatch):
    """A detector that returns the ground-truth 2D joints of the take it is given, labelled correctly."""
    import demoforge.lib.perception.detectors as D
    from demoforge.lib.evaluation.detection import load_ground_truth

    class Oracle(D.HandDetector):
        name, version = "oracle", "1"
        gt = None

        def detect(self, rgb_batch, K, frame_indices):
            out = []
            for f in frame_indices:
                out.append([D.HandCandidate(handedness=s, confidence=1.0, joints_px=self.gt["px"][f, h],
                                            joints_cam=np.ones((21, 3)))
                            for h, s in enumerate(("left", "right")) if np.isfinite(self.gt["px"][f, h]).all()])
            return out

    monkeypatch.setitem(D.DETECTORS._entries, "oracle", Oracle)  # registered for this test only
    return Oracle, load_ground_truth


def test_end_to_end_on_a_rendered_take(tmp_path, oracle):
    from demoforge.lib.synth import take as TK
    from tests.support.standin import STANDIN_XML, StandInDemo

    Oracle, load = oracle
    out = tmp_path / "t"
    TK.write_take(out, task_name="standin", seed=2, mirror=False, scene_xml=STANDIN_XML,
                  object_names=["cup", "bowl"], keypoint_names=[f"kp{i}" for i in range(11)],
                  demo=StandInDemo(5), video=False)
    Oracle.gt = load(out)
    rows = {r["subset"]: r for r in evaluate_detection(out, "oracle")}
    a = rows["all"]
    assert a["take"] == "synth_standin_s0002" and a["hand_style"] == "capsule" and a["frames"] == 5
    assert a["hand_frames"] == 10 and a["detection_rate"] == 1.0 and a["handedness_acc"] == 1.0
    assert a["mpjpe_2d_px"] == 0.0 and a["pck05"] == 1.0
    # the right hand holds the cup from frame 2 on (StandInDemo.closed)
    assert rows["occluded"]["hand_frames"] <= 3


def test_cli_without_takes_says_what_to_do(tmp_path):
    from typer.testing import CliRunner

    from demoforge.cli import app

    res = CliRunner().invoke(app, ["--warehouse", str(tmp_path / "wh"), "evaluate-detection"])
    assert res.exit_code == 2 and "run `demoforge synth` first" in res.output
    res = CliRunner().invoke(app, ["--warehouse", str(tmp_path / "wh"), "evaluate-detection", "--mode", "fast"])
    assert res.exit_code == 2 and "--mode must be" in res.output
