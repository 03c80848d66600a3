"""The closed-loop policy: action chunks from the current joints and the objects' state, in the style of
ACT (Zhao et al. 2023: a Transformer predicts the next `chunk` actions at every step; the overlapping
chunks are averaged with exponential weights, "temporal ensembling").

Inputs, exactly the export's features at one frame: ``observation.state`` (14 joint values, the gripper
columns 1 open / 0 closed), ``observation.environment_state`` (11 object keypoints) and the frame's
timestamp (the LeRobot dataset's ``timestamp`` column). Encoder tokens: one for the state with the time,
one per keypoint (its normalised xyz plus a learned index embedding). Head: the encoded tokens, flattened,
through a two-layer MLP to the whole chunk: per future step the joints' change from the current state
(normalised: the arms' ready pose and a pour's far end are both in the data, so absolute targets let the
first steps of a chunk jump) and the grippers' "open" logits. An MLP head instead of ACT's query decoder:
the decoder costs five times the training time on a CPU for the same validation loss.

No CVAE latent (ACT's style variable): a database is one demonstration carried to many placements, so the
actions are a function of the state and the scene, not a distribution over styles of several people.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import mujoco
import numpy as np
import torch
from torch import nn

from demoforge.lib.policy.joint_demos import GRIPPER_COLUMNS
from demoforge.lib.sim.robots import resolve_robot

PINCH_SCALE = 0.3  # m: the scale of the pinch points and of the keypoints relative to them
DELTA_FLOOR = 1e-3  # rad: the smallest scale of a joint's change over a horizon
STD_FLOOR = 1e-2  # a joint or keypoint coordinate that never moves in the data is scaled as if it moved 1 cm / rad


@dataclass(frozen=True)
class ChunkConfig:
    state_dim: int = 14
    n_keypoints: int = 11
    chunk: int = 30          # future steps predicted per query (1 s at 30 fps)
    d_model: int = 64
    n_heads: int = 4
    enc_layers: int = 2
    ff_dim: int = 128
    head_dim: int = 512
    time_scale_s: float = 20.0  # the timestamp input is t / time_scale_s
    use_time: bool = True       # without it the grippers open and close at the wrong moments
    pinch_features: bool = True  # also the hands' pinch points (forward kinematics of the state) and each keypoint
    robot: str = "aloha+2f140"   # relative to them: the approach becomes "move the hand to the keypoint"
    task: str = "pouring"        # (robot, task: whose kinematic model the forward kinematics use)

    def __post_init__(self):
        if self.d_model % self.n_heads:
            raise ValueError(f"d_model ({self.d_model}) must be a multiple of n_heads ({self.n_heads})")
        if self.chunk < 1 or self.n_keypoints < 1 or self.state_dim < 1:
            raise ValueError("need chunk, n_keypoints and state_dim >= 1")

    def to_dict(self) -> dict:
        return asdict(self)


def joint_columns(state_dim: int) -> np.ndarray:
    """The columns of a state that are joints (normalised), not grippers (0/1)."""
    return np.setdiff1d(np.arange(state_dim), GRIPPER_COLUMNS)


class ChunkPolicy(nn.Module):
    """(state (B, 14), time (B,) s, keypoints (B, K, 3)) in world units -> raw chunk (B, chunk, 14): the joints'
    normalised change from the state, the grippers' open logits."""

    def __init__(self, config: ChunkConfig):
        super().__init__()
        c = self.config = config
        d = c.d_model
        self.joints = torch.as_tensor(joint_columns(c.state_dim))
        self.grippers = torch.as_tensor(GRIPPER_COLUMNS)
        for name, shape in (("state_mean", (c.state_dim,)), ("state_std", (c.state_dim,)), ("delta_std", (c.chunk, c.state_dim)),
                            ("kp_mean", (c.n_keypoints, 3)), ("kp_std", (c.n_keypoints, 3))):
            self.register_buffer(name, torch.zeros(shape) if name.endswith("mean") else torch.ones(shape))
        extra = 6 if c.pinch_features else 0
        self.state_embed = nn.Linear(c.state_dim + 1 + extra, d)
        self.kp_embed = nn.Linear(3 + extra, d)
        self._fk = None
        self.kp_index = nn.Parameter(torch.randn(c.n_keypoints, d) * 0.02)
        enc = nn.TransformerEncoderLayer(d, c.n_heads, c.ff_dim, dropout=0.0, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(enc, c.enc_layers, enable_nested_tensor=False)
        self.head = nn.Sequential(nn.LayerNorm((c.n_keypoints + 1) * d), nn.Linear((c.n_keypoints + 1) * d, c.head_dim),
                                  nn.GELU(), nn.Linear(c.head_dim, c.chunk * c.state_dim))

    def fit_normalizer(self, states: np.ndarray, keypoints: np.ndarray, delta_rms: np.ndarray) -> None:
        """Means and scales from the training frames: states (F, 14), keypoints (F, K, 3), the root mean square
        of the targets' changes from their frame's state per future step (chunk, 14); the gripper columns stay as
        they are (0/1)."""
        s, k = np.asarray(states, np.float64), np.asarray(keypoints, np.float64)
        mean, std = s.mean(0), np.maximum(s.std(0), STD_FLOOR)
        # per future step: the next frame's change is as important as the one a second ahead, not 30 times smaller
        dstd = np.maximum(np.asarray(delta_rms, np.float64), DELTA_FLOOR)
        g = list(GRIPPER_COLUMNS)
        mean[g], std[g], dstd[:, g] = 0.0, 1.0, 1.0
        self.delta_std.copy_(torch.as_tensor(dstd, dtype=torch.float32))
        self.state_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.state_std.copy_(torch.as_tensor(std, dtype=torch.float32))
        self.kp_mean.copy_(torch.as_tensor(k.mean(0), dtype=torch.float32))
        self.kp_std.copy_(torch.as_tensor(np.maximum(k.std(0), STD_FLOOR), dtype=torch.float32))

    def normalize_state(self, state: torch.Tensor) -> torch.Tensor:
        return (state - self.state_mean) / self.state_std

    def encode(self, state: torch.Tensor, time_s: torch.Tensor, keypoints: torch.Tensor,
               pinch: torch.Tensor | None = None) -> torch.Tensor:
        """The encoded tokens (B, 1 + K, d); pinch (B, 2, 3): the hands' pinch points, with ``pinch_features``."""
        c = self.config
        s = [self.normalize_state(state), (time_s / c.time_scale_s)[:, None] * float(c.use_time)]
        k = [(keypoints - self.kp_mean) / self.kp_std]
        if c.pinch_features:
            s.append(pinch.flatten(1) / PINCH_SCALE)
            k.append((keypoints[:, :, None] - pinch[:, None]).flatten(2) / PINCH_SCALE)
        tokens = torch.cat([self.state_embed(torch.cat(s, -1))[:, None],
                            self.kp_embed(torch.cat(k, -1)) + self.kp_index], dim=1)
        return self.encoder(tokens)

    def forward(self, state: torch.Tensor, time_s: torch.Tensor, keypoints: torch.Tensor,
                pinch: torch.Tensor | None = None) -> torch.Tensor:
        c = self.config
        return self.head(self.encode(state, time_s, keypoints, pinch).flatten(1)).view(len(state), c.chunk, c.state_dim)

    def decode(self, raw: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Raw outputs -> actions in world units after `state` (B, 14): joints in rad, grippers as the
        probability of open."""
        out = state[:, None] + raw * self.delta_std
        out[..., self.grippers] = torch.sigmoid(raw[..., self.grippers])
        return out

    @torch.no_grad()
    def predict(self, state: np.ndarray, environment_state: np.ndarray, time_s: float) -> np.ndarray:
        """The next `chunk` actions (chunk, 14) after one frame: state (14,), environment_state (3K,)."""
        s = torch.as_tensor(np.asarray(state, np.float32)[None])
        k = torch.as_tensor(np.asarray(environment_state, np.float32).reshape(1, -1, 3))
        p = torch.as_tensor(self.pinch_points(np.asarray(state)[None]), dtype=torch.float32) \
            if self.config.pinch_features else None
        return self.decode(self(s, torch.tensor([float(time_s)]), k, p), s)[0].numpy()

    def pinch_points(self, states: np.ndarray) -> np.ndarray:
        """(B, 2, 3) the hands' pinch points of joint states (B, 14): the robot's forward kinematics."""
        if self._fk is None:
            self._fk = PinchKinematics(self.config.robot, self.config.task)
        return self._fk(states)


class PinchKinematics:
    """Forward kinematics of an arm robot's pinch points on its IK's kinematic model (the planner's, as the
    joint-space export's poses)."""

    def __init__(self, robot_label: str, task: str):
        ik = resolve_robot(robot_label).ik(task)  # the label parsed by RobotSpec
        self.model, self.data, self.sites = ik.model, mujoco.MjData(ik.model), ik.sites

    def __call__(self, states: np.ndarray) -> np.ndarray:
        s = np.asarray(states, np.float64)
        out = np.zeros((len(s), 2, 3))
        for i, row in enumerate(s):
            self.data.qpos[:] = np.concatenate([row[0:6], row[7:13]])
            mujoco.mj_kinematics(self.model, self.data)
            out[i] = self.data.site_xpos[self.sites]
        return out


class TemporalEnsemble:
    """ACT's temporal ensembling: the action for step t is the weighted mean of every chunk predicted at the
    steps t - chunk + 1 .. t for step t, the oldest weighted most (weights exp(-decay * i), i = 0 the oldest).
    Call with each observation: ``action = ensemble(obs_state, obs_environment, time_s)``."""

    def __init__(self, policy: ChunkPolicy, decay: float = 0.01):
        self.policy, self.decay = policy, float(decay)
        self.reset()

    def reset(self) -> None:
        self.chunks: list[tuple[int, np.ndarray]] = []
        self.t = 0
        self.inference_s = 0.0

    def __call__(self, state: np.ndarray, environment_state: np.ndarray, time_s: float) -> np.ndarray:
        t0 = time.perf_counter()
        chunk = self.policy.predict(state, environment_state, time_s)
        self.inference_s += time.perf_counter() - t0
        n = len(chunk)
        self.chunks = [(s, c) for s, c in self.chunks if self.t - s < n] + [(self.t, chunk)]
        preds = np.stack([c[self.t - s] for s, c in self.chunks])          # oldest first
        w = np.exp(-self.decay * np.arange(len(preds)))
        self.t += 1
        return (w[:, None] * preds).sum(0) / w.sum()


__all__ = ["ChunkConfig", "ChunkPolicy", "TemporalEnsemble", "joint_columns"]
