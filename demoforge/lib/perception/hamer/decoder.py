"""HaMeR's MANO head: a cross-attention transformer decoder with one query token, parameter names as released.

Follows hamer/models/heads/mano_head.py (MANOTransformerDecoderHead) and
hamer/models/components/pose_transformer.py (TransformerDecoder, TransformerCrossAttn, PreNorm,
Attention, CrossAttention, FeedForward) of github.com/geopavlakos/hamer, with the released
model_config.yaml's TRANSFORMER_DECODER: depth 6, heads 8, dim_head 64, mlp_dim 1024, dim 1024,
context_dim 1280 (ViT-H), norm "layer", TRANSFORMER_INPUT "zero" (token_dim 1), IEF_ITERS 1,
JOINT_REP "6d" (16 joints x 6 = 96 pose outputs), 10 betas, 3 camera values.

State-dict layout (prefix ``mano_head.`` in the checkpoint)::

    transformer.to_token_embedding.{weight,bias}      Linear(1, dim)
    transformer.pos_embedding                          (1, 1, dim)
    transformer.transformer.layers.N.0.norm.*          LayerNorm before self-attention
    transformer.transformer.layers.N.0.fn.to_qkv.weight            (3 * heads * dim_head, dim), no bias
    transformer.transformer.layers.N.0.fn.to_out.0.{weight,bias}
    transformer.transformer.layers.N.1.norm.*          LayerNorm before cross-attention
    transformer.transformer.layers.N.1.fn.to_kv.weight             (2 * heads * dim_head, context_dim)
    transformer.transformer.layers.N.1.fn.to_q.weight              (heads * dim_head, dim)
    transformer.transformer.layers.N.1.fn.to_out.0.{weight,bias}
    transformer.transformer.layers.N.2.norm.*          LayerNorm before the MLP
    transformer.transformer.layers.N.2.fn.net.0.*      Linear(dim, mlp_dim), GELU, Linear(mlp_dim, dim) = net.3
    decpose.*, decshape.*, deccam.*                    Linear(dim, 96 / 10 / 3)
    init_hand_pose (1, 96), init_betas (1, 10), init_cam (1, 3)   buffers (mano_mean_params.npz)
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def rot6d_to_rotmat(x: torch.Tensor) -> torch.Tensor:
    """HaMeR's 6D -> rotation matrix (hamer/utils/geometry.py): (..., 6) -> (..., 3, 3).

    The 6 numbers are the first two COLUMNS a1 = x[0:3], a2 = x[3:6] (``reshape(-1, 2, 3).permute``),
    Gram-Schmidt orthonormalised; the third column is their cross product.
    """
    shape = x.shape[:-1]
    x = x.reshape(-1, 2, 3)
    b1 = F.normalize(x[:, 0], dim=-1)
    a2 = x[:, 1]
    b2 = F.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack((b1, b2, b3), dim=-1).reshape(*shape, 3, 3)


class PreNorm(nn.Module):
    def __init__(self, dim: int, fn: nn.Module):
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.fn = fn

    def forward(self, x: torch.Tensor, **kwargs) -> torch.Tensor:
        return self.fn(self.norm(x), **kwargs)


class FeedForward(nn.Module):
    def __init__(self, dim: int, hidden_dim: int):
        super().__init__()
        # indices 0 (Linear), 1 (GELU), 2 (Dropout), 3 (Linear), 4 (Dropout) as in pose_transformer.py
        self.net = nn.Sequential(nn.Linear(dim, hidden_dim), nn.GELU(), nn.Identity(),
                                 nn.Linear(hidden_dim, dim), nn.Identity())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


def _heads(t: torch.Tensor, h: int) -> torch.Tensor:
    b, n, hd = t.shape
    return t.reshape(b, n, h, hd // h).transpose(1, 2)


class SelfAttention(nn.Module):
    def __init__(self, dim: int, heads: int, dim_head: int):
        super().__init__()
        inner = heads * dim_head
        self.heads = heads
        self.to_qkv = nn.Linear(dim, inner * 3, bias=False)
        if heads == 1 and dim_head == dim:
            raise ValueError("heads=1 with dim_head=dim has no output projection in HaMeR; not supported")
        self.to_out = nn.Sequential(nn.Linear(inner, dim), nn.Identity())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        q, k, v = (_heads(t, self.heads) for t in self.to_qkv(x).chunk(3, dim=-1))
        out = F.scaled_dot_product_attention(q, k, v)
        b, h, n, d = out.shape
        return self.to_out(out.transpose(1, 2).reshape(b, n, h * d))


class CrossAttention(nn.Module):
    def __init__(self, dim: int, context_dim: int, heads: int, dim_head: int):
        super().__init__()
        inner = heads * dim_head
        self.heads = heads
        self.to_kv = nn.Linear(context_dim, inner * 2, bias=False)
        self.to_q = nn.Linear(dim, inner, bias=False)
        self.to_out = nn.Sequential(nn.Linear(inner, dim), nn.Identity())

    def forward(self, x: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        k, v = (_heads(t, self.heads) for t in self.to_kv(context).chunk(2, dim=-1))
        q = _heads(self.to_q(x), self.heads)
        out = F.scaled_dot_product_attention(q, k, v)
        b, h, n, d = out.shape
        return self.to_out(out.transpose(1, 2).reshape(b, n, h * d))


class TransformerCrossAttn(nn.Module):
    def __init__(self, dim: int, depth: int, heads: int, dim_head: int, mlp_dim: int, context_dim: int):
        super().__init__()
        self.layers = nn.ModuleList(
            nn.ModuleList([PreNorm(dim, SelfAttention(dim, heads, dim_head)),
                           PreNorm(dim, CrossAttention(dim, context_dim, heads, dim_head)),
                           PreNorm(dim, FeedForward(dim, mlp_dim))])
            for _ in range(depth))

    def forward(self, x: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        for self_attn, cross_attn, ff in self.layers:
            x = self_attn(x) + x
            x = cross_attn(x, context=context) + x
            x = ff(x) + x
        return x


class TransformerDecoder(nn.Module):
    def __init__(self, num_tokens: int, token_dim: int, dim: int, depth: int, heads: int, mlp_dim: int,
                 dim_head: int, context_dim: int):
        super().__init__()
        self.to_token_embedding = nn.Linear(token_dim, dim)
        self.pos_embedding = nn.Parameter(torch.zeros(1, num_tokens, dim))
        self.transformer = TransformerCrossAttn(dim, depth, heads, dim_head, mlp_dim, context_dim)

    def forward(self, inp: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        x = self.to_token_embedding(inp)
        x = x + self.pos_embedding[:, :x.shape[1]]
        return self.transformer(x, context=context)


class MANOHead(nn.Module):
    """Backbone features (B, C, Hp, Wp) -> per-crop rotation matrices (B, 16, 3, 3), betas (B, 10), cam (B, 3).

    ``cam`` is HaMeR's weak-perspective crop camera (s, tx, ty); see demoforge.lib.perception.hamer.camera.
    """

    def __init__(self, dim: int = 1024, depth: int = 6, heads: int = 8, dim_head: int = 64,
                 mlp_dim: int = 1024, context_dim: int = 1280, num_hand_joints: int = 15,
                 num_betas: int = 10):
        super().__init__()
        self.num_joints = num_hand_joints + 1
        npose = 6 * self.num_joints
        self.transformer = TransformerDecoder(1, 1, dim, depth, heads, mlp_dim, dim_head, context_dim)
        self.decpose = nn.Linear(dim, npose)
        self.decshape = nn.Linear(dim, num_betas)
        self.deccam = nn.Linear(dim, 3)
        # HaMeR fills these from mano_mean_params.npz; the checkpoint carries them
        self.register_buffer("init_hand_pose", torch.zeros(1, npose))
        self.register_buffer("init_betas", torch.zeros(1, num_betas))
        self.register_buffer("init_cam", torch.zeros(1, 3))

    def forward(self, feats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        B = feats.shape[0]
        context = feats.flatten(2).transpose(1, 2)            # 'b c h w -> b (h w) c'
        token = feats.new_zeros(B, 1, 1)                       # TRANSFORMER_INPUT: zero
        out = self.transformer(token, context=context)[:, 0]
        pose6d = self.decpose(out) + self.init_hand_pose       # one IEF iteration
        betas = self.decshape(out) + self.init_betas
        cam = self.deccam(out) + self.init_cam
        rotmats = rot6d_to_rotmat(pose6d.reshape(B, self.num_joints, 6))
        return rotmats, betas, cam
