"""A take's task (demoforge.lib.takes.task_definition): custom tasks group their keypoints by object and check
the names; the annotations' task section round-trips; a library task's keypoints are fixed."""

from __future__ import annotations

import json

import pytest

from demoforge.lib.takes import TakeError
from demoforge.lib.takes.task_definition import custom_task, library_task, load_task_file, parse_task_section


def _names(prefix: str, n: int) -> list[str]:
    return [f"{prefix}{i}" for i in range(n)]


def test_custom_task_groups_keypoints_by_object_and_validates_names():
    t = custom_task(["cup:rim", "bowl:rim_l", "cup:base", "bowl:rim_r", *(f"bowl:{k}" for k in _names("b", 7))],
                    name="stack")
    assert t.object_names == ("cup", "bowl")
    assert t.keypoint_names[:4] == ("rim", "base", "rim_l", "rim_r") and t.keypoint_object == (0, 0) + (1,) * 9
    assert custom_task(",".join(_names("k", 11))).object_names == ("object_a",)
    with pytest.raises(TakeError, match="needs 11 object keypoints, got 3"):
        custom_task("a,b,c")
    with pytest.raises(TakeError, match="unique"):
        custom_task(_names("k", 10) + ["k0"])
    with pytest.raises(TakeError, match="at most 2 objects"):
        custom_task(["x:a", "y:b", *(f"z:{k}" for k in _names("c", 9))])
    with pytest.raises(TakeError, match="letters, digits"):
        custom_task(_names("k", 10) + ["a b"])
    with pytest.raises(TakeError, match="--keypoints"):
        custom_task(" , ")


def test_task_section_round_trips_and_library_keypoints_are_fixed(tmp_path):
    lib_t = library_task("pouring")
    assert lib_t.n_keypoints == 11 and lib_t.library
    assert parse_task_section(lib_t.to_json()) == lib_t
    bad = lib_t.to_json()
    bad["objects"][0]["keypoints"] = ["x"] + bad["objects"][0]["keypoints"][1:]
    with pytest.raises(TakeError, match="library task"):
        parse_task_section(bad)
    f = tmp_path / "task.json"
    f.write_text(json.dumps({"name": "stack", "objects": [{"name": "cup", "arm": "right", "keypoints": _names("c", 5)},
                                                          {"name": "bowl", "arm": "up", "keypoints": _names("b", 6)}]}))
    with pytest.raises(TakeError, match="'left' or 'right'"):
        load_task_file(f)
    f.write_text("{nope")
    with pytest.raises(TakeError, match="not valid JSON"):
        load_task_file(f)
    with pytest.raises(TakeError, match="unknown task"):
        library_task("juggling")
