"""Seeded training of the closed-loop chunk policy (chunking.py) on joint demonstrations (joint_demos.py),
and its self-contained checkpoints.

A sample is one frame of one episode: its state, environment state and timestamp, and as target the next
`chunk` actions (the following frames' states; past an episode's end its last state, the arms at rest).
Loss: L1 on the joints' normalised changes (as ACT's L1) plus the grippers' binary cross-entropy. Small Gaussian noise on
the input joints (``state_noise`` rad) teaches the policy to come back to the demonstrated path from
where its own errors take it. Same data, config, seed and thread count: the same weights."""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import nn

from demoforge.lib.policy.checkpoints import load_model, save_model, weights_digest
from demoforge.lib.policy.chunking import ChunkConfig, ChunkPolicy
from demoforge.lib.policy.joint_demos import JointDemos

CHUNK_CHECKPOINT_FORMAT = "demoforge-chunk-policy-v1"


@dataclass(frozen=True)
class ChunkTrainConfig:
    steps: int = 3000
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    grip_weight: float = 0.5
    state_noise: float = 0.01   # rad of Gaussian noise on the input joints
    hold_s: float = 1.0         # s of rest appended to each episode (JointDemos.held)
    threads: int = 1

    def __post_init__(self):
        if self.steps < 1 or self.batch_size < 1 or self.lr <= 0 or self.threads < 1 or self.state_noise < 0:
            raise ValueError(f"steps, batch_size, threads must be >= 1, lr > 0, state_noise >= 0; got {self}")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class ChunkTrainResult:
    model: ChunkPolicy
    losses: list[float]      # the mean loss of each tenth of the steps
    seconds: float
    frames: int
    episodes: int


def targets_index(lengths: np.ndarray, chunk: int) -> np.ndarray:
    """(F, chunk) row indices of each frame's target actions: the next `chunk` frames of its episode, the
    episode's last frame repeated past its end."""
    lengths = np.asarray(lengths, np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    ep = np.repeat(np.arange(len(lengths)), lengths)
    local = np.arange(len(ep)) - starts[ep]
    ahead = local[:, None] + 1 + np.arange(chunk)[None]
    return starts[ep][:, None] + np.minimum(ahead, lengths[ep][:, None] - 1)


def delta_rms(states: np.ndarray, target_rows: np.ndarray, block: int = 20_000) -> np.ndarray:
    """(chunk, D) root mean square over the frames of each target's change from its frame's state, summed a block
    of frames at a time (all frames' chunks at once would take 3.4 kB a frame: 1.2 GB for 1,000 episodes)."""
    total = np.zeros(target_rows.shape[1:] + states.shape[1:])
    for s in range(0, len(states), block):
        d = states[target_rows[s:s + block]] - states[s:s + block, None]
        total += (d.astype(np.float64) ** 2).sum(0)
    return np.sqrt(total / max(len(states), 1))


def frame_times(lengths: np.ndarray, fps: float) -> np.ndarray:
    """(F,) each frame's timestamp in its episode, s."""
    lengths = np.asarray(lengths, np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    ep = np.repeat(np.arange(len(lengths)), lengths)
    return (np.arange(len(ep)) - starts[ep]) / float(fps)


def train_chunk_policy(demos: JointDemos, config: ChunkConfig | None = None, train: ChunkTrainConfig | None = None,
                       seed: int = 0, fps: float = 30.0, on_step: Callable[[int, int], None] | None = None,
                       model: ChunkPolicy | None = None) -> ChunkTrainResult:
    """Train a ChunkPolicy (a new one of `config`, or `model`) on every frame of `demos`."""
    tc = train or ChunkTrainConfig()
    if len(demos) == 0:
        raise ValueError("no episodes to train on: the arms reach none of the selected episodes")
    demos = demos.held(int(round(tc.hold_s * fps)))
    torch.set_num_threads(tc.threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng([int(seed), 43])
    k = demos.environment.shape[1] // 3
    cfg = config or ChunkConfig(state_dim=demos.states.shape[1], n_keypoints=k, robot=demos.robot, task=demos.task)
    model = model if model is not None else ChunkPolicy(cfg)
    cfg = model.config
    states = torch.as_tensor(demos.states, dtype=torch.float32)
    kps = torch.as_tensor(demos.environment.reshape(-1, k, 3), dtype=torch.float32)
    times = torch.as_tensor(frame_times(demos.lengths, fps), dtype=torch.float32)
    target_rows = torch.as_tensor(targets_index(demos.lengths, cfg.chunk))
    model.fit_normalizer(demos.states, demos.environment.reshape(-1, k, 3),
                         delta_rms(demos.states, target_rows.numpy()))
    opt = torch.optim.AdamW(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    bce = nn.BCEWithLogitsLoss()
    joints, grippers = model.joints, model.grippers
    noise = torch.zeros(states.shape[1])
    noise[joints] = tc.state_noise
    losses, window = [], []
    t0 = time.perf_counter()
    n = len(states)
    for step in range(tc.steps):
        lr = tc.lr * min(1.0, (step + 1) / tc.warmup_steps) * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * step / tc.steps)))
        for g in opt.param_groups:
            g["lr"] = lr
        rows = torch.as_tensor(rng.integers(0, n, tc.batch_size))
        s = states[rows] + torch.randn(len(rows), states.shape[1]) * noise
        pinch = torch.as_tensor(model.pinch_points(s.numpy()), dtype=torch.float32) if cfg.pinch_features else None
        raw = model(s, times[rows], kps[rows], pinch)
        tgt = states[target_rows[rows]]                                                   # (B, chunk, 14)
        tgt_n = (tgt - s[:, None]) / model.delta_std  # the change from the noisy input: a way back to the path
        loss = (raw[..., joints] - tgt_n[..., joints]).abs().mean() \
            + tc.grip_weight * bce(raw[..., grippers], tgt[..., grippers])
        opt.zero_grad()
        loss.backward()
        opt.step()
        window.append(loss.item())
        if (step + 1) % max(1, tc.steps // 10) == 0 or step + 1 == tc.steps:
            losses.append(float(np.mean(window)))
            window = []
        if on_step is not None:
            on_step(step + 1, tc.steps)
    model.eval()
    return ChunkTrainResult(model, losses, time.perf_counter() - t0, int(n), len(demos))


def chunk_checkpoint_id(model: ChunkPolicy) -> str:
    """A short id of the trained weights."""
    return "cl-" + weights_digest(model)[:10]


def save_chunk_checkpoint(model: ChunkPolicy, folder: str | os.PathLike, meta: dict) -> Path:
    """Write model.pt (config + weights) and config.json (config + training metadata), each atomically."""
    return save_model(model, folder, CHUNK_CHECKPOINT_FORMAT, chunk_checkpoint_id(model), meta)[0]


def load_chunk_checkpoint(path: str | os.PathLike) -> ChunkPolicy:
    """A ChunkPolicy from a model.pt written by save_chunk_checkpoint (or the folder holding it)."""
    return load_model(path, CHUNK_CHECKPOINT_FORMAT, lambda c: ChunkPolicy(ChunkConfig(**c)),
                      "demoforge train-policy --closed-loop")


__all__ = ["CHUNK_CHECKPOINT_FORMAT", "ChunkTrainConfig", "ChunkTrainResult", "chunk_checkpoint_id",
           "delta_rms", "frame_times", "load_chunk_checkpoint", "save_chunk_checkpoint", "targets_index",
           "train_chunk_policy"]
