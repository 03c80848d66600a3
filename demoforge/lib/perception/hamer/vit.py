"""HaMeR's ViT backbone (ViTPose-style ViT-H/16 on a 256x192 hand crop), parameter names as released.

Follows hamer/models/backbones/vit.py of github.com/geopavlakos/hamer (ViTPose's ViT): the released
checkpoint uses ``vit(cfg)`` = ViT(img_size=(256, 192), patch_size=16, embed_dim=1280, depth=32,
num_heads=16, mlp_ratio=4, qkv_bias=True), LayerNorm eps 1e-6, a patch-embedding convolution with
padding 2 (``4 + 2 * (ratio // 2 - 1)`` with ratio 1), an absolute position embedding that still has
the class-token slot (added as ``pos_embed[:, 1:] + pos_embed[:, :1]``), no class token, and a last
LayerNorm. The output is channel-first (B, C, Hp, Wp) like the original, so the state_dict keys are
``patch_embed.proj.*``, ``pos_embed``, ``blocks.N.{norm1,attn.qkv,attn.proj,norm2,mlp.fc1,mlp.fc2}.*``
and ``last_norm.*``. Stochastic depth (drop_path) is a training-only detail and is left out.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


class Attention(nn.Module):
    def __init__(self, dim: int, num_heads: int, qkv_bias: bool = True):
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"embed_dim {dim} is not divisible by num_heads {num_heads}")
        self.num_heads = num_heads
        self.qkv = nn.Linear(dim, dim * 3, bias=qkv_bias)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, N, C = x.shape
        q, k, v = self.qkv(x).reshape(B, N, 3, self.num_heads, C // self.num_heads).permute(2, 0, 3, 1, 4)
        # fused kernel (flash / memory-efficient on GPU); same maths as softmax(q k^T / sqrt(d)) v
        x = F.scaled_dot_product_attention(q, k, v)
        return self.proj(x.transpose(1, 2).reshape(B, N, C))


class Block(nn.Module):
    def __init__(self, dim: int, num_heads: int, mlp_ratio: float, qkv_bias: bool):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = Attention(dim, num_heads, qkv_bias)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class PatchEmbed(nn.Module):
    def __init__(self, img_size: tuple[int, int], patch_size: int, in_chans: int, embed_dim: int):
        super().__init__()
        self.img_size = tuple(img_size)
        self.num_patches = (img_size[0] // patch_size) * (img_size[1] // patch_size)
        # padding 2 as in ViTPose (ratio 1): 256x192 -> 16x12 patches, the same grid as without it
        self.proj = nn.Conv2d(in_chans, embed_dim, kernel_size=patch_size, stride=patch_size, padding=2)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, tuple[int, int]]:
        x = self.proj(x)
        hp, wp = x.shape[2], x.shape[3]
        return x.flatten(2).transpose(1, 2), (hp, wp)


class ViT(nn.Module):
    """ViT backbone: (B, 3, H, W) normalised crop -> (B, embed_dim, H/16, W/16) features."""

    def __init__(self, img_size: tuple[int, int] = (256, 192), patch_size: int = 16, in_chans: int = 3,
                 embed_dim: int = 1280, depth: int = 32, num_heads: int = 16, mlp_ratio: float = 4.0,
                 qkv_bias: bool = True):
        super().__init__()
        self.embed_dim = embed_dim
        self.patch_embed = PatchEmbed(img_size, patch_size, in_chans, embed_dim)
        self.pos_embed = nn.Parameter(torch.zeros(1, self.patch_embed.num_patches + 1, embed_dim))
        self.blocks = nn.ModuleList(Block(embed_dim, num_heads, mlp_ratio, qkv_bias) for _ in range(depth))
        self.last_norm = nn.LayerNorm(embed_dim, eps=1e-6)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B = x.shape[0]
        if tuple(x.shape[2:]) != self.patch_embed.img_size:
            raise ValueError(f"ViT input must be (B, 3, {self.patch_embed.img_size[0]}, "
                             f"{self.patch_embed.img_size[1]}), got {tuple(x.shape)}")
        x, (hp, wp) = self.patch_embed(x)
        x = x + self.pos_embed[:, 1:] + self.pos_embed[:, :1]
        for blk in self.blocks:
            x = blk(x)
        x = self.last_norm(x)
        return x.transpose(1, 2).reshape(B, -1, hp, wp)
