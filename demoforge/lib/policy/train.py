"""Seeded training of the keypoint policy, validation metrics, and self-contained checkpoints.

Reproducibility: the weights' initialisation, the batch order and any dropout come from ``seed``
alone; with the same data, config, seed and thread count the trained weights are bit-identical
(torch CPU kernels are deterministic for a fixed thread count, which is recorded)."""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import nn

from demoforge.lib.policy.checkpoints import load_model, save_model, weights_digest
from demoforge.lib.policy.data import Normalizer, PolicyData, pose_features
from demoforge.lib.policy.model import KeypointPolicy, PolicyConfig
from demoforge.lib.policy.rotation6d import torch_geodesic

CHECKPOINT_FORMAT = "demoforge-policy-v1"


@dataclass(frozen=True)
class TrainConfig:
    epochs: int = 60
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 50
    rot_weight: float = 1.0      # weight of the 6D-rotation MSE against the normalised-position MSE
    grip_weight: float = 0.2     # weight of the gripper BCE
    max_seconds: float | None = None  # wall-clock budget: stop after the epoch that exceeds it
    threads: int = 1

    def __post_init__(self):
        if self.epochs < 1 or self.batch_size < 1 or self.lr <= 0 or self.threads < 1:
            raise ValueError(f"epochs, batch_size, threads must be >= 1 and lr > 0, got {self}")


@dataclass
class EpochLog:
    epoch: int
    train_loss: float
    val_loss: float
    seconds: float


@dataclass
class TrainResult:
    model: KeypointPolicy
    history: list[EpochLog]
    val_metrics: dict
    seconds: float
    steps: int
    stopped_early: bool
    n_train: int
    n_val: int
    meta: dict = field(default_factory=dict)


def _tensors(model: KeypointPolicy, data: PolicyData):
    """Network-ready tensors: normalised inputs and targets (pos normalised, 6D, gripper 0/1)."""
    kp, ini = model.encode_inputs(torch.as_tensor(data.keypoints, dtype=torch.float32),
                                  torch.as_tensor(pose_features(data.initial), dtype=torch.float32))
    tgt = torch.as_tensor(pose_features(data.waypoints), dtype=torch.float32)  # (N, n, 2, 10)
    tgt[..., :3] = (tgt[..., :3] - model.wp_mean) / model.wp_std
    return kp, ini, tgt


def loss_terms(raw: torch.Tensor, tgt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(position MSE in normalised units, 6D rotation MSE, gripper BCE)."""
    pos = torch.mean((raw[..., :3] - tgt[..., :3]) ** 2)
    rot = torch.mean((raw[..., 3:9] - tgt[..., 3:9]) ** 2)
    grip = nn.functional.binary_cross_entropy_with_logits(raw[..., 9], tgt[..., 9])
    return pos, rot, grip


@torch.no_grad()
def evaluate(model: KeypointPolicy, data: PolicyData, cfg: TrainConfig, batch: int = 1024) -> dict:
    """Loss and interpretable errors on a data set: position error (mm), rotation error (deg),
    gripper state accuracy, all over every waypoint and arm."""
    model.eval()
    kp, ini, tgt = _tensors(model, data)
    sums = np.zeros(6)
    for a in range(0, len(kp), batch):
        raw = model(kp[a:a + batch], ini[a:a + batch])
        t = tgt[a:a + batch]
        p, r, g = loss_terms(raw, t)
        w = len(raw)
        pos_err = torch.linalg.norm((raw[..., :3] - t[..., :3]) * model.wp_std, dim=-1)
        sums += w * np.array([float(p + cfg.rot_weight * r + cfg.grip_weight * g), float(p), float(r),
                              float(pos_err.mean()), float(torch_geodesic(raw[..., 3:9], t[..., 3:9]).mean()),
                              float(((raw[..., 9] > 0).float() == t[..., 9]).float().mean())])
    m = sums / max(len(kp), 1)
    model.train()
    return {"loss": m[0], "pos_loss": m[1], "rot_loss": m[2], "pos_err_mm": 1000 * m[3],
            "rot_err_deg": math.degrees(m[4]), "grip_acc": m[5]}


def train_policy(train: PolicyData, val: PolicyData, seed: int = 0, config: PolicyConfig | None = None,
                 train_config: TrainConfig | None = None,
                 on_epoch: Callable[[EpochLog], None] | None = None,
                 on_step: Callable[[int, int], None] | None = None) -> TrainResult:
    """Train a fresh KeypointPolicy on ``train``, report ``val`` after every epoch (on_epoch) and
    every step (on_step(step, total_steps), for a progress bar)."""
    if len(train) == 0 or len(val) == 0:
        raise ValueError(f"need training and validation episodes, got {len(train)} and {len(val)}")
    cfg = train_config or TrainConfig()
    pcfg = config or PolicyConfig(n_keypoints=train.keypoints.shape[1], n_waypoints=train.waypoints.shape[1])
    if (pcfg.n_keypoints, pcfg.n_waypoints) != (train.keypoints.shape[1], train.waypoints.shape[1]):
        raise ValueError(f"config expects {pcfg.n_keypoints} keypoints / {pcfg.n_waypoints} waypoints, the data "
                         f"has {train.keypoints.shape[1]} / {train.waypoints.shape[1]}")
    prev_threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        torch.manual_seed(seed)
        gen = torch.Generator().manual_seed(seed)
        model = KeypointPolicy(pcfg, Normalizer.fit(train))
        kp, ini, tgt = _tensors(model, train)
        opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        per_epoch = math.ceil(len(kp) / cfg.batch_size)
        total = per_epoch * cfg.epochs

        def lr_at(step):  # linear warm-up, then cosine decay to 5 %
            if step < cfg.warmup_steps:
                return (step + 1) / cfg.warmup_steps
            u = (step - cfg.warmup_steps) / max(total - cfg.warmup_steps, 1)
            return 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(u, 1.0)))

        sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_at)
        history: list[EpochLog] = []
        t_start = time.perf_counter()
        step, stopped = 0, False
        model.train()
        for epoch in range(cfg.epochs):
            order = torch.randperm(len(kp), generator=gen)
            run_loss = 0.0
            for a in range(0, len(kp), cfg.batch_size):
                idx = order[a:a + cfg.batch_size]
                p, r, g = loss_terms(model(kp[idx], ini[idx]), tgt[idx])
                loss = p + cfg.rot_weight * r + cfg.grip_weight * g
                opt.zero_grad(set_to_none=True)
                loss.backward()
                nn.utils.clip_grad_norm_(model.parameters(), 1.0)
                opt.step()
                sched.step()
                run_loss += float(loss.detach()) * len(idx)
                step += 1
                if on_step:
                    on_step(step, total)
            log = EpochLog(epoch, run_loss / len(kp), evaluate(model, val, cfg)["loss"], time.perf_counter() - t_start)
            history.append(log)
            if on_epoch:
                on_epoch(log)
            if cfg.max_seconds is not None and log.seconds > cfg.max_seconds and epoch < cfg.epochs - 1:
                stopped = True
                break
        seconds = time.perf_counter() - t_start
        model.eval()
        return TrainResult(model, history, evaluate(model, val, cfg), seconds, step, stopped, len(train), len(val),
                           meta={"seed": seed, "threads": cfg.threads, "train_config": asdict(cfg),
                                 "policy_config": pcfg.to_dict()})
    finally:
        torch.set_num_threads(prev_threads)


# --------------------------------------------------------------------------------- checkpoints

def checkpoint_id(model: KeypointPolicy) -> str:
    """A short id of the trained weights (the `model` of its llm_trials rows)."""
    return "kp-" + weights_digest(model)[:10]


def save_checkpoint(model: KeypointPolicy, folder: str | os.PathLike, meta: dict) -> tuple[Path, Path]:
    """Write model.pt (config + weights) and config.json (config + training metadata) into folder,
    each atomically (temporary file + rename)."""
    return save_model(model, folder, CHECKPOINT_FORMAT, checkpoint_id(model), meta)


def load_checkpoint(path: str | os.PathLike) -> KeypointPolicy:
    """A KeypointPolicy from a model.pt written by save_checkpoint (or the folder holding it)."""
    return load_model(path, CHECKPOINT_FORMAT, lambda c: KeypointPolicy(PolicyConfig(**c)), "demoforge train-policy")
