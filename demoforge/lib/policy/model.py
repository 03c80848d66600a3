"""The policy network: a small Transformer encoder-decoder in the style of action chunking (ACT).

Encoder tokens: one per object keypoint (its normalised xyz + a learned keypoint-index embedding)
and one per arm's initial gripper pose ([xyz, 6D rotation, g] + an arm embedding).  Decoder: one
learned query per waypoint, cross-attending to the scene; each query's output is both arms'
[xyz (normalised), 6D rotation, gripper logit] at that waypoint.  The whole chunk comes out in one
forward pass, so inference is one call per scene.

Why no diffusion head: a database is one demonstration carried to many placements, so the action
sequence is a function of the scene (mirrored scenes have mirrored keypoints), not a multi-modal
distribution; a regression head fits it and a diffusion head would multiply inference cost by its
denoising steps for nothing.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from demoforge.lib.policy.data import Normalizer, pose_features
from demoforge.lib.policy.rotation6d import quat_from_6d

OUT_PER_ARM = 10  # xyz, 6D rotation, gripper logit


@dataclass(frozen=True)
class PolicyConfig:
    n_keypoints: int = 11
    n_waypoints: int = 20
    d_model: int = 64
    n_heads: int = 4
    enc_layers: int = 2
    dec_layers: int = 2
    ff_dim: int = 128
    dropout: float = 0.0

    def __post_init__(self):
        if self.d_model % self.n_heads:
            raise ValueError(f"d_model ({self.d_model}) must be a multiple of n_heads ({self.n_heads})")
        if self.n_waypoints < 2 or self.n_keypoints < 1:
            raise ValueError("need n_waypoints >= 2 and n_keypoints >= 1")

    def to_dict(self) -> dict:
        return asdict(self)


class KeypointPolicy(nn.Module):
    """(keypoints (B, k, 3), initial poses (B, 2, 8)) in world units -> raw outputs (B, n, 2, 10)."""

    def __init__(self, config: PolicyConfig, normalizer: Normalizer | None = None):
        super().__init__()
        c = self.config = config
        d = c.d_model
        self.kp_embed = nn.Linear(3, d)
        self.kp_index = nn.Parameter(torch.randn(c.n_keypoints, d) * 0.02)
        self.init_embed = nn.Linear(10, d)
        self.arm_embed = nn.Parameter(torch.randn(2, d) * 0.02)
        layer = dict(d_model=d, nhead=c.n_heads, dim_feedforward=c.ff_dim, dropout=c.dropout,
                     batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(nn.TransformerEncoderLayer(**layer), c.enc_layers,
                                             enable_nested_tensor=False)
        self.queries = nn.Parameter(torch.randn(c.n_waypoints, d) * 0.02)
        self.decoder = nn.TransformerDecoder(nn.TransformerDecoderLayer(**layer), c.dec_layers)
        self.norm = nn.LayerNorm(d)
        self.head = nn.Linear(d, 2 * OUT_PER_ARM)
        k, n = c.n_keypoints, c.n_waypoints
        # normalisation constants travel inside the state dict: a checkpoint is self-contained
        for name, shape in (("kp_mean", (k, 3)), ("kp_std", (k, 3)), ("init_mean", (2, 3)), ("init_std", (2, 3)),
                            ("wp_mean", (n, 2, 3)), ("wp_std", (n, 2, 3))):
            self.register_buffer(name, torch.zeros(shape) if "mean" in name else torch.ones(shape))
        if normalizer is not None:
            self.set_normalizer(normalizer)

    def set_normalizer(self, nz: Normalizer) -> None:
        for name in ("kp_mean", "kp_std", "init_mean", "init_std", "wp_mean", "wp_std"):
            getattr(self, name).copy_(torch.as_tensor(np.asarray(getattr(nz, name)), dtype=torch.float32))

    def encode_inputs(self, keypoints: torch.Tensor, init_feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World-unit inputs -> normalised network inputs (init_feat: (B, 2, 10) from pose_features)."""
        kp = (keypoints - self.kp_mean) / self.kp_std
        ini = torch.cat([(init_feat[..., :3] - self.init_mean) / self.init_std, init_feat[..., 3:]], dim=-1)
        return kp, ini

    def forward(self, kp_norm: torch.Tensor, init_norm: torch.Tensor) -> torch.Tensor:
        tokens = torch.cat([self.kp_embed(kp_norm) + self.kp_index, self.init_embed(init_norm) + self.arm_embed], dim=1)
        memory = self.encoder(tokens)
        q = self.queries.unsqueeze(0).expand(len(kp_norm), -1, -1)
        out = self.head(self.norm(self.decoder(q, memory)))
        return out.view(len(kp_norm), self.config.n_waypoints, 2, OUT_PER_ARM)

    def decode_outputs(self, raw: torch.Tensor) -> np.ndarray:
        """Raw outputs (B, n, 2, 10) -> (B, n, 2, 8) actions [xyz m, unit quaternion xyzw, g in {0, 1}]."""
        raw = raw.detach().double()
        pos = raw[..., :3] * self.wp_std.double() + self.wp_mean.double()
        quat = quat_from_6d(raw[..., 3:9].numpy())
        g = (raw[..., 9:10] > 0).double()  # logit > 0 <=> P(open) > 0.5
        return np.concatenate([pos.numpy(), quat, g.numpy()], axis=-1)

    @torch.no_grad()
    def predict(self, keypoints: np.ndarray, initial: np.ndarray) -> np.ndarray:
        """(k, 3) / (2, 8) for one scene, or batched (B, k, 3) / (B, 2, 8) -> (n, 2, 8) or (B, n, 2, 8) actions."""
        kp = np.asarray(keypoints, np.float64)
        ini = np.asarray(initial, np.float64)
        single = kp.ndim == 2
        if single:
            kp, ini = kp[None], ini[None]
        k = self.config.n_keypoints
        if kp.shape[1:] != (k, 3) or ini.shape[1:] != (2, 8) or len(kp) != len(ini):
            raise ValueError(f"expected keypoints (B, {k}, 3) and initial poses (B, 2, 8), got {kp.shape} and {ini.shape}")
        was_training = self.training
        self.eval()
        kp_n, ini_n = self.encode_inputs(torch.tensor(kp, dtype=torch.float32),
                                         torch.as_tensor(pose_features(ini), dtype=torch.float32))
        out = self.decode_outputs(self(kp_n, ini_n))
        self.train(was_training)
        return out[0] if single else out
