"""Velocity-limited retiming (demoforge.lib.sim.robots.retiming): only the steps too fast for a joint are slowed,
on the waypoints' straight line. (A too-fast trajectory retimed on the arms: tests/lib/sim/robots/aloha/test_aloha.py.)"""

import numpy as np
import pytest

from demoforge.lib.sim.robots.retiming import at, max_speed_ratio, velocity_limited


def test_velocity_limited_retiming_slows_only_the_steps_too_fast():
    """One step of 1 rad at 30 fps for a 3 rad/s joint takes 1/3 s: 10 frames instead of 1; a step within
    the limit keeps its frame; the samples are on the waypoints' straight line, within the limit."""
    q = np.array([[0.0, 0.0], [1.0, 0.05], [1.05, 0.1]])
    r = velocity_limited(q, 30.0, np.array([3.0, 3.0]))
    assert r.slowed.tolist() == [True, False]
    assert len(r.s) == 12 and r.time_scale == pytest.approx(11 / 2)
    samples = at(q, r.s)
    assert max_speed_ratio(samples, 30.0, np.array([3.0, 3.0])) <= 1.0 + 1e-9
    assert np.allclose(samples[-1], q[-1]) and np.allclose(samples[0], q[0])
    assert velocity_limited(q[:, :1] * 0.01, 30.0, np.array([3.0])).s.tolist() == [0.0, 1.0, 2.0]
