"""Whether the ViperX arms can execute each episode of a task database, kinematically, batched over all
episodes and steps with the arms' closed-form IK (closed_form.py): no MuJoCo, no mink.

    s = screen_episodes(robot, "pouring", actions, lengths, keypoints0)   # actions (E, n, 2, 8) or a list
    s.executable      # (E,) bool
    s.reason          # (E,) "" or the first cause: unreachable, wrist_in_table, fingers_in_table,
                      #      joint_limit, branch_jump, forearms_meet
    s.min_margin_rad  # (E,) the smallest joint margin along the arms' screened paths (NaN: no window)
    s.turn, s.flip    # (E, 2) each arm's grasp turn (rad, at its window's first sample) and half-turn

The decision is the planner's (aloha/__init__.py AlohaRobot.motion -> arm_motion.py plan_arm_motion ->
retargeting.py -> grasp_choice.py), rule for rule: the poses smoothed (SMOOTH_SIGMA), each arm's window
(follow_windows), the held objects (held_objects) and the object each window turns its grasp about
(window_objects), the objects' demonstrated motion, and per window the candidate grasps (the held object's
symmetric turns x the gripper's half-turn) judged on the same SAMPLES steps: within reach (the triangle
closes), every joint MIN_MARGIN inside its range, no joint jumping between samples (JUMP, or JUMP_PER_STEP per
demonstrated step between them), the wrist WRIST_ABOVE_TABLE and the fingertips the clearance less
LIFT_TOLERANCE above the table, the turn changing only while an axially symmetric object is held
(GRIP_SETTLE_STEPS after the close) and by at most TURN_STEP_MAX_DEG a sample; then the two arms'
forearm-wrist-hand segments and hands ARM_GAP apart (or as far as the demonstrated hands were, less 1 cm) at
every sample step of either arm where both windows run, else one arm chosen again around the other.
screening_windows.py does the part before the grasps over a group's episodes at once, screening_arm.py the
grasps (screening_paths.py their paths), screening_pairs.py the two arms together (screening_points.py the
point sets).

An arm can follow its window when some candidate has a path that meets every rule at every sample (a
*witness*): the planner's shortest path (grasp_choice._best_path, a fault costs BAD, everything else
together less) then meets them too. A witness is found cheaply: reach and the wrist's and fingertips'
heights depend on the pose only (not on the branch; a half-turn about the approach axis moves the last
joint by pi and nothing else), so they are checked for every turn and sample first, a few dozen operations
each; the joints (all 8 branches of the closed form) are solved only where needed: per episode the
smallest turn that passes those checks throughout (the demonstration's grasp, as a rule), both half-turns
from one solve; for the episodes it fails, every turn at once, held fixed (screening_arm.py _fixed_turns)
or, for an axially symmetric held object, on turning paths (the joints only of the poses such a path
reaches). An episode with no witness is screened out, with the first cause (by window step) as its reason.
The forearms are checked on the witnesses, and where they clash each arm is searched again around the
other's witness, as the planner does (screening_pairs.py _again).

What keeps it fast (one core; the verdicts are the same float for float as the plain batched rules'): the
loops that numpy ran as many small passes (per sample, per neighbour, per point) are numba kernels that do
the same arithmetic in the same order (no fastmath; numpy's own sines, cosines, arctangents and arccosines
on whole arrays where libm's would differ in the last bit), each checked bit for bit against its numpy or
per-episode original in the tests: the path search (screening_paths.py, one episode at a time over its arm
branches), the joints' arithmetic between numpy's trigonometry (closed_form.ViperXBatchIK.solve_into,
margins per joint, straight into place), the pose checks, the turn paths' reach, the smoothing, the
proximity signal, the rotations, the forearm points, the point sets' distances and the other arm's test
against a held object's turned hand (each pair of points comes near on an arc of turns: in closed form,
point distances only in a 10 um band). Around them, arrays laid out for contiguous work, a few tens of
episodes a pass so the temporaries stay in the cache, and the shared steps, needed gaps and witness points
of a pair check taken once.

Where it differs from the planner: the witness is a feasible candidate, not necessarily the planner's best
one, so the turn and margin reported are the witness's and the forearms are checked on the witnesses'
joints (the planner's own pair may clash where the witnesses' do not, or the reverse); a path with a joint
jump is infeasible here, where the planner's flag (GraspChoice.feasible: every sample followed) passes it
when nothing cleaner exists (such episodes fail in physics: 16 of 22 empty_vase ones `unreachable`, none
succeeded); a branch changes only within an arm branch (the wrist's two), never through the arm's
singular configurations (the stretched elbow, the wrist centre over the waist axis), which no followed
path crosses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from demoforge.lib.sim.robots.aloha import SMOOTH_SIGMA
from .retargeting import GRASP_REACH
from .screening_arm import REASONS, ArmScreen, ArmsContext, screen_arm
from .screening_pairs import forearms
from .screening_windows import held_batch, object_poses_batch, smooth_batch, windows_batch

#: bump when the same episodes would be screened otherwise
SCREEN_VERSION = "2"  # 2: the held object named by hull distance (segmentation.held_objects)
CHUNK = 256  # episodes per pass: a pass's arrays stay within a few tens of MB


@dataclass
class Screening:
    """Per episode (see the module docstring). windows (E, 2, 2) and objects (E, 2) (-1: none) are the
    planner's; arm_feasible (E, 2) each arm's window on its own; forearm_gap (E,) m the smallest distance
    between the two arms' segments where their windows share samples (inf: none shared, or an arm out)."""
    executable: np.ndarray
    reason: np.ndarray
    min_margin_rad: np.ndarray
    turn: np.ndarray
    flip: np.ndarray
    windows: np.ndarray
    objects: np.ndarray
    arm_feasible: np.ndarray
    forearm_gap: np.ndarray

    def __len__(self) -> int:
        return len(self.executable)


def padded_actions(actions, lengths=None) -> tuple[np.ndarray, np.ndarray]:
    """(E, n_max, 2, 8) actions (each padded with its last step) and (E,) lengths from an array or a list."""
    if isinstance(actions, np.ndarray) and actions.ndim == 4:
        n = np.full(len(actions), actions.shape[1]) if lengths is None else np.asarray(lengths, int)
        return np.asarray(actions, float), n
    seqs = [np.asarray(x, float) for x in actions]
    n = np.array([len(x) for x in seqs], int)
    out = np.zeros((len(seqs), int(n.max()) if len(n) else 0, 2, 8))
    for i, x in enumerate(seqs):
        out[i, :len(x)], out[i, len(x):] = x, x[-1]
    return out, n


def screen_episodes(robot, task_name: str, actions, lengths=None, keypoints0=None, chunk: int = CHUNK) -> Screening:
    """Screen episodes (actions (E, n, 2, 8) padded with lengths (E,), or a list of (n_i, 2, 8)) whose objects'
    keypoints at the start are keypoints0 (E, K, 3), for the robot's arms (an AlohaRobot: its retargeting of
    the task gives the closed form, the bases, the ready pose, the speeds and the hand)."""
    actions, lengths = padded_actions(actions, lengths)
    kp = np.asarray(keypoints0, float)
    E = len(actions)
    out = Screening(np.zeros(E, bool), np.full(E, "", object), np.full(E, np.nan), np.full((E, 2), np.nan),
                    np.zeros((E, 2), bool), np.zeros((E, 2, 2), int), np.full((E, 2), -1), np.zeros((E, 2), bool),
                    np.full(E, np.inf))
    if not E:
        return out
    ctx = ArmsContext(robot.retargeting(task_name))
    for rows in episode_groups(actions, lengths):
        n = int(lengths[rows[0]])
        for i in range(0, len(rows), chunk):
            part = rows[i:i + chunk]
            _screen_part(ctx, actions[part, :n], kp[part], out, part)
    return out


def warm_kernels() -> list:
    """Compile the screening's numba kernels (or load them from numba's cache beside their modules) by screening
    a small pouring database (its scripted seed-0 demonstration augmented, half mirrored: every stage runs,
    the second choice of an arm around the other included): `make setup` runs it once, so the first
    screening of a fresh checkout and every process of the test suite load them instead of compiling
    them again (8.5 s CPU each). Returns the index files of numba's cache of the kernels' modules."""
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes

    from . import closed_form, screening_arm, screening_paths, screening_points, screening_windows

    t = get_task("pouring")
    b = generate_episodes(from_scripted_demo(t, t.scripted_demo(0)), n=47, n_mirrored=24, seed=0, workers=1)
    screen_episodes(get_robot("aloha", "2f140"), "pouring", np.asarray(b.actions, float), np.asarray(b.lengths),
                    np.asarray(b.keypoints, float))
    return sorted(f for m in (closed_form, screening_arm, screening_paths, screening_points, screening_windows)
                  for f in (Path(m.__file__).parent / "__pycache__").glob(f"{Path(m.__file__).stem}.*.nbi"))


def episode_groups(actions: np.ndarray, lengths: np.ndarray) -> list[np.ndarray]:
    """Indices of the episodes sharing a length and every step's open/close state of both grippers (a task
    database: one group per kind of episode, the original and the translated ones sharing one)."""
    closed = actions[..., 7] < 0.5
    keys: dict = {}
    for e in range(len(actions)):
        keys.setdefault((int(lengths[e]), np.packbits(closed[e, :lengths[e]]).tobytes()), []).append(e)
    return [np.array(v) for v in keys.values()]


def _screen_part(ctx: ArmsContext, actions: np.ndarray, kp: np.ndarray, out: Screening, idx: np.ndarray) -> None:
    """Screen a chunk of one group's episodes into out[idx]."""
    traj = smooth_batch(actions, SMOOTH_SIGMA, idx)
    held_all = held_batch(traj, kp, ctx.ko)
    _, first, inverse = np.unique(held_all.reshape(len(traj), -1), axis=0, return_index=True, return_inverse=True)
    for k, f in enumerate(first):  # one pattern of held objects per group, as a rule
        sub = np.flatnonzero(inverse.ravel() == k)
        t, held = traj[sub], held_all[f]
        windows = windows_batch(t, kp[sub], ctx.ko, held)
        obj0 = object_poses_batch(ctx.task, kp[sub])
        objects = _window_objects(held, windows, t, kp[sub], ctx.ko)
        arms, cands = [], []
        for a in range(2):
            res, parts = ArmScreen(len(sub)), []
            for o in np.unique(objects[:, a]):
                sel = np.flatnonzero(objects[:, a] == o)
                c, r = screen_arm(ctx, t[sel], held, obj0[sel], windows[sel, a], a, int(o))
                res.put(sel, r)
                parts.append((sel, c))
            arms.append(res)
            cands.append(parts)
        _combine(out, idx[sub], arms, forearms(ctx, arms, cands, t), windows, objects)


def _window_objects(held: np.ndarray, windows: np.ndarray, traj: np.ndarray, kp: np.ndarray,
                    ko: np.ndarray) -> np.ndarray:
    """(E, 2) retargeting.window_objects of each episode (held (T, 2): the group's; traj (E, T, 2, 8) the
    smoothed poses, kp (E, K, 3) the keypoints at the start): the one object held in the window, if the hand
    closes on it within GRASP_REACH of its keypoints."""
    T = len(held)
    out = np.full(windows.shape[:2], -1)
    for a in range(2):
        objs = [int(o) for o in np.unique(held[:, a]) if o >= 0]
        if not objs:
            continue
        inside = np.stack([np.concatenate([[0], np.cumsum(held[:, a] == o)]) for o in objs], axis=1)
        w0, w1 = np.minimum(windows[:, a, 0], T), np.minimum(windows[:, a, 1], T)
        count = inside[w1] - inside[w0]  # (E, n_held) steps held inside the window
        one = (count > 0).sum(axis=1) == 1
        o = np.array(objs)[np.argmax(count > 0, axis=1)]
        first_held = np.flatnonzero(held[:, a] >= 0)  # the first held step inside each window
        close = first_held[np.minimum(np.searchsorted(first_held, w0), len(first_held) - 1)]
        hand = traj[np.arange(len(traj)), close, a, :3]
        near = np.full(len(traj), np.inf)
        for obj in objs:
            d = np.sqrt(((kp[:, ko == obj] - hand[:, None]) ** 2).sum(axis=-1)).min(axis=1)
            near = np.where(o == obj, d, near)
        out[:, a] = np.where(one & (near <= GRASP_REACH), o, -1)
    return out


def _combine(out: Screening, idx: np.ndarray, arms: list, forearms: tuple, windows: np.ndarray,
             objects: np.ndarray) -> None:
    """The episodes' verdicts from both arms and their forearms: the first cause by window step."""
    n = len(idx)
    gap, apart, slot = forearms
    feasible = np.stack([r.feasible for r in arms], axis=1)
    steps = np.stack([np.where(r.feasible, np.iinfo(np.int64).max, r.fail_step) for r in arms], axis=1)
    first = np.argmin(steps, axis=1)
    code = np.stack([r.reason for r in arms], axis=1)[np.arange(n), first]
    reason = np.where(feasible.all(axis=1), np.where(apart, "", "forearms_meet"),
                      np.array(REASONS, object)[np.where(code >= 0, code, 0)])
    margin = np.full((n, 2), np.inf)
    for a, r in enumerate(arms):
        m = np.where(r.feasible, r.wit_margin[np.arange(n), slot[:, a]], r.best_margin)
        margin[:, a] = np.where(r.active, m, np.inf)
        ok = r.active & r.feasible
        out.turn[idx, a] = np.where(ok, r.wit_turn[np.arange(n), slot[:, a]], np.nan)
        out.flip[idx, a] = ok & (slot[:, a] == 1)
    low = margin.min(axis=1)
    out.executable[idx] = feasible.all(axis=1) & apart
    out.reason[idx] = reason
    out.min_margin_rad[idx] = np.where(np.isfinite(low), low, np.nan)
    out.windows[idx], out.objects[idx], out.forearm_gap[idx] = windows, objects, gap
    out.arm_feasible[idx] = feasible


__all__ = ["CHUNK", "REASONS", "SCREEN_VERSION", "Screening", "episode_groups", "padded_actions", "screen_episodes",
           "warm_kernels"]
