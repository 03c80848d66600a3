"""The HaMeR network (ViT backbone + MANO transformer head) and a predictor that keeps it loaded.

Architecture and checkpoint layout: hamer/models/hamer.py (HAMER: ``self.backbone``,
``self.mano_head``; the backbone sees ``img[:, :, :, 32:-32]``) of github.com/geopavlakos/hamer.
:class:`HamerConfig` defaults are the released model's sizes (ViT-H/16 on 256x192, decoder 6 x 8
heads x 64, dim 1024, context 1280); tests build a tiny model with the same key layout.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np
import torch
from torch import nn

from demoforge.lib.perception.detectors import fit_translation_to_2d
from demoforge.lib.perception.hamer.camera import (
    BBOX_SHAPE, FOCAL_LENGTH, IMAGE_SIZE, boxes_to_crops, cam_crop_to_camera, crop_images,
    crop_points_to_image,
)
from demoforge.lib.perception.hamer.decoder import MANOHead
from demoforge.lib.perception.hamer.mano import ManoLayer, ManoModelData, load_mano_model
from demoforge.lib.perception.hamer.vit import ViT

__all__ = ["HamerConfig", "HamerNet", "HamerPredictor", "HandPrediction", "default_device"]


@dataclass(frozen=True)
class HamerConfig:
    """Network sizes. Defaults = the released ``hamer.ckpt`` (hamer/models/backbones/vit.py vit(),
    model_config.yaml MODEL.MANO_HEAD.TRANSFORMER_DECODER)."""

    img_size: tuple[int, int] = (256, 192)
    patch_size: int = 16
    embed_dim: int = 1280
    depth: int = 32
    num_heads: int = 16
    mlp_ratio: float = 4.0
    dec_dim: int = 1024
    dec_depth: int = 6
    dec_heads: int = 8
    dec_dim_head: int = 64
    dec_mlp_dim: int = 1024
    num_hand_joints: int = 15
    num_betas: int = 10

    @classmethod
    def tiny(cls, **overrides) -> "HamerConfig":
        """A small model with the released key layout (for tests and benchmarks without the checkpoint)."""
        kw = dict(embed_dim=64, depth=2, num_heads=4, dec_dim=32, dec_depth=2, dec_heads=2,
                  dec_dim_head=16, dec_mlp_dim=64)
        kw.update(overrides)
        return cls(**kw)

    def to_dict(self) -> dict:
        return asdict(self)


class HamerNet(nn.Module):
    """(N, 3, 256, 256) normalised crops -> rotations (N, 16, 3, 3), betas (N, 10), crop camera (N, 3)."""

    def __init__(self, config: HamerConfig = HamerConfig()):
        super().__init__()
        c = config
        self.config = c
        self.backbone = ViT(img_size=c.img_size, patch_size=c.patch_size, embed_dim=c.embed_dim, depth=c.depth,
                            num_heads=c.num_heads, mlp_ratio=c.mlp_ratio, qkv_bias=True)
        self.mano_head = MANOHead(dim=c.dec_dim, depth=c.dec_depth, heads=c.dec_heads, dim_head=c.dec_dim_head,
                                  mlp_dim=c.dec_mlp_dim, context_dim=c.embed_dim,
                                  num_hand_joints=c.num_hand_joints, num_betas=c.num_betas)

    def forward(self, crops: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        h, w = self.config.img_size
        pad = (crops.shape[-1] - w) // 2
        feats = self.backbone(crops[..., pad:pad + w] if pad > 0 else crops)  # x[:, :, :, 32:-32]
        return self.mano_head(feats)


def default_device() -> torch.device:
    return torch.device("cuda") if torch.cuda.is_available() else torch.device("cpu")


@dataclass
class HandPrediction:
    """Per crop (N = number of hand boxes), numpy float64."""

    joints_cam: np.ndarray      # (N, 21, 3) m, camera frame (MediaPipe joint order)
    joints_px: np.ndarray       # (N, 21, 2) the network's 2D keypoints in full-image pixels
    joints_model: np.ndarray    # (N, 21, 3) m, MANO frame (left hands un-flipped), before translation
    translation: np.ndarray     # (N, 3) camera-frame translation of the MANO frame
    cam_crop: np.ndarray        # (N, 3) weak-perspective (s, tx, ty), un-flipped
    betas: np.ndarray           # (N, num_betas)
    box_center: np.ndarray      # (N, 2)
    box_size: np.ndarray        # (N,)
    is_right: np.ndarray        # (N,) bool
    extra: dict = field(default_factory=dict)


class HamerPredictor:
    """HaMeR with MANO, loaded once and kept on its device; runs batches of hand boxes.

    Args:
        net: a HamerNet with weights (see :func:`demoforge.lib.perception.hamer.checkpoint.load_hamer`).
        mano: MANO right-hand model (path or arrays).
        device: "cuda", "cpu" or None (cuda when present).
        batch_size: crops per forward pass.
        rescale_factor: box padding (demo.py's --rescale_factor, 2.0).
        translation: "crop_camera" (the crop camera moved to K, closed form) or "fit_2d" (the
            translation whose projection with K best fits the network's 2D keypoints).
        amp: run the network in bfloat16 autocast on CUDA (faster; float32 otherwise).
    """

    def __init__(self, net: HamerNet, mano: str | os.PathLike | ManoModelData, device: str | torch.device | None = None,
                 batch_size: int = 16, rescale_factor: float = 2.0, translation: str = "crop_camera",
                 amp: bool = False):
        if translation not in ("crop_camera", "fit_2d"):
            raise ValueError(f"translation must be 'crop_camera' or 'fit_2d', got {translation!r}")
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.device = torch.device(device) if device is not None else default_device()
        self.net = net.to(self.device).eval()
        model = mano if isinstance(mano, ManoModelData) else load_mano_model(mano)
        self.mano = ManoLayer(model).to(self.device)
        self.batch_size = int(batch_size)
        self.rescale_factor = float(rescale_factor)
        self.translation = translation
        self.amp = bool(amp) and self.device.type == "cuda"

    @torch.inference_mode()
    def run_crops(self, crops: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Network + MANO on normalised crops (N, 3, 256, 256) -> joints (N, 21, 3), cam (N, 3), betas."""
        outs = []
        for i in range(0, crops.shape[0], self.batch_size):
            x = crops[i:i + self.batch_size].to(self.device, non_blocking=True)
            with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.amp):
                rot, betas, cam = self.net(x)
            _, joints = self.mano(rot[:, 0].float(), rot[:, 1:].float(), betas.float())
            outs.append((joints, cam.float(), betas.float()))
        if not outs:
            nb = self.net.config.num_betas
            z = crops.new_zeros
            return z(0, 21, 3), z(0, 3), z(0, nb)
        return tuple(torch.cat(t) for t in zip(*outs))  # type: ignore[return-value]

    def predict(self, images: np.ndarray | torch.Tensor, boxes_xyxy: np.ndarray, image_index: Sequence[int],
                is_right: Sequence[bool], K: np.ndarray) -> HandPrediction:
        """Hands in full images.

        Args:
            images: (B, H, W, 3) uint8 RGB.
            boxes_xyxy: (N, 4) hand boxes in pixels.
            image_index: (N,) image of each box.
            is_right: (N,) True for a right hand (left hands are flipped for the network and back).
            K: (3, 3) intrinsics of the images.
        """
        boxes = np.asarray(boxes_xyxy, float).reshape(-1, 4)
        n = boxes.shape[0]
        right = np.asarray(is_right, bool).reshape(-1)
        idx = np.asarray(image_index, np.int64).reshape(-1)
        if right.shape[0] != n or idx.shape[0] != n:
            raise ValueError(f"{n} boxes but {right.shape[0]} is_right flags and {idx.shape[0]} image indices")
        imgs = torch.as_tensor(np.asarray(images) if not torch.is_tensor(images) else images)
        if imgs.ndim != 4 or imgs.shape[-1] != 3:
            raise ValueError(f"images must be (B, H, W, 3) RGB, got {tuple(imgs.shape)}")
        center, size = boxes_to_crops(boxes, self.rescale_factor, BBOX_SHAPE)
        imgs = imgs.to(self.device)
        crops = crop_images(imgs, torch.as_tensor(idx, device=self.device),
                            torch.as_tensor(center, device=self.device), torch.as_tensor(size, device=self.device),
                            torch.as_tensor(~right, device=self.device))
        joints, cam, betas = (t.detach().double().cpu().numpy() for t in self.run_crops(crops))
        sign = np.where(right, 1.0, -1.0)
        joints[..., 0] *= sign[:, None]      # un-flip left hands (demo.py: verts[:, 0] *= 2 * right - 1)
        cam[:, 1] *= sign                    # and the crop camera's x (pred_cam[:, 1] *= 2 * right - 1)
        px = crop_points_to_image(joints, cam, center, size, FOCAL_LENGTH, IMAGE_SIZE)
        if self.translation == "crop_camera":
            t = cam_crop_to_camera(cam, center, size, K)
        else:
            t = fit_translation_to_2d(joints, px, K) if n else np.zeros((0, 3))
        return HandPrediction(joints_cam=joints + t[:, None], joints_px=px, joints_model=joints, translation=t,
                              cam_crop=cam, betas=betas, box_center=center, box_size=size, is_right=right)
