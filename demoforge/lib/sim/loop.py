"""The simulator's frame loop: the one body of MuJoCo stepping that every execution runs.

Three drivers share it, so that one episode gives the same physics whichever runs it:

* ``execute`` (executor.py): a whole episode of (n, 2, 8) actions with a robot;
* ``EpisodeStepper`` (stepper.py): the same, one action frame per call (the Gymnasium environments);
* ``replay`` (replay.py): the task library's scripted demonstration with the demonstrator's own hands
  (robots/hands.py), the held object welded to its hand.

A frame is `ctrl_per_frame` control steps; each writes the robot's targets (its plan's ``apply``), the
finger commands (:class:`FingerCommand`), runs its physics sub-steps and scans the contacts
(:func:`contact_scan`); then the frame is recorded (:func:`record_frame`) and, with
``stop_on_hard_failure``, the episode stops at the first hard failure (:class:`Records`). After the
last action frame the settle phase (:func:`settle`) holds the last commands, ending early at rest
with ``stop_when_settled``.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from .scene import PAIR_ARMS, PAIR_LINK, PAIR_TABLE, PAIR_TOUCH, SimScene


def frame_timing(fps: float, timestep: float, ctrl_per_frame: int) -> tuple[int, int, list[int]]:
    """(physics steps per action frame, control steps per frame, the physics steps of each control step)."""
    steps_per_frame = max(1, int(round(1.0 / (fps * timestep))))
    cpf = max(1, min(ctrl_per_frame, steps_per_frame))
    sub = np.diff(np.round(np.linspace(0, steps_per_frame, cpf + 1)).astype(int))
    return steps_per_frame, cpf, [int(x) for x in sub]


# ------------------------------------------------------------------ finger command (the g mapping)
class FingerCommand:
    """Aperture command per arm from the binary g (documented mapping, gripper.py):
    closed (g < 0.5) -> -squeeze (force-limited squeeze); open -> `opening`, except that a release
    (closed -> open) opens only to the measured held width + release_margin until the pinch target
    has moved reopen_distance away (so releasing near the table does not ram a finger into it);
    the command moves at most `speed` m/s (the gripper's closing speed)."""

    def __init__(self, spec, closed0: np.ndarray, dt_ctrl: float):
        self.spec = spec
        self.w = np.where(closed0, 0.0, spec.opening).astype(float)
        self.closed = [bool(x) for x in closed0]  # Python bools: compared every control step
        self.goal_open = np.full(2, spec.opening)
        self.release_pos: list = [None, None]
        self.wmax = spec.speed * dt_ctrl
        self.steady = False
        self.out = spec.stroke - self.w

    def update(self, closed, target_pos: np.ndarray, qpos: np.ndarray, finger_qadr: np.ndarray) -> np.ndarray:
        """closed: per-arm bools; qpos / finger_qadr: MjData.qpos and the (2, 2) finger joint addresses
        (read only on a release, so the steady fast path does no indexing)."""
        if self.steady and closed[0] == self.closed[0] and closed[1] == self.closed[1]:
            return self.out  # nothing can change: same g, commands at their goals, no release pending
        sp = self.spec
        finger_q = qpos[finger_qadr]
        steady = True
        for a in range(2):
            if closed[a]:
                goal = -sp.squeeze
                self.release_pos[a] = None
                self.goal_open[a] = sp.opening
            else:
                if self.closed[a]:  # release now
                    width = max(sp.stroke - float(finger_q[a, 0] + finger_q[a, 1]), 0.0)
                    self.goal_open[a] = min(sp.opening, width + sp.release_margin)
                    self.release_pos[a] = np.array(target_pos[a], float)
                rp = self.release_pos[a]
                if rp is not None and np.linalg.norm(target_pos[a] - rp) > sp.reopen_distance:
                    self.goal_open[a] = sp.opening
                    self.release_pos[a] = None
                goal = self.goal_open[a]
            self.closed[a] = closed[a]
            dw = goal - self.w[a]
            self.w[a] = goal if abs(dw) <= self.wmax else self.w[a] + math.copysign(self.wmax, dw)
            steady = steady and self.w[a] == goal and self.release_pos[a] is None
        self.steady = steady
        self.out = sp.stroke - self.w
        return self.out


# ------------------------------------------------------------------ per-frame records
class Records:
    """Per recorded frame: object poses, actual pinch poses, contacts; and the per-frame checks."""

    def __init__(self, sc: SimScene, T: int, opt, stop_frame: int | None):
        n_obj = sc.n_obj
        self.hist = np.zeros((T, n_obj, 4, 4))
        self.hist[:, :, 3, 3] = 1.0
        self.gp = np.zeros((T, 2, 8))
        self.touch = np.zeros((T, 2, 3, n_obj), bool)
        self.arm_contact = np.zeros(T, bool)
        self.link_contact = np.zeros(T, bool)
        self.table_force = np.zeros((T, 2))
        self.diag: dict[str, Any] = {"arm_pair": [], "link_pair": []}
        self.T = T
        self.limit = opt.table_force_limit
        self.lo, self.hi = sc.workspace[0] - opt.workspace_margin, sc.workspace[1] + opt.workspace_margin
        self.slack = sc.binding.hand_workspace_slack
        self.stop_frame = stop_frame  # a hard failure known before physics (the plan's): stop there

    def truncate(self, last: int) -> None:
        for k in ("hist", "gp", "touch", "arm_contact", "link_contact", "table_force"):
            setattr(self, k, getattr(self, k)[:last + 1])

    def hard_failure(self, i) -> bool:
        """The outcome is decided (failures.py: a hard failure fails the episode whatever follows).
        Collisions are checked every frame, the workspace every 6th frame (0.2 s at 30 fps) and at
        the last: classify() finds the first offending frame in the records."""
        tf = self.table_force
        if self.arm_contact[i] or tf[i, 0] > self.limit or tf[i, 1] > self.limit or self.link_contact[i]:
            return True
        if self.stop_frame is not None and i >= self.stop_frame:
            return True
        if i % 6 and i != self.T - 1:
            return False
        g, o = self.gp[i - 5:i + 1, :, :3], self.hist[i - 5:i + 1, :, :3, 3]
        return bool(((g < self.lo - self.slack) | (g > self.hi + self.slack)).any() or ((o < self.lo) | (o > self.hi)).any())


def contact_scan(sc: SimScene, rec: Records):
    """contacts(i): the current contacts into frame i's records (called every control step)."""
    mj, m, d = sc.mj, sc.model, sc.data
    ng = m.ngeom
    pk, pa, pp, po = sc.pair_lists
    force6 = np.zeros(6)
    touch, table_force, arm_contact, link_contact, diag = (rec.touch, rec.table_force, rec.arm_contact,
                                                           rec.link_contact, rec.diag)

    def names(j):
        return [mj.mj_id2name(m, mj.mjtObj.mjOBJ_GEOM, int(x)) for x in d.contact.geom[j]]

    def contacts(i):
        # one table look-up per contact (scene.py pair tables), plain Python on the few relevant contacts
        # (numpy calls on arrays of ~10 elements cost more than the work)
        nc = d.ncon
        if nc == 0:
            return
        geom = d.contact.geom[:nc]
        flat = (geom[:, 0] * ng + geom[:, 1]).tolist()
        for j, f in enumerate(flat):
            k = pk[f]
            if k == 0:  # PAIR_NONE: object-object, object-table (most contacts)
                continue
            if k == PAIR_TOUCH:
                touch[i, pa[f], pp[f], po[f]] = True
            elif k == PAIR_TABLE:
                mj.mj_contactForce(m, d, j, force6)
                arm = pa[f]
                if abs(force6[0]) > table_force[i, arm]:
                    table_force[i, arm] = abs(force6[0])
            elif k == PAIR_ARMS:
                if not diag["arm_pair"]:
                    diag["arm_pair"] = names(j)
                arm_contact[i] = True
            elif k == PAIR_LINK:
                if not diag["link_pair"]:
                    diag["link_pair"] = names(j)
                    diag["link_time_frame"] = i
                link_contact[i] = True

    return contacts


# ------------------------------------------------------------------ the loop
def preroll(sc: SimScene, seconds: float) -> int:
    """Hold the robot at its first pose for `seconds` (the objects settle); the physics steps run."""
    pre = int(round(seconds / sc.model.opt.timestep))
    if pre:
        sc.mj.mj_step(sc.model, sc.data, nstep=pre)
    return pre


def control_frame(sc: SimScene, i: int, sub: list[int], closed: tuple, targets_pos: np.ndarray,
                  fc: FingerCommand | None, contacts: Callable[[int], None] | None,
                  apply: Callable[[Any, int], None] | None = None, k0: int = 0) -> None:
    """Frame i's control steps: step c writes the plan's control step k0 + c (``apply``; None in the
    settle phase: the targets stay), the finger commands for the per-arm close commands `closed` and the
    pinch targets targets_pos[k0 + c] (fc None: a robot without finger actuators), runs sub[c] physics
    steps and scans the contacts into frame i's records (contacts None: nothing to classify)."""
    mj, m, d = sc.mj, sc.model, sc.data
    act, fq = sc.act_index, sc.finger_qadr
    for c, nstep in enumerate(sub):
        if apply is not None:
            apply(d, k0 + c)
        if fc is not None:
            d.ctrl[act] = fc.update(closed, targets_pos[k0 + c], d.qpos, fq)
        mj.mj_step(m, d, nstep=nstep)
        if contacts is not None:
            contacts(i)


def record_frame(sc: SimScene, rec: Records, i: int, on_frame: Callable[[Any], None] | None = None) -> None:
    """Frame i's records: the objects' poses, the robot's actual pinch poses and finger widths."""
    d = sc.data
    if on_frame is not None:
        on_frame(d)
    rec.hist[i, :, :3, :3] = d.xmat[sc.obj_body].reshape(-1, 3, 3)
    rec.hist[i, :, :3, 3] = d.xpos[sc.obj_body]
    sc.binding.record(d, rec.gp[i])
    rec.gp[i, :, 7] = sc.spec.stroke - d.qpos[sc.finger_qadr].sum(axis=1)


def run_frames(sc: SimScene, rec: Records, opt, sub: list[int], closed: list[tuple], targets_pos: np.ndarray,
               fc: FingerCommand | None, contacts, apply, n: int,
               on_frame: Callable[[Any], None] | None = None) -> int | None:
    """Action frames 1 .. n - 1 (frame 0 is recorded after the pre-roll): closed[i] the close commands
    of frame i, targets_pos the pinch targets at control rate. The frame a hard failure stopped the
    simulation at (opt.stop_on_hard_failure), else None."""
    cpf = len(sub)
    for i in range(1, n):
        control_frame(sc, i, sub, closed[i], targets_pos, fc, contacts, apply, (i - 1) * cpf)
        record_frame(sc, rec, i, on_frame)
        if opt.stop_on_hard_failure and rec.hard_failure(i):
            return i
    return None


def settle(sc: SimScene, rec: Records, opt, sub: list[int], closed_last: tuple, pos_last: np.ndarray,
           fc: FingerCommand | None, contacts, first: int, T: int,
           on_frame: Callable[[Any], None] | None = None) -> tuple[int | None, int | None, int]:
    """The settle phase, frames first .. T - 1, holding the last commands: (the frame a hard failure
    stopped it at, the frame it ended at rest (opt.stop_when_settled), the last frame run)."""
    targets = np.broadcast_to(pos_last, (len(sub),) + np.shape(pos_last))
    rest = 0
    for i in range(first, T):
        control_frame(sc, i, sub, closed_last, targets, fc, contacts)
        record_frame(sc, rec, i, on_frame)
        if opt.stop_on_hard_failure and rec.hard_failure(i):
            return i, None, i
        if opt.stop_when_settled:
            qv = sc.data.qvel
            still = ((fc is None or fc.steady) and float(np.abs(qv[sc.rest_lin]).max()) < opt.rest_speed
                     and float(np.abs(qv[sc.rest_ang]).max()) < opt.rest_spin)
            rest = rest + 1 if still else 0
            if rest >= opt.rest_frames and i < T - 1:
                return None, i, i
    return None, None, T - 1
