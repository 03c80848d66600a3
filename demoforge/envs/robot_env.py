"""A task of the library with a robot as a Gymnasium environment whose observations and actions are the
LeRobot export's features, and whose physics and verdict are the robot check's (demoforge.lib.sim).

    env = DemoforgeEnv("pouring", robot="aloha", gripper="2f140")     # or gymnasium.make(...): demoforge.envs
    obs, info = env.reset(seed=0, options={"protocol": "novel"})
    obs, reward, terminated, truncated, info = env.step(action)

**Action** (``action``, float32): for the arms the 14 joint values of the next frame, exactly the
joint-space export's ``action`` row (per arm, left first: six joint targets in rad, then the gripper,
1 open / 0 closed: the finger command, closed below 0.5); for the grippers the 16 pose values
``[x y z qx qy qz qw g]`` per arm. One step is one frame at the dataset's 30 fps: the executor's control
(4 updates per frame: the arms' joint targets interpolated from the last frame's with the velocity
feed-forward, the grippers' mocap poses interpolated, the force-limited finger command) and physics at
1/480 s (demoforge/lib/sim/stepper.py: the executor's own pieces, frame by frame).

**Observation**: ``observation.state`` (the export's 14 joint values or 16 pose values),
``observation.environment_state`` (the 11 object keypoints, 33 values) and, with ``images``,
``observation.images.top`` (``.camera`` for the grippers; RGB uint8 drawn as the export draws its video's
frames; camera default: the synthetic takes' head camera). ``observation="export"`` (default) gives them as
the export defines them, so the observation of an exported episode's step equals its row: the state is
the commanded frame (the
export writes the joints the arms were planned to run, and ``action[t] == observation.state[t + 1]``
holds here as there), the environment state the keypoints carried by the commanded pinch poses
(observation.py). ``observation="measured"`` gives the simulator's values instead: the arms' joint
positions and the gripper's measured opening (width / opening), the keypoints of the simulated objects.
Both are always in ``info`` (``measured_state``, ``object_keypoints``).

**Episode end and reward**: an episode ends (1) at a hard failure of the robot check (arm, link or table
collision, the workspace left, a hand closing on an object wider than it opens): ``terminated``;
(2) after ``max_steps`` steps (default 900 = 30 s; per episode ``options["max_steps"]``): the executor's
settle phase (holding the last command up to 0.8 s, ending early at rest), the task's success predicate
and the failure classification, exactly as ``execute`` ends an episode: ``terminated`` on success,
``truncated`` otherwise; (3) with ``check_success_every`` = k > 0, also when the predicate holds at a
k-th step: settle and verdict at once, ``terminated``. The reward is 1.0 at the step that ends an
episode with success, else 0. ``info``: ``success`` and ``failure`` (None until the verdict; then a
class of demoforge.lib.sim.failures.FAILURES, None on success), ``detail``, ``predicate_ok`` /
``predicate_detail`` (the predicate at the verdict, or at a checked step), ``events``, ``action_clipped``,
``frame``, and at the end ``result`` (the SimResult's row).

**Bad input**: an action of the wrong shape or not numeric raises ValueError (nothing is stepped); a
NaN or infinite value ends the episode with the recorded failure ``invalid_action`` (terminated, reward
0, the rollout goes on with reset()); a finite value outside the action space (a joint beyond its range,
g outside [0, 1]) is clipped to it and ``info["action_clipped"]`` says so; a grippers' quaternion is
normalised (a zero one is ``invalid_action``). A step after an episode's end raises ResetNeeded.

**Same physics as execute**: replaying an exported episode (:meth:`DemoforgeEnv.replay_actions`) gives
its robot check's verdict (driven with the float64 joints execute plans: its SimResult, bit for bit); the
one thing a step cannot do as execute does is the close lead (stepper.py: ``execute`` closes the fingers
0.3 s before the demonstrated g switches; replay_actions issues those commands). The gripper command is
an action like the joints: a policy closes when it wants the fingers to start closing.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import mujoco
import numpy as np
from gymnasium import spaces

from demoforge.envs.observation import ENV_STATE, IMAGE_PREFIX, STATE, CarriedKeypoints, export_features
from demoforge.envs.scenes import PROTOCOLS, draw_scene, scripted_source
from demoforge.lib.exports import POSE16_NAMES, STEPS_PER_SECOND
from demoforge.lib.geometry import matrix_to_quat
from demoforge.lib.sim import SimOptions, as_object_poses
from demoforge.lib.sim.render import pinhole_gl_camera
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.sim.robots.aloha.model import REST
from demoforge.lib.sim.stepper import EpisodeStepper, close_commands
from demoforge.lib.synth.render import HEIGHT, WIDTH, camera_K, camera_T_world_camera

OBSERVATIONS = ("export", "measured")
RESET_OPTIONS = ("protocol", "scene", "object_poses", "keypoints", "state", "joints", "max_steps", "source")
CAMERA_KEYS = {True: "top", False: "camera"}  # the export's video key: an arm robot's `top`, the grippers' `camera`
ROOM = 10.0  # m: the bound of every position in an observation (the scene's floor is 6 x 6 m)
MEASURED_SLACK = 0.5  # rad a measured joint may lie past its range (the servos' command range is that much wider)


class DemoforgeEnv(gymnasium.Env):
    """See the module docstring. task: a task of the library; robot, gripper: as ``--robot`` / ``--gripper``;
    protocol: the default scene protocol of reset (``novel`` | ``thesis``); demo_seed, mirrored_fraction,
    generation: the thesis protocol's demonstration and database (scenes.py); camera: {K, T_world_camera,
    width, height} of the rendered image (default the synthetic head camera, 640 x 480)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": STEPS_PER_SECOND}

    def __init__(self, task: str = "pouring", robot: str = "aloha", gripper: str | None = None, *,
                 protocol: str = "novel", observation: str = "export", images: bool = False,
                 camera: dict | None = None, max_steps: int = 900, check_success_every: int = 0,
                 render_mode: str | None = None, demo_seed: int = 0, mirrored_fraction: float = 0.5,
                 generation: dict | None = None):
        if protocol not in PROTOCOLS:
            raise ValueError(f"unknown protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS)}, got {observation!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if int(max_steps) < 1 or int(check_success_every) < 0:
            raise ValueError(f"need max_steps >= 1 and check_success_every >= 0, got {max_steps}, {check_success_every}")
        self.robot = get_robot(robot, gripper)
        self.fps = float(STEPS_PER_SECOND)
        self.stepper = EpisodeStepper(task, SimOptions(robot=self.robot), self.fps)
        self.sc = self.stepper.sc
        self.task = self.sc.task
        self.arms = bool(self.robot.joint_names)
        self.protocol, self.observation, self.images, self.render_mode = protocol, observation, bool(images), render_mode
        self.max_steps, self.check_success_every = int(max_steps), int(check_success_every)
        self.source = scripted_source(self.task, demo_seed)
        self.mirrored_fraction, self.generation = float(mirrored_fraction), dict(generation or {})
        self.camera = self._camera(camera)
        self.state_names = tuple(self.robot.joint_names) if self.arms else POSE16_NAMES
        self.image_key = IMAGE_PREFIX + CAMERA_KEYS[self.arms]
        image = (CAMERA_KEYS[self.arms], self.camera["width"], self.camera["height"]) if self.images else None
        self.features = export_features(self.task.keypoint_names, self.state_names, image)
        self._bounds()
        self.carried = CarriedKeypoints(self.task.keypoint_object)
        if self.arms:  # the planner's forward kinematics (ik.ArmsIK.fk, as arm_motion computes the poses) on its own data
            arm_robot: Any = self.robot  # an arm robot (AlohaRobot): its IK's kinematic model
            ik = arm_robot.ik(self.task.name)
            self._fk = (ik.model, mujoco.MjData(ik.model), ik.sites)
        self._renderer: Any = None
        self._ended = True

    # ------------------------------------------------------------------ spaces
    def _camera(self, camera: dict | None) -> dict[str, Any]:
        c: dict[str, Any] = {"K": camera_K(), "T_world_camera": camera_T_world_camera(), "width": WIDTH, "height": HEIGHT}
        c.update(camera or {})
        c["K"], c["T_world_camera"] = np.asarray(c["K"], float), np.asarray(c["T_world_camera"], float)
        c["width"], c["height"] = int(c["width"]), int(c["height"])
        if c["K"].shape != (3, 3) or c["T_world_camera"].shape != (4, 4) or min(c["width"], c["height"]) < 1:
            raise ValueError("camera needs K (3, 3), T_world_camera (4, 4) and a positive width and height")
        return c

    def _bounds(self) -> None:
        """The action space (the joints' ranges, g in [0, 1]; the grippers: the workspace with its margin,
        quaternion components in [-1, 1]) and the observation space (the export's features)."""
        m, mj = self.sc.model, self.sc.mj
        if self.arms:
            lo, hi = np.zeros(14), np.ones(14)
            for k, name in enumerate(self.state_names):
                if not name.endswith("_gripper"):
                    lo[k], hi[k] = m.jnt_range[mj.mj_name2id(m, mj.mjtObj.mjOBJ_JOINT, name)]
            self.gripper_cols = [6, 13]
        else:
            margin = SimOptions().workspace_margin
            ws = self.sc.workspace + np.array([[-margin], [margin]])
            arm_lo = np.concatenate([ws[0], -np.ones(4), [0.0]])
            arm_hi = np.concatenate([ws[1], np.ones(4), [1.0]])
            lo, hi = np.tile(arm_lo, 2), np.tile(arm_hi, 2)
            self.gripper_cols = [7, 15]
        self.low, self.high = lo, hi
        self.action_space = spaces.Box(lo.astype(np.float32), hi.astype(np.float32), dtype=np.float32)
        if self.observation == "measured":  # what the simulator may show: a joint a little past its range
            if self.arms:
                slack = np.where(np.isin(np.arange(len(lo)), self.gripper_cols), 0.0, MEASURED_SLACK)
                lo, hi = lo - slack, hi + slack
            else:  # a gripper's measured position: anywhere in the room
                pos = np.isin(np.arange(len(lo)), [0, 1, 2, 8, 9, 10])
                lo, hi = np.where(pos, -ROOM, lo), np.where(pos, ROOM, hi)
        n_kp = 3 * len(self.task.keypoint_names)
        obs: dict[str, spaces.Space] = {STATE: spaces.Box(lo.astype(np.float32), hi.astype(np.float32), dtype=np.float32),
               ENV_STATE: spaces.Box(-ROOM, ROOM, (n_kp,), np.float32)}
        if self.images:
            obs[self.image_key] = spaces.Box(0, 255, (self.camera["height"], self.camera["width"], 3), np.uint8)
        self.observation_space = spaces.Dict(obs)

    # ------------------------------------------------------------------ frames
    def _pose(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(the commanded pinch poses with g (2, 8), the arms' 12 joints or None) of a state/action vector."""
        if not self.arms:
            return state.reshape(2, 8).copy(), None
        joints = np.concatenate([state[0:6], state[7:13]])
        m, d, sites = self._fk
        d.qpos[:] = joints
        mujoco.mj_kinematics(m, d)
        pos, R = d.site_xpos[sites], d.site_xmat[sites].reshape(2, 3, 3)
        g = state[self.gripper_cols]
        return np.concatenate([pos, matrix_to_quat(R), g[:, None]], axis=-1), joints

    @staticmethod
    def _physics_pose(pose: np.ndarray) -> np.ndarray | None:
        """The pose the simulator gets (it normalises the quaternions, as execute does); None for a zero one."""
        return None if (np.linalg.norm(pose[:, 3:7], axis=-1) < 1e-9).any() else pose

    def _parse(self, action: Any) -> tuple[np.ndarray | None, bool, str]:
        """(the clipped action as float64, or None when it is invalid; clipped; the reason it is invalid)."""
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(f"the action must be numeric: {e}") from None
        if a.shape != self.low.shape:
            raise ValueError(f"the action must have shape {self.low.shape} ({', '.join(self.state_names[:3])}, ...: "
                             f"{'the 14 joint values' if self.arms else 'the 16 pose values'} of the next frame), "
                             f"got {a.shape}")
        bad = ~np.isfinite(a)
        if bad.any():
            cols = [self.state_names[k] for k in np.flatnonzero(bad)]
            more = f" and {len(cols) - 3} more" if len(cols) > 3 else ""
            return None, False, f"non-finite action value in {', '.join(cols[:3])}{more}"
        c = np.clip(a, self.low, self.high)
        return c, bool(np.abs(c - a).max() > 1e-6), ""

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """A new episode. options: ``protocol`` (thesis | novel: draw a scene), ``scene`` (a drawn scene: a dict
        with ``object_poses`` or ``keypoints``, e.g. QueryScenes.scene(i)), ``object_poses`` ((n_obj, 4, 4) or
        the (K, 3) keypoints), ``state`` / ``joints`` (the first frame: an export's observation.state row;
        default the arms' ready pose with open grippers, the grippers' demonstrated start), ``max_steps``,
        ``source`` (the thesis protocol's DemoSource)."""
        super().reset(seed=seed)
        opts = dict(options or {})
        unknown = sorted(set(opts) - set(RESET_OPTIONS))
        if unknown:
            raise ValueError(f"unknown reset options {unknown}; known: {', '.join(RESET_OPTIONS)}")
        scene = self._scene(opts)
        obj0 = as_object_poses(self.task, scene["object_poses"] if scene.get("object_poses") is not None
                               else scene["keypoints"])
        kp0 = self.task.keypoints_world(obj0) if scene.get("keypoints") is None else np.asarray(scene["keypoints"], float)
        if kp0.shape != (len(self.task.keypoint_names), 3) or not np.isfinite(kp0).all():
            raise ValueError(f"keypoints must be ({len(self.task.keypoint_names)}, 3) finite values, got {kp0.shape}")
        state0 = self._initial_state(opts, scene)
        max_steps = int(opts.get("max_steps", self.max_steps))
        if max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        pose, joints = self._pose(state0)
        physics_pose = self._physics_pose(pose)
        if physics_pose is None:
            raise ValueError("the initial state has a zero quaternion")
        self.stepper.reset(obj0, physics_pose, joints, max_frames=max_steps + 1)
        self.max_frames, self.t, self._ended = max_steps + 1, 0, False
        self.state = state0
        self.scene_info = {k: v for k, v in scene.items() if k in ("protocol", "mirrored")}
        self.kp = self.carried.reset(kp0, pose)
        self.measured = self._measured()
        self.verdict: dict = {}
        return self._observe(), self._info(False)

    def _scene(self, opts: dict) -> dict:
        if "object_poses" in opts or "keypoints" in opts:
            poses = opts.get("object_poses")
            if poses is not None and np.shape(poses) == (len(self.task.keypoint_names), 3):
                return {"object_poses": None, "keypoints": poses, "protocol": None}  # keypoints given as object_poses
            return {"object_poses": poses, "keypoints": opts.get("keypoints"), "protocol": None}
        if "scene" in opts:
            s = dict(opts["scene"])
            if s.get("object_poses") is None and s.get("keypoints") is None:
                raise ValueError("options['scene'] needs object_poses or keypoints")
            return {**s, "protocol": s.get("protocol")}
        return draw_scene(self.task, opts.get("protocol", self.protocol), self.np_random,
                          opts.get("source", self.source), self.mirrored_fraction, self.generation)

    def _initial_state(self, opts: dict, scene: dict) -> np.ndarray:
        given = opts.get("state", opts.get("joints"))
        if given is None:
            if self.arms:  # the arms' ready pose (where every episode they execute starts), the grippers open
                return np.array([*REST, 1.0, *REST, 1.0])
            return np.asarray(scene.get("initial", self.source.trajectory[0]), float).reshape(16)
        state, clipped, reason = self._parse(given)
        if state is None:
            raise ValueError(f"the initial state: {reason}")
        return state

    def step(self, action):
        if self._ended:
            raise gymnasium.error.ResetNeeded("the episode has ended (or was never started): call reset()")
        a, clipped, reason = self._parse(action)
        physics_pose = None
        if a is not None:
            pose, joints = self._pose(a)
            physics_pose = self._physics_pose(pose)
            reason = reason or "zero quaternion in the action"
        if physics_pose is None:  # recorded, not raised: the rollout loop goes on with reset()
            self._ended = True
            self.verdict = {"success": False, "failure": "invalid_action", "detail": reason, "predicate_ok": None,
                            "predicate_detail": "", "events": [(self.t / self.fps, "invalid_action", reason)]}
            return self._observe(), 0.0, True, False, self._info(clipped)
        stopped = self.stepper.step(physics_pose, joints)
        self.t += 1
        self.state = a
        self.kp = self.carried.update(pose)
        self.measured = self._measured()  # before finish(), which may cut the records back to a stop
        obs = self._observe()
        end, terminated = stopped, stopped
        predicate = None
        if not end and self.check_success_every and self.t % self.check_success_every == 0:
            predicate = self.stepper.predicate()
            end = terminated = predicate[0]
        if not end and self.t + 1 >= self.max_frames:
            end = True
        reward, truncated = 0.0, False
        if end:
            res = self.stepper.finish()
            self._ended = True
            self.verdict = {"success": res.success, "failure": res.failure, "detail": res.detail,
                            "predicate_ok": res.predicate_ok, "predicate_detail": res.predicate_detail,
                            "events": list(res.events), "result": res.row()}
            reward = 1.0 if res.success else 0.0
            terminated = terminated or res.success
            truncated = not terminated
        info = self._info(clipped)
        if predicate is not None and not end:
            info["predicate_ok"], info["predicate_detail"] = predicate
        return obs, reward, bool(terminated), bool(truncated), info

    # ------------------------------------------------------------------ observation, info, rendering
    def _measured(self) -> tuple[np.ndarray, np.ndarray]:
        """(the simulator's state vector: joints and measured openings, or the pinch poses with them; the
        simulated objects' keypoints (K, 3)) at the last frame."""
        rec, i, spec = self.stepper.rec, self.stepper.n - 1, self.sc.spec
        opening = np.clip(rec.gp[i, :, 7] / spec.opening, 0.0, 1.0)
        if self.arms:
            binding: Any = self.sc.binding  # an arm robot's binding (AlohaBinding): its joints' qpos addresses
            q = self.sc.data.qpos[binding.arm_qadr]
            state = np.concatenate([q[:6], opening[:1], q[6:], opening[1:]])
        else:
            gp = rec.gp[i].copy()
            gp[:, 7] = opening
            state = gp.reshape(16)
        return state, self.task.keypoints_world(rec.hist[i])

    def _observe(self) -> dict:
        if self.observation == "export":
            obs = {STATE: self.state.astype(np.float32), ENV_STATE: self.kp.reshape(-1).astype(np.float32)}
        else:
            state, kp = self.measured
            obs = {STATE: state.astype(np.float32), ENV_STATE: kp.reshape(-1).astype(np.float32)}
        if self.images:
            obs[self.image_key] = self._render_image()
        return obs

    def _info(self, clipped: bool) -> dict:
        state, kp = self.measured
        v = self.verdict
        info = {"frame": self.t, "time_s": self.t / self.fps, "action_clipped": clipped,
                "success": v.get("success"), "failure": v.get("failure"), "detail": v.get("detail", ""),
                "predicate_ok": v.get("predicate_ok"), "predicate_detail": v.get("predicate_detail", ""),
                "events": v.get("events", []), "measured_state": state.astype(np.float32),
                "object_keypoints": kp.reshape(-1).astype(np.float32), **self.scene_info}
        if "result" in v:
            info["result"] = v["result"]
        return info

    def _render_image(self) -> np.ndarray:
        """The scene now, drawn as the export draws its video (lib/sim/render.py episode_frames): the state's
        positions (qpos) on a data of its own, shadows and reflections off, the pinhole camera."""
        c = self.camera
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.sc.model, height=c["height"], width=c["width"])
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
            self._render_data = mujoco.MjData(self.sc.model)
        r, d = self._renderer, self._render_data
        d.qpos[:] = self.sc.data.qpos  # not the simulation's own data: its derived values are a substep old
        mujoco.mj_forward(self.sc.model, d)
        r.update_scene(d)
        for cam in r.scene.camera:
            pinhole_gl_camera(cam, c["K"], c["T_world_camera"], c["width"], c["height"])
        return r.render().copy()

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self._render_image()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()

    # ------------------------------------------------------------------ replaying an export
    def replay_actions(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the first state, the actions (m - 1, D)) that replay an exported episode's observation.state rows
        states (m, D) with the physics of its robot check: the rows as they are, the gripper columns turned into
        the close commands execute issues (each close close_lead_s before the demonstrated g switches;
        stepper.close_commands). Reset with ``options={"state": first, "keypoints": ...}`` and
        ``max_steps=m - 1``, then step through the actions: the verdict is ``execute``'s."""
        s = np.asarray(states, np.float64).copy()
        if s.ndim != 2 or s.shape[1] != len(self.low) or len(s) < 1:
            raise ValueError(f"states must be (m, {len(self.low)}) rows of observation.state, got {s.shape}")
        closed = close_commands(s[:, self.gripper_cols], self.stepper.lead)
        s[:, self.gripper_cols] = np.where(closed, 0.0, 1.0)
        return s[0], s[1:]


__all__ = ["DemoforgeEnv", "OBSERVATIONS", "RESET_OPTIONS", "CAMERA_KEYS"]
