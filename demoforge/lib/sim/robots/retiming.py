"""Velocity-limited time-scaling of a joint trajectory: a real arm runs a path its joints cannot follow
at the demonstrated speed more slowly, instead of failing it.

    r = velocity_limited(q, fps=30.0, speed=limits)   # q (n, nq) waypoints, one per demonstrated frame
    r.s              # (m,) where along the waypoints each executed frame (1 / fps apart) is
    r.time_scale     # executed duration / demonstrated duration (1.0: nothing was too fast)
    q_exec = at(q, r.s)

Each step between two waypoints takes the demonstrated frame time 1 / fps, or longer where a joint
would exceed its speed limit: then the slowest joint sets the step's duration (|dq_j| / v_j, the
standard per-segment velocity scaling). The joints move linearly between waypoints, so no joint
exceeds its limit anywhere along the retimed trajectory. The retimed trajectory is then sampled
again at the frame rate (the executor and the exports run at the episode's fps); the last sample is
the last waypoint. A trajectory with no step too fast comes back unchanged (s = 0, 1, ..., n - 1).

Why not a time-optimal parameterisation (toppra installs here, 0.6.10): it would also speed up what
the person did slowly (waiting for the liquid to run, a careful placement), and it fits a spline
through the waypoints; the demonstration's timing is kept wherever the arm can follow it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Retiming:
    """s (m,): the fractional waypoint index of each executed frame; durations (n - 1,): seconds each
    demonstrated step takes when executed; fps: the frame rate of both."""
    s: np.ndarray
    durations: np.ndarray
    fps: float

    @property
    def time_scale(self) -> float:
        """Executed duration / demonstrated duration (1.0 for a single waypoint)."""
        nominal = len(self.durations) / self.fps
        return float((len(self.s) - 1) / self.fps / nominal) if nominal > 0 else 1.0

    @property
    def slowed(self) -> np.ndarray:
        """(n - 1,) bool: the steps a joint's speed limit stretched."""
        return self.durations > 1.0 / self.fps * (1 + 1e-9)


def velocity_limited(q: np.ndarray, fps: float, speed: np.ndarray) -> Retiming:
    """The retiming of waypoints q (n, nq), one per frame at `fps`, within the joints' speed limits
    `speed` (nq,) rad/s (see the module docstring)."""
    q = np.asarray(q, float)
    dt = 1.0 / fps
    if len(q) < 2:
        return Retiming(np.zeros(len(q)), np.zeros(0), fps)
    need = (np.abs(np.diff(q, axis=0)) / np.asarray(speed, float)).max(axis=1)  # (n - 1,) s per step
    durations = np.maximum(need, dt)
    n = len(q)
    if not (need > dt).any():
        return Retiming(np.arange(n, dtype=float), durations, fps)
    t = np.concatenate([[0.0], np.cumsum(durations)])
    m = int(np.ceil(t[-1] * fps - 1e-9)) + 1
    t_out = np.minimum(np.arange(m) / fps, t[-1])
    s = np.interp(t_out, t, np.arange(n, dtype=float))
    s[-1] = n - 1
    return Retiming(s, durations, fps)


def at(values: np.ndarray, s: np.ndarray) -> np.ndarray:
    """values (n, ...) linearly interpolated at fractional indices s (m,)."""
    values = np.asarray(values, float)
    i = np.clip(np.floor(s).astype(int), 0, len(values) - 1)
    j = np.minimum(i + 1, len(values) - 1)
    w = (np.asarray(s, float) - i).reshape((-1,) + (1,) * (values.ndim - 1))
    return (1.0 - w) * values[i] + w * values[j]


def step_of(s: np.ndarray) -> np.ndarray:
    """(m,) the waypoint each executed frame has reached (floor of s, exact waypoints included)."""
    return np.floor(np.asarray(s, float) + 1e-9).astype(int)


def max_speed_ratio(q: np.ndarray, fps: float, speed: np.ndarray) -> float:
    """The largest |dq_j| * fps / v_j over the steps of q (n, nq): above 1, a joint is too fast."""
    q = np.asarray(q, float)
    if len(q) < 2:
        return 0.0
    return float((np.abs(np.diff(q, axis=0)) * fps / np.asarray(speed, float)).max())
