"""Execute (n, 2, 8) gripper action sequences in MuJoCo with a robot of lib/sim/robots (the floating grippers, or
the ALOHA arms following a motion plan of the same actions).

    from demoforge.lib.sim import execute, execute_many, SimOptions
    r = execute("pouring", demo.placement.object_poses, demo.gripper_actions())
    r.success, r.failure, r.detail

Pipeline per episode: validate actions -> object poses (given, or estimated from the 11 object
keypoints by Kabsch against the task's local keypoints) -> reset the cached model's MjData ->
pre-roll (`preroll_s`, grippers held at the first pose, objects settle) -> for each action frame,
`ctrl_per_frame` control steps: mocap targets interpolated (positions linear or cubic, rotations
slerp: demoforge.lib.geometry.interpolate_poses), finger commands rate-limited to the gripper's speed, physics
substeps, contacts summarised (which finger touches which object, gripper-gripper, gripper-table
normal force) -> `settle_s` more seconds holding the last pose -> task predicate on the final state
and the per-frame object history -> failure classification (failures.py).  The frames themselves
run in loop.py, the one frame loop that the stepper (stepper.py) and the scripted replay (replay.py)
share.  With `stop_on_hard_failure` (default) the simulation stops at the first frame with an arm
collision, a table collision or a workspace exit: the episode has failed whatever follows, so the
remaining physics is skipped (the per-frame records end there and the predicate is not evaluated).  With
`stop_when_settled` (default) the settle phase ends once the scene is at rest under constant
commands (the state cannot change any more); the predicate is evaluated on that state.

Where the time goes (scripted demos, 1/480 s, mjData.timer; demoforge/bench/cases_sim.py breakdown): about
80-85 % in mj_step (per step: collision detection ~20 %, constraint construction ~15 %, the Newton
solver 25-45 %, the rest of the pipeline the remainder; ~1-2 solver iterations per step, 8-25
contacts) and 15-20 % in the frame loop's Python (loop.py: 4 control updates, 4 contact scans and one
record per 30 fps frame).  The per-step cost is set by the scenes (multi-geom containers, pouring's liquid
spheres), so the remaining levers are fewer steps (timestep: rejected, see PhysicsOptions), shorter
episodes (the early stops) and the Python share.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np

from demoforge.lib.geometry import interpolate_poses, umeyama, xyzw_to_wxyz

from .failures import FAILURES, classify
from .loop import FingerCommand, Records, contact_scan, frame_timing, preroll, record_frame, run_frames, settle
from .robots import PlanEvent, Robot
from .robots.grippers import GrippersRobot
from .scene import PhysicsOptions, SimScene, get_scene, robot_scene


@dataclass(frozen=True)
class SimOptions:
    robot: Robot = GrippersRobot()  # lib/sim/robots: the floating grippers, or the ALOHA arms (get_robot)
    physics: PhysicsOptions = PhysicsOptions()
    ctrl_per_frame: int = 4  # control (mocap / finger command) updates per action frame: 120 Hz at 30 fps
    position_interp: str = "linear"  # "linear" | "cubic"
    preroll_s: float = 0.3
    settle_s: float = 0.8  # after the last action, like Task.replay
    quat_tol: float = 1e-2  # | |q| - 1 | beyond this is an invalid action
    workspace_margin: float = 0.05  # m around task.workspace
    table_force_limit: float = 15.0  # N gripper-table normal force -> "table_collision"
    keep_trajectory: bool = True  # keep per-frame arrays in SimResult
    # stop simulating at the first frame with a hard failure (arm / table collision, left workspace):
    # the episode has failed whatever follows (failures.py); the per-frame records end there, events
    # list only what happened up to then, and predicate_ok is None (not evaluated)
    stop_on_hard_failure: bool = True
    # stop the settle phase (after the last action) once the scene is at rest: every free body's and
    # finger's translation speed below rest_speed (m/s) and every object's and gripper's rotation speed
    # below rest_spin (rad/s) for rest_frames consecutive frames, with the finger commands at their
    # goals. A scene at rest under constant commands stays at rest, so the predicate on that state is
    # the predicate at the end of settle_s (A/B on the scripted demos: identical outcomes and predicate
    # details, final object positions within 0.01 mm)
    stop_when_settled: bool = True
    rest_speed: float = 2e-3
    rest_spin: float = 0.05
    rest_frames: int = 3


@dataclass
class SimResult:
    task: str
    success: bool
    failure: str | None  # None on success, else one of failures.FAILURES
    detail: str
    predicate_ok: bool | None
    predicate_detail: str
    duration_s: float  # simulated seconds (pre-roll + actions + settle)
    physics_steps: int
    wall_s: float
    n_frames: int
    events: list = field(default_factory=list)  # [(time_s, failure, detail)] all detected, earliest first
    # per recorded frame (action frames + settle frames), when keep_trajectory:
    gripper_poses: np.ndarray | None = None  # (T, 2, 8) actual pinch pose [x y z qx qy qz qw width_m]
    object_poses: np.ndarray | None = None  # (T, n_obj, 4, 4)
    touch: np.ndarray | None = None  # (T, 2 arms, 3 parts (left finger, right finger, palm), n_obj) bool
    arm_contact: np.ndarray | None = None  # (T,) bool
    table_force: np.ndarray | None = None  # (T, 2) max gripper-table normal force, N
    command_g: np.ndarray | None = None  # (T, 2) commanded g per frame
    robot: dict = field(default_factory=dict)  # the robot's per-episode figures (arms: the IK residual)

    def row(self) -> dict:
        """Flat summary (no arrays), e.g. for a table."""
        return {"task": self.task, "success": self.success, "failure": self.failure, "detail": self.detail,
                "predicate_ok": self.predicate_ok, "predicate_detail": self.predicate_detail,
                "duration_s": self.duration_s, "physics_steps": self.physics_steps, "wall_s": self.wall_s,
                "n_frames": self.n_frames, **self.robot}

    def strip(self) -> "SimResult":
        return replace(self, gripper_poses=None, object_poses=None, touch=None, arm_contact=None,
                       table_force=None, command_g=None)


# ------------------------------------------------------------------ validation and inputs
def validate_actions(actions, quat_tol: float = 1e-2) -> str | None:
    """None if valid, else a human-readable reason."""
    try:
        a = np.asarray(actions, dtype=np.float64)
    except (TypeError, ValueError) as e:
        return f"actions not numeric: {e}"
    if a.ndim != 3 or a.shape[1:] != (2, 8):
        return f"actions must have shape (n, 2, 8), got {a.shape}"
    if a.shape[0] < 1:
        return "empty action sequence"
    bad = ~np.isfinite(a)
    if bad.any():
        t, arm, c = np.argwhere(bad)[0]
        return f"non-finite value in {int(bad.sum())} entries (first: step {t}, arm {arm}, column {c})"
    n = np.linalg.norm(a[..., 3:7], axis=-1)
    off = np.abs(n - 1.0)
    if (off > quat_tol).any():
        t, arm = np.argwhere(off > quat_tol)[0]
        return (f"non-unit quaternion in {int((off > quat_tol).sum())} poses (first: step {t}, arm {arm}, "
                f"|q| = {n[t, arm]:.4f}, tolerance {quat_tol})")
    g = a[..., 7]
    if ((g < -0.01) | (g > 1.01)).any():
        return f"gripper state g outside [0, 1] (min {g.min():.3f}, max {g.max():.3f})"
    return None


def object_poses_from_keypoints(task, keypoints: np.ndarray) -> np.ndarray:
    """(n_obj, 4, 4) object poses from the task's (k, 3) world keypoints (Kabsch, no scale)."""
    kp = np.asarray(keypoints, float)
    local = task.keypoints_local
    owner = task.keypoint_object
    out = np.tile(np.eye(4), (len(task.objects), 1, 1))
    for k in range(len(task.objects)):
        idx = owner == k
        _, R, t = umeyama(local[idx], kp[idx], with_scale=False)
        out[k, :3, :3] = R
        out[k, :3, 3] = t
    return out


def as_object_poses(task, poses_or_keypoints) -> np.ndarray:
    x = np.asarray(poses_or_keypoints, float)
    n_obj = len(task.objects)
    if x.shape == (n_obj, 4, 4):
        return x
    if x.shape == (len(task.keypoint_names), 3):
        return object_poses_from_keypoints(task, x)
    raise ValueError(f"expected object poses ({n_obj}, 4, 4) or keypoints ({len(task.keypoint_names)}, 3), "
                     f"got {x.shape}")


def _invalid(task_name: str, detail: str, t0: float) -> SimResult:
    return SimResult(task_name, False, "invalid_action", detail, None, "", 0.0, 0, time.perf_counter() - t0, 0,
                     events=[(0.0, "invalid_action", detail)])


# ------------------------------------------------------------------ one episode
def execute(task_name: str, object_poses_or_keypoints, actions, fps: float = 30.0,
            options: SimOptions | None = None, on_frame: Callable[[Any], None] | None = None) -> SimResult:
    """Run one episode; never raises for bad actions or object input (-> failure "invalid_action").
    ``on_frame``: called with the MjData at every recorded frame (a renderer keeps qpos, the benchmark
    counts contacts); it must not change the data."""
    t_wall = time.perf_counter()
    opt = options or SimOptions()
    reason = validate_actions(actions, opt.quat_tol)
    if reason is None and not (np.isfinite(fps) and fps > 0):
        reason = f"fps must be positive, got {fps}"
    sc = get_scene(task_name, opt.robot, opt.physics)
    if reason is None:
        try:
            obj0 = as_object_poses(sc.task, object_poses_or_keypoints)
            if not np.isfinite(obj0).all():
                raise ValueError("object poses contain non-finite values")
        except ValueError as e:
            reason = f"bad object input: {e}"
    if reason is not None:
        return _invalid(task_name, reason, t_wall)
    return _run(sc, obj0, np.asarray(actions, float), float(fps), opt, t_wall, on_frame)


@dataclass
class _Schedule:
    """An episode's timing and targets at control rate (shared by every robot)."""
    steps_per_frame: int
    cpf: int  # control steps per action frame
    sub: list  # physics steps of each control step of a frame
    dt_ctrl: float
    pos: np.ndarray  # (n, 2, 3) pinch targets per action frame
    quat: np.ndarray  # (n, 2, 4) unit xyzw
    closed_cmd: np.ndarray  # (n, 2) close commands, issued close_lead_s early
    targets_pos: np.ndarray  # ((n - 1) * cpf, 2, 3) interpolated at control rate
    targets_wxyz: np.ndarray  # ((n - 1) * cpf, 2, 4)
    settle_frames: int


def _schedule(actions: np.ndarray, fps: float, opt: SimOptions, spec, timestep: float) -> _Schedule:
    n = actions.shape[0]
    steps_per_frame, cpf, sub = frame_timing(fps, timestep, opt.ctrl_per_frame)
    pos = actions[..., :3]
    quat = actions[..., 3:7] / np.linalg.norm(actions[..., 3:7], axis=-1, keepdims=True)
    closed_cmd = actions[..., 7] < 0.5  # (n, 2)
    lead = int(round(spec.close_lead_s * fps))
    if lead > 0 and n > 1:  # issue each close `lead` frames early (gripper.py, mapping)
        early = closed_cmd.copy()
        for a in range(2):
            onsets = np.flatnonzero(closed_cmd[1:, a] & ~closed_cmd[:-1, a]) + 1
            for o in onsets:
                early[max(0, o - lead):o, a] = True
        closed_cmd = early
    K = (n - 1) * cpf
    if n > 1:
        tq = (np.arange(1, K + 1)) / cpf  # in frames
        tp, tqu = interpolate_poses(np.arange(n, dtype=float), pos, quat, tq, rotation="slerp",
                                    position=opt.position_interp)
    else:
        tp, tqu = pos[:0], quat[:0]
    return _Schedule(steps_per_frame, cpf, sub, 1.0 / (fps * cpf), pos, quat, closed_cmd, tp,
                     xyzw_to_wxyz(tqu), int(round(opt.settle_s * fps)))


def _run(sc: SimScene, obj0: np.ndarray, actions: np.ndarray, fps: float, opt: SimOptions, t_wall: float,
         on_frame: Callable[[Any], None] | None = None) -> SimResult:
    """The episode on the robot's plan through the frame loop (loop.py): reset, pre-roll, action frames,
    settle phase, verdict."""
    m = sc.model
    spec = sc.spec
    execution = sc.binding.prepare(sc, obj0, actions, fps, until_failure=opt.stop_on_hard_failure)  # robots/base.py
    actions = execution.actions
    n = actions.shape[0]
    sch = _schedule(actions, fps, opt, spec, opt.physics.timestep)
    m.opt.timestep = 1.0 / (fps * sch.steps_per_frame)
    plan = sc.binding.plan(sc, execution, sch.quat, sch.targets_pos, sch.targets_wxyz, sch.cpf, fps)
    plan_events = sorted(plan.events + _stroke_events(sc, obj0, sch, fps), key=lambda e: e.frame)
    fc = FingerCommand(spec, sch.closed_cmd[0], sch.dt_ctrl)
    pose0 = np.concatenate([sch.pos[0], sch.quat[0]], axis=-1)
    sc.reset(obj0, pose0, np.where(sch.closed_cmd[0], 0.0, spec.opening), plan)
    pre = preroll(sc, opt.preroll_s)
    T = n + sch.settle_frames
    rec = Records(sc, T, opt, min((e.frame for e in plan_events), default=None))
    contacts = contact_scan(sc, rec)
    closed = [tuple(r) for r in sch.closed_cmd.tolist()]  # per action frame, Python bools
    record_frame(sc, rec, 0, on_frame)
    # stop: the frame a hard failure stopped the simulation at (stop_on_hard_failure); settled: the frame
    # the settle phase ended at rest (stop_when_settled)
    stop = run_frames(sc, rec, opt, sch.sub, closed, sch.targets_pos, fc, contacts, plan.apply, n, on_frame)
    settled = None
    if stop is None:
        stop, settled, last = settle(sc, rec, opt, sch.sub, closed[-1], sch.pos[-1], fc, contacts, n, T, on_frame)
    else:
        last = stop
    steps = pre + last * sch.steps_per_frame
    return _finish(sc, opt, fps, n, sch, plan, plan_events, rec, stop, settled, steps, t_wall)


def _stroke_events(sc: SimScene, obj0: np.ndarray, sch: _Schedule, fps: float) -> list[PlanEvent]:
    """`wider_than_stroke` where a hand closes on an object it cannot open around: the object nearest
    (by its keypoints at the episode's start) to where the hand closes, whose grasp width is not less
    than the hand's opening. Objects narrower than the opening (every object for the 2F-140): none."""
    opening = sc.spec.opening
    widths = sc.task.grasp_widths
    if (widths < opening).all():
        return []
    kp = sc.task.keypoints_world(obj0)
    owner = sc.task.keypoint_object
    closed = sch.closed_cmd
    n = len(closed)
    lead = int(round(sc.spec.close_lead_s * fps))
    events = []
    for arm in range(2):
        onsets = np.flatnonzero(np.concatenate([closed[:1, arm], closed[1:, arm] & ~closed[:-1, arm]]))
        for o in onsets.tolist():
            at = sch.pos[min(o + lead, n - 1), arm]  # where the hand is when g switches to closed
            k = int(owner[np.argmin(np.linalg.norm(kp - at, axis=1))])
            if widths[k] >= opening:
                events.append(PlanEvent(o, "wider_than_stroke",
                                        f"arm {arm} closes on the {sc.task.object_names[k]} at t = {o / fps:.2f} s: "
                                        f"it is {widths[k] * 1000:.0f} mm wide where grasped, the hand opens "
                                        f"{opening * 1000:.0f} mm"))
    return events


def _finish(sc, opt, fps, n, sch, plan, plan_events, rec, stop, settled, steps, t_wall) -> SimResult:
    """The predicate (unless a hard failure stopped the simulation) and the verdict."""
    m, d = sc.model, sc.data
    closed_cmd = sch.closed_cmd
    g_cmd = np.concatenate([(~closed_cmd).astype(float),
                            np.repeat((~closed_cmd[-1:]).astype(float), sch.settle_frames, 0)])
    last = stop if stop is not None else settled
    if last is not None:  # truncate the per-frame records where the simulation stopped
        rec.truncate(last)
        g_cmd = g_cmd[:last + 1]
    if stop is None:
        ok, pdetail = sc.task.success(m, d, rec.hist)
        ok = bool(ok)
    else:  # the predicate is not evaluated after a hard failure
        ok, pdetail = None, f"not evaluated: simulation stopped at t = {stop / fps:.2f} s after a hard failure"
    failure, detail, events = classify(sc, opt, fps, bool(ok), str(pdetail), rec.hist, rec.gp, rec.touch,
                                       rec.arm_contact, rec.table_force, g_cmd, n, rec.diag,
                                       link_contact=rec.link_contact, plan_events=plan_events)
    res = SimResult(sc.task.name, failure is None, failure, detail, ok, str(pdetail),
                    steps * m.opt.timestep, steps, time.perf_counter() - t_wall, n, events,
                    rec.gp, rec.hist, rec.touch, rec.arm_contact, rec.table_force, g_cmd, dict(plan.summary))
    return res if opt.keep_trajectory else res.strip()


def planned_execution(task_name: str, object_poses_or_keypoints, actions, fps: float = 30.0,
                      options: SimOptions | None = None):
    """What the robot executes of an episode (robots/base.py Execution), as execute() plans it, without physics."""
    opt = options or SimOptions()
    sc = get_scene(task_name, opt.robot, opt.physics)
    obj0 = as_object_poses(sc.task, object_poses_or_keypoints)
    return sc.binding.prepare(sc, obj0, np.asarray(actions, float), float(fps), until_failure=False)


def scene_fingerprint(task_name: str, options: SimOptions | None = None) -> str:
    """sha256 of what a task's simulation depends on besides the episode and the executor's code: the
    scene MJCF with the robot and the files it names (meshes), and every simulation option (robot,
    physics, control). A cache of results keyed by it goes stale by itself when a task's objects or the
    robot change."""
    import hashlib

    opt = options or SimOptions()
    xml, assets = robot_scene(task_name, opt.robot)
    h = hashlib.sha256(xml.encode())
    for name in sorted(assets):
        h.update(name.encode() + hashlib.sha256(assets[name]).digest())
    h.update(repr(replace(opt, keep_trajectory=False)).encode())
    h.update(opt.robot.settings(task_name).encode())
    return h.hexdigest()


# ------------------------------------------------------------------ many episodes
_WORKER_STATE: dict = {}


def _episode_args(ep) -> tuple[Any, Any, float]:
    if isinstance(ep, dict):
        objs = ep.get("object_poses")
        if objs is None:
            objs = ep.get("keypoints")
        return objs, ep["actions"], float(ep.get("fps", 30.0))
    if len(ep) == 3:
        return ep[0], ep[1], float(ep[2])
    return ep[0], ep[1], 30.0


def _work(job):
    idx, ep = job
    task_name, opt = _WORKER_STATE["task"], _WORKER_STATE["opt"]
    objs, acts, fps = _episode_args(ep)
    try:
        return idx, execute(task_name, objs, acts, fps, opt)
    except Exception as e:  # never lose a batch to one bad episode
        return idx, SimResult(task_name, False, "invalid_action", f"{type(e).__name__}: {e}", None, "", 0.0, 0,
                              0.0, 0, events=[(0.0, "invalid_action", str(e))])


def _init_worker(task_name, opt, in_pool: bool = False):
    if in_pool:
        # Forked workers inherit the parent's signal handlers (Prefect's raises on SIGTERM, which the
        # pool sends at shutdown); a worker just exits on SIGTERM and leaves Ctrl-C to the parent.
        import signal

        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER_STATE["task"] = task_name
    _WORKER_STATE["opt"] = opt
    get_scene(task_name, opt.robot, opt.physics)  # compile once per process


def execute_many(task_name: str, episodes: Sequence, workers: int = 2,
                 progress: Callable[[int, int], None] | None = None, options: SimOptions | None = None,
                 keep_trajectory: bool = False, chunksize: int = 4) -> list[SimResult]:
    """Execute episodes (each a dict {object_poses | keypoints, actions, fps?} or a tuple
    (object_poses_or_keypoints, actions[, fps])) over `workers` processes, each with its own cached
    compiled model; results in input order, identical for any worker count.  progress(done, total)
    is called in the calling process as results arrive."""
    opt = replace(options or SimOptions(), keep_trajectory=keep_trajectory)
    jobs = list(enumerate(episodes))
    total = len(jobs)
    out: list[SimResult | None] = [None] * total
    if workers <= 1 or total <= 1:
        _init_worker(task_name, opt)
        for done, job in enumerate(jobs, 1):
            i, r = _work(job)
            out[i] = r
            if progress:
                progress(done, total)
        return out  # type: ignore[return-value]
    import multiprocessing as mp

    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    with ctx.Pool(workers, initializer=_init_worker, initargs=(task_name, opt, True)) as pool:
        for done, (i, r) in enumerate(pool.imap_unordered(_work, jobs, chunksize=chunksize), 1):
            out[i] = r
            if progress:
                progress(done, total)
    return out  # type: ignore[return-value]


__all__ = ["SimOptions", "SimResult", "execute", "execute_many", "planned_execution", "scene_fingerprint",
           "validate_actions", "as_object_poses", "object_poses_from_keypoints", "FAILURES"]
