"""The one registry (demoforge.lib.registry) behind robots, take sources, hand detectors and LLM backends, and
the robot spec parsed once (demoforge.lib.robot_spec): unknown names are one line listing the choices, lazy
entries are imported only by `get`, `aloha+2f140` and `--robot aloha --gripper 2f140` are the same object, and
the command line lists and checks the registries' own names."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap

import pytest
from typer.testing import CliRunner

from demoforge.lib.errors import UnknownNameError, UnknownTaskError, UserError
from demoforge.lib.registry import Registry
from demoforge.lib.robot_spec import ROBOTS, RobotError, RobotSpec, robot_labels
from tests.support.paths import REPO_ROOT

PROJECT = REPO_ROOT
runner = CliRunner()


def _one_line_error(fn) -> UnknownNameError:
    with pytest.raises(UnknownNameError) as ei:
        fn()
    text = str(ei.value)
    assert "\n" not in text
    return ei.value


def test_an_unknown_name_is_one_line_listing_the_names_in_every_registry():
    from demoforge.lib.llm import get_backend
    from demoforge.lib.perception.detectors import get_detector
    from demoforge.lib.takes import TakeError
    from demoforge.lib.takes.sources import get_source

    e = _one_line_error(lambda: RobotSpec("ur5"))
    assert str(e) == "unknown robot 'ur5'; choose one of: grippers, aloha" and isinstance(e, RobotError)
    e = _one_line_error(lambda: get_detector("nosuch"))
    assert str(e) == "unknown hand detector 'nosuch'; choose one of: hamer, mediapipe, precomputed, simulated"
    e = _one_line_error(lambda: get_backend("nosuch"))
    assert str(e) == "unknown LLM backend 'nosuch'; choose one of: local, openai, fake"
    e = _one_line_error(lambda: get_source("nosuch"))
    assert str(e).startswith("unknown take source 'nosuch'; choose one of: folder, mp4, realsense, rosbag2, record3d")
    assert isinstance(e, TakeError)  # callers that catch a take's errors still catch it
    assert e.kind == "take source" and e.name == "nosuch" and "mp4" in e.choices
    # one user-error type: a ValueError (what the detector and LLM lookups raised before) and a UserError
    assert issubclass(UnknownNameError, UserError) and issubclass(UnknownNameError, ValueError)
    assert issubclass(RobotError, UnknownNameError) and issubclass(UnknownTaskError, UnknownNameError)
    e = _one_line_error(lambda: RobotSpec("aloha", "robotiq"))
    assert str(e) == "the aloha robot carries aloha or 2f140, not 'robotiq'" and e.choices == ("aloha", "2f140")


def test_a_lazy_entry_is_imported_by_get_only(tmp_path, monkeypatch):
    (tmp_path / "registry_probe_mod.py").write_text("VALUE = object()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "registry_probe_mod", raising=False)
    reg: Registry = Registry("probe", {"eager": 1})
    reg.register("lazy", "registry_probe_mod:VALUE")
    assert reg.names() == ("eager", "lazy") and "lazy" in reg and reg.check("lazy") == "lazy"
    assert not reg.is_loaded("lazy") and "registry_probe_mod" not in sys.modules
    value = reg.get("lazy")
    assert "registry_probe_mod" in sys.modules and value is sys.modules["registry_probe_mod"].VALUE
    assert reg.is_loaded("lazy") and reg.get("lazy") is value  # imported once
    with pytest.raises(ValueError, match="module:attribute"):
        reg.register("bad", "no_colon_here")


def test_listing_and_checking_names_loads_no_backend_no_robot_model_and_no_numpy():
    """The command line checks robots and LLM backends, and parses robot labels, without loading their modules."""
    code = textwrap.dedent("""
        import sys
        from demoforge.lib.llm import BACKENDS
        from demoforge.lib.robot_spec import ROBOTS, RobotSpec, robot_labels
        assert BACKENDS.check("local") == "local" and RobotSpec.parse("aloha+2f140").label == "aloha+2f140"
        assert robot_labels() == ("grippers", "aloha", "aloha+2f140")
        loaded = [m for m in ("demoforge.lib.llm.local_backend", "demoforge.lib.llm.openai_backend", "numpy",
                              "demoforge.lib.sim", "demoforge.lib.sim.robots.aloha", "mujoco") if m in sys.modules]
        assert loaded == [], loaded
        assert not ROBOTS.is_loaded("aloha") and not BACKENDS.is_loaded("local")
    """)
    p = subprocess.run([sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr


def test_robot_spec_parsed_from_a_label_equals_the_one_from_the_cli_options():
    assert RobotSpec.parse("aloha+2f140") == RobotSpec.from_options("aloha", "2f140")
    assert hash(RobotSpec.parse("aloha+2f140")) == hash(RobotSpec.from_options("aloha", "2f140"))
    # no hand given: the robot's own, stored by name, so equal requests are equal objects
    assert RobotSpec.parse("aloha") == RobotSpec.from_options("aloha") == RobotSpec("aloha", "aloha")
    assert RobotSpec.parse("grippers") == RobotSpec.from_options("grippers", "2f140") == RobotSpec()
    assert RobotSpec.parse("aloha").gripper == "aloha" and RobotSpec.parse("grippers").gripper == "2f140"
    # the labels the tables store: the hand only where it is not the robot's own
    assert [RobotSpec.parse(x).label for x in ("grippers", "aloha", "aloha+2f140", "aloha+aloha", "grippers+2f140")] \
        == ["grippers", "aloha", "aloha+2f140", "aloha", "grippers"]
    assert all(RobotSpec.parse(label).label == label for label in robot_labels())
    assert RobotSpec.of("aloha+2f140") == RobotSpec.of("aloha", "2f140") == RobotSpec.of(RobotSpec("aloha", "2f140"))
    with pytest.raises(RobotError):
        RobotSpec.of(RobotSpec("aloha"), "2f140")  # a spec keeps its own hand
    with pytest.raises(AttributeError):
        RobotSpec("aloha").gripper = "2f140"  # frozen


def test_the_embodiment_is_resolved_once_per_process_with_the_specs_label():
    from demoforge.lib.sim.robots import get_robot, resolve_robot

    for label in robot_labels():
        spec = RobotSpec.parse(label)
        robot = resolve_robot(spec)
        assert robot is resolve_robot(label) and robot is get_robot(spec.robot, spec.gripper)
        assert (robot.name, robot.gripper_name, robot.label) == (spec.robot, spec.gripper, spec.label)


def test_the_main_jobs_config_checks_and_normalises_its_robots_once():
    from demoforge.lib.evaluation.config import EvaluateConfig

    c = EvaluateConfig(robots=["grippers+2f140", "aloha", "aloha+2f140"], grid_robots=("aloha+2f140",))
    assert c.robots == ("grippers", "aloha", "aloha+2f140")
    assert c.robot_specs[2] == RobotSpec("aloha", "2f140") and c.grid_robot_specs == (RobotSpec("aloha", "2f140"),)
    with pytest.raises(RobotError, match="unknown robot 'ur5'"):
        EvaluateConfig(robots=("ur5",))
    with pytest.raises(RobotError, match="carries aloha or 2f140"):
        EvaluateConfig(grid_robots=("aloha+robotiq",))


def _cli(args):
    from demoforge.cli import app

    return runner.invoke(app, args)


def _help(args) -> str:
    """The help text of a command on one line, without the panels' borders."""
    r = _cli([*args, "--help"])
    assert r.exit_code == 0, r.output
    return " ".join(re.sub("[│╭╮╰╯─]", " ", r.stdout).split())


@pytest.mark.parametrize("args, message", [
    (["simulate", "--robot", "nosuch"], "error: --robot must be one of grippers, aloha, got 'nosuch'"),
    (["simulate", "--robot", "aloha", "--gripper", "nosuch"],
     "error: --gripper 'nosuch': the aloha robot carries aloha or 2f140"),
    (["ingest", "no_such_take", "--detector", "nosuch"],
     "error: --detector must be one of hamer, mediapipe, precomputed, simulated, got 'nosuch'"),
    (["llm-eval", "--backend", "nosuch"], "error: --backend must be one of local, openai, fake, got 'nosuch'"),
    (["evaluate", "--robot", "aloha+robotiq"], "error: --robot: the aloha robot carries aloha or 2f140, not 'robotiq'"),
])
def test_an_unknown_name_on_the_command_line_is_one_line_and_exit_2(tmp_path, monkeypatch, args, message):
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(tmp_path / "warehouse"))
    r = _cli(args)
    assert r.exit_code == 2 and r.stderr.splitlines() == [message], (r.exit_code, r.output)


def test_help_lists_the_choices_of_the_registries_themselves(monkeypatch):
    from demoforge.lib import robot_spec

    monkeypatch.setitem(ROBOTS._entries, "testbot", "nowhere_at_all:Robot")  # never loaded: --help only lists it
    monkeypatch.setitem(robot_spec._HANDS, "testbot", ("claw", "2f140"))
    text = _help(["simulate"])
    assert "one of: grippers, aloha, testbot." in text and "testbot: claw or 2f140" in text
    assert "pouring, trash_in_bin, paper_in_case, mix_bowl, open_container, empty_vase" in text  # --task
    assert "{robots}" not in text and "{tasks}" not in text
    text = _help(["ingest"])
    assert "One of: hamer, mediapipe, precomputed, simulated." in text
    text = _help(["table3"])
    assert "One of: local, openai, fake." in text
    text = _help(["evaluate"])
    assert "grippers, aloha, aloha+2f140, testbot, testbot+2f140" in text
