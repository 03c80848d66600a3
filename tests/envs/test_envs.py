"""demoforge.envs' registration: every task with each robot an environment id of Gymnasium's registry, from a
module that loads no simulator; the ids name the robot check's robot and hand."""

from __future__ import annotations

import subprocess
import sys

import gymnasium
import numpy as np
import pytest

import demoforge.envs
from demoforge.lib.task_library import TASK_NAMES


def test_every_task_and_robot_is_registered_by_a_module_that_needs_only_gymnasium():
    assert demoforge.envs.TASKS == TASK_NAMES
    ids = {f"demoforge/{t}-{r}-v0" for t in TASK_NAMES for r in ("aloha", "aloha2f140", "grippers")}
    assert ids == set(demoforge.envs.ENV_IDS) and ids <= set(gymnasium.registry)
    assert demoforge.envs.env_id("pouring", "aloha2f140") == "demoforge/pouring-aloha2f140-v0"
    with pytest.raises(ValueError, match="aloha2f140"):
        demoforge.envs.env_id("pouring", "aloha+2f140")
    probe = ("import sys, gymnasium, demoforge.envs; "
             "print(sorted(m for m in sys.modules if m.startswith(('mujoco', 'demoforge.lib.sim', 'scipy'))))")
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    assert loaded.stdout.strip() == "[]", loaded.stdout


def test_the_ids_map_to_the_robot_checks_robot_and_hand():
    from demoforge.lib.exports import POSE16_NAMES
    from demoforge.lib.sim.robots.aloha import JOINT_NAMES

    labels = {}
    for key in ("aloha", "aloha2f140", "grippers"):
        env = gymnasium.make(demoforge.envs.env_id("trash_in_bin", key)).unwrapped
        labels[key] = env.robot.label
        names = env.features["observation.state"]["names"]
        assert names == (list(JOINT_NAMES) if key != "grippers" else list(POSE16_NAMES))
        assert env.action_space.shape == (len(names),) and env.action_space.dtype == np.float32
        env.close()
    assert labels == {"aloha": "aloha", "aloha2f140": "aloha+2f140", "grippers": "grippers"}
