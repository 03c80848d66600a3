"""What the annotation page writes (demoforge.lib.annotate.model): annotations checked and written atomically,
closed ranges suggested as the automatic method finds them, clicked points back-projected with a warning on
invalid depth. (Whether a take is annotated: tests/runtime/test_annotate.py, on a rendered take.)"""

from __future__ import annotations

import json

import numpy as np
import pytest

from demoforge.lib.annotate.model import (
    build_annotations, mask_to_ranges, point_info, suggest_closed_ranges, write_annotations,
)
from demoforge.lib.takes import TakeError
from demoforge.lib.takes.task_definition import custom_task


def _names(prefix: str, n: int) -> list[str]:
    return [f"{prefix}{i}" for i in range(n)]


def test_build_annotations_validates_and_writes_atomically(tmp_path):
    t = custom_task(["cup:rim", "cup:base", *(f"bowl:{k}" for k in _names("b", 9))])
    obj = build_annotations(t, {"rim": [10, 20], "base": [11.5, 30]}, frame=3, closed_ranges={"left": [[5, 9], [0, 2]]}, n_frames=12)
    assert obj["object_keypoints_2d"] == {"frame": 3, "names": ["rim", "base"], "uv": [[10.0, 20.0], [11.5, 30.0]]}
    assert obj["gripper_closed_ranges"] == {"left": [[0, 2], [5, 9]], "right": []}
    with pytest.raises(TakeError, match="overlapping"):
        build_annotations(t, {}, 0, {"right": [[0, 5], [4, 8]]}, n_frames=12)
    with pytest.raises(TakeError, match="take has 12 frames"):
        build_annotations(t, {}, 0, {"right": [[0, 20]]}, n_frames=12)
    with pytest.raises(TakeError, match="not keypoints of task"):
        build_annotations(t, {"lid": [1, 1]}, 0, {}, n_frames=12)
    p = write_annotations(tmp_path / "annotations.json", obj)
    assert json.loads(p.read_text()) == obj and [f.name for f in tmp_path.iterdir()] == ["annotations.json"]


def test_mask_to_ranges_and_suggestion_follow_the_automatic_method():
    from demoforge.lib.ingest.gripper_open_close import gripper_state

    assert mask_to_ranges(np.array([1, 1, 0, 0, 1, 0, 1], bool)) == [[0, 2], [4, 5], [6, 7]]
    assert mask_to_ranges(np.zeros(4, bool)) == []
    rng = np.random.default_rng(0)
    d = np.full((120, 2), 0.09) + rng.normal(0, 0.002, (120, 2))
    d[30:70, 0] = 0.02
    d[50:100, 1] = 0.025
    sug = suggest_closed_ranges(d)
    g = gripper_state(d, "auto")
    for h, side in enumerate(("left", "right")):
        mask = np.zeros(120, bool)
        for a, b in sug[side]:
            mask[a:b] = True
        assert np.array_equal(mask, g[:, h] < 0.5)
    assert len(sug["left"]) == 1 and abs(sug["left"][0][0] - 30) <= 3 and abs(sug["left"][0][1] - 70) <= 3
    assert suggest_closed_ranges(np.full((5, 2), np.nan)) == {"left": [], "right": []}


def test_point_info_back_projects_and_warns_on_invalid_depth():
    K = np.array([[500.0, 0, 32], [0, 500.0, 24], [0, 0, 1]])
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    depth = np.full((48, 64), 2.0, np.float32)
    depth[:, :20] = 0.0                     # a hole on the left
    depth[30, 40] = 0.0                     # one missing pixel, neighbours valid
    info = point_info(np.array([[32.0, 24.0], [5.0, 5.0], [40.0, 30.0], [100.0, 5.0]]), depth, K, T)
    assert info[0]["valid"] and info[0]["warning"] == ""
    assert np.allclose(info[0]["camera"], [0.0, 0.0, 2.0]) and np.allclose(info[0]["world"], [1.0, 2.0, 5.0])
    assert not info[1]["valid"] and "invalid depth" in info[1]["warning"] and info[1]["world"] is None
    assert info[2]["valid"] and not info[2]["pixel_depth_valid"] and "neighbours" in info[2]["warning"]
    assert not info[3]["valid"] and "outside the image" in info[3]["warning"]
