"""Benchmark cases of the torch HaMeR (demoforge.lib.perception.hamer): frames/s against batch size (registered in demoforge/bench/registry.py).

Throughput depends on the architecture, not on the weights, so the cases use random weights in the
released key layout and the synthetic MANO model: no licensed file is needed. On CUDA the network
has the released sizes (ViT-H/16); on CPU a ViT-S-sized backbone (embed 384, depth 12, 6 heads)
with the released decoder keeps a run within minutes. Each frame has two hands (two crops).
The baseline is the same predictor with batch size 1 (one crop per forward pass).
"""

from __future__ import annotations

import numpy as np

from demoforge.bench.timing import BenchCase

CPU_CONFIG = dict(embed_dim=384, depth=12, num_heads=6)


def make_predictor(batch_size: int, device: str | None = None, config=None, seed: int = 0, amp: bool = False):
    """A HamerPredictor with random weights (released layout) and the synthetic MANO model."""
    import torch

    # lazy: torch
    from demoforge.lib.perception.hamer.model import HamerConfig, HamerNet, HamerPredictor, default_device
    from demoforge.lib.perception.hamer.synthetic import synthetic_mano

    dev = torch.device(device) if device else default_device()
    if config is None:
        config = HamerConfig() if dev.type == "cuda" else HamerConfig(**CPU_CONFIG)
    torch.manual_seed(seed)
    net = HamerNet(config)
    return HamerPredictor(net, synthetic_mano(seed)[0], device=dev, batch_size=batch_size, amp=amp)


def frames_and_boxes(n_frames: int, h: int = 480, w: int = 640, seed: int = 0):
    """n_frames RGB images with a left and a right hand box each, and intrinsics."""
    rng = np.random.default_rng(seed)
    imgs = rng.integers(0, 256, (n_frames, h, w, 3), dtype=np.uint8)
    boxes = np.tile(np.array([[180.0, 200, 260, 300], [380, 190, 460, 290]]), (n_frames, 1))
    idx = np.repeat(np.arange(n_frames), 2)
    right = np.tile([False, True], n_frames)
    K = np.array([[600.0, 0, (w - 1) / 2], [0, 600.0, (h - 1) / 2], [0, 0, 1]])
    return imgs, boxes, idx, right, K


def cases(quick: bool) -> list[BenchCase]:
    import torch

    cuda = torch.cuda.is_available()
    frames = (64 if quick else 256) if cuda else (4 if quick else 8)
    batches = (16, 64) if cuda else (8,)
    size_name = "ViT-H released sizes, CUDA" if cuda else "ViT-S backbone, CPU"
    out = []
    for bs in batches:
        def setup(n: int, bs=bs):
            fast_p = make_predictor(bs)
            base_p = make_predictor(1)
            imgs, boxes, idx, right, K = frames_and_boxes(n)

            def run(p):
                def go():
                    r = p.predict(imgs, boxes, idx, right, K)
                    if cuda:
                        torch.cuda.synchronize()
                    return r.joints_cam
                return go

            return run(fast_p), run(base_p)

        def check(a, b):
            np.testing.assert_allclose(a, b, atol=1e-3)

        out.append(BenchCase("hamer", f"HaMeR forward + MANO, 2 hands/frame, batch {bs} ({size_name})", frames,
                             "frames", "the same predictor with batch size 1", setup, check=check, repeats=2 if cuda else 1))
    return out
