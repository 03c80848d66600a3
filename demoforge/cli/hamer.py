"""`demoforge` commands of the hamer area (a sub-app composed into the root app)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from demoforge.cli.root import current_warehouse, fail

app = typer.Typer()


def _config(sizes: str | None):
    import json

    from demoforge.lib.perception.hamer.model import HamerConfig  # lazy: torch

    if not sizes:
        return HamerConfig()
    try:
        kw = json.loads(sizes)
        if "img_size" in kw:
            kw["img_size"] = tuple(kw["img_size"])
        return HamerConfig(**kw)
    except (json.JSONDecodeError, TypeError) as e:
        raise fail(f"--sizes must be a JSON object of HamerConfig fields: {e}")


@app.command("hamer-check")
def hamer_check(
    checkpoint: Path = typer.Option(..., "--checkpoint", "-c", help="Local hamer.ckpt (HaMeR release, _DATA/hamer_ckpts/checkpoints/hamer.ckpt)."),
    mano: Path = typer.Option(..., "--mano", "-m", help="Local MANO right-hand model: MANO_RIGHT.pkl (or an .npz with its arrays)."),
    run: bool = typer.Option(False, "--run", help="Also run one frame (two hand crops) through network + MANO and time it."),
    device: Optional[str] = typer.Option(None, help="cuda or cpu (default: cuda when present)."),
    non_strict: bool = typer.Option(False, "--non-strict", help="Report mismatches without failing (exit 0)."),
    sizes: Optional[str] = typer.Option(None, help='Network sizes other than the released ones, as JSON, e.g. \'{"embed_dim": 1024, "depth": 24, "num_heads": 16}\' (fields of demoforge.lib.perception.hamer.model.HamerConfig).'),
) -> None:
    """Check a HaMeR checkpoint and a MANO model file before ingesting with --detector hamer.

    Loads the checkpoint's state_dict into the torch HaMeR (released sizes: ViT-H/16 on 256x192,
    6-layer cross-attention decoder) and reports how many tensors match, which keys are missing or
    unexpected and which shapes differ; the training-only entries (discriminator, MANO buffers)
    are listed as ignored. Then loads the MANO model and reports its size. Neither file is
    downloaded by demoforge: both are licensed, pass your local copies. Exit code 2 on a mismatch.
    """
    # lazy: torch
    from demoforge.lib.perception.hamer.checkpoint import (
        CheckpointError, check_state_dict, load_hamer, read_state_dict,
    )
    from demoforge.lib.perception.hamer.mano import MANOError, load_mano_model
    from demoforge.lib.perception.hamer.model import HamerNet

    cfg = _config(sizes)
    t0 = time.perf_counter()
    try:
        sd = read_state_dict(checkpoint)
    except CheckpointError as e:
        raise fail(str(e))
    import torch

    with torch.device("meta"):
        rep = check_state_dict(HamerNet(cfg), sd)
    typer.echo(f"checkpoint  {checkpoint}  ({len(sd)} tensors, read in {time.perf_counter() - t0:.1f} s)")
    typer.echo(f"  matched     {rep.matched}")
    typer.echo(f"  ignored     {len(rep.ignored)}" + (f"  ({', '.join(sorted({k.split('.')[0] for k in rep.ignored}))})" if rep.ignored else ""))
    for label, keys in (("missing", rep.missing), ("unexpected", rep.unexpected)):
        typer.echo(f"  {label:<11} {len(keys)}")
        for k in keys[:20]:
            typer.echo(f"    {k}")
        if len(keys) > 20:
            typer.echo(f"    ... {len(keys) - 20} more")
    typer.echo(f"  shape diffs {len(rep.shape_mismatch)}")
    for k, want, got in rep.shape_mismatch[:20]:
        typer.echo(f"    {k}: expected {list(want)}, found {list(got)}")
    try:
        model = load_mano_model(mano)
    except MANOError as e:
        raise fail(str(e))
    typer.echo(f"MANO        {mano}  ({model.v_template.shape[0]} vertices, 16 joints + 5 fingertips, "
               f"{model.shapedirs.shape[-1]} shape directions)")
    if not rep.ok:
        if non_strict:
            typer.echo("checkpoint does not match the released HaMeR layout (--non-strict: not an error)")
            return
        raise fail(f"checkpoint does not match the released HaMeR layout: {rep.summary(limit=4)}")
    if run:
        import numpy as np

        from demoforge.lib.perception.hamer.model import HamerPredictor  # lazy: torch

        t1 = time.perf_counter()
        net, _ = load_hamer(checkpoint, cfg)
        pred = HamerPredictor(net, model, device=device, batch_size=2)
        t2 = time.perf_counter()
        img = np.full((1, 480, 640, 3), 128, np.uint8)
        K = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
        boxes = np.array([[180.0, 200, 260, 300], [380, 190, 460, 290]])
        pred.predict(img, boxes, [0, 0], [False, True], K)  # warm-up
        t3 = time.perf_counter()
        out = pred.predict(img, boxes, [0, 0], [False, True], K)
        t4 = time.perf_counter()
        typer.echo(f"run         device {pred.device}; model loaded in {t2 - t1:.1f} s; one frame (2 hands) "
                   f"{(t4 - t3) * 1000:.0f} ms; wrist depth on a grey image {out.joints_cam[:, 0, 2].round(3).tolist()} m")
    typer.echo("ok")


@app.command("hamer-bench")
def hamer_bench(
    batch_size: list[int] = typer.Option([1, 8, 32], "--batch-size", "-b", help="Crops per forward pass (repeat the option)."),
    frames: int = typer.Option(32, help="Frames per measurement (2 hand crops each)."),
    device: Optional[str] = typer.Option(None, help="cuda or cpu (default: cuda when present)."),
    checkpoint: Optional[Path] = typer.Option(None, "--checkpoint", "-c", help="Real hamer.ckpt (default: random weights; the speed is the same)."),
    mano: Optional[Path] = typer.Option(None, "--mano", "-m", help="MANO_RIGHT.pkl (default: the synthetic MANO-like model)."),
    small: bool = typer.Option(False, "--small", help="ViT-S-sized backbone instead of the released ViT-H (for slow CPUs)."),
    amp: bool = typer.Option(False, "--amp", help="bfloat16 autocast on CUDA."),
    sizes: Optional[str] = typer.Option(None, help="Network sizes as JSON (fields of demoforge.lib.perception.hamer.model.HamerConfig); overrides --small."),
) -> None:
    """Throughput of the torch HaMeR (network + MANO + crops + cameras) in frames/s per batch size.

    The model is loaded once and reused across batch sizes, as in an ingest. Without --checkpoint
    the weights are random in the released layout (speed does not depend on the weights).
    """
    import torch

    from demoforge.bench.cases_hamer import CPU_CONFIG, frames_and_boxes  # lazy (CLI start-up): numpy
    # lazy: torch
    from demoforge.lib.perception.hamer.model import HamerConfig, HamerNet, HamerPredictor
    from demoforge.lib.perception.hamer.synthetic import synthetic_mano

    if frames < 1 or any(b < 1 for b in batch_size):
        raise fail("--frames and --batch-size must be >= 1")
    if checkpoint is not None:
        from demoforge.lib.perception.hamer.checkpoint import CheckpointError, load_hamer  # lazy: torch

        try:
            net, _ = load_hamer(checkpoint, _config(sizes))
        except CheckpointError as e:
            raise fail(str(e))
    else:
        net = HamerNet(_config(sizes) if sizes else HamerConfig(**CPU_CONFIG) if small else HamerConfig())
    mano_model = synthetic_mano()[0]
    if mano is not None:
        from demoforge.lib.perception.hamer.mano import MANOError, load_mano_model  # lazy: torch

        try:
            mano_model = load_mano_model(mano)
        except MANOError as e:
            raise fail(str(e))
    pred = HamerPredictor(net, mano_model, device=device, amp=amp)
    imgs, boxes, idx, right, K = frames_and_boxes(frames)
    sync = torch.cuda.synchronize if pred.device.type == "cuda" else (lambda: None)
    typer.echo(f"device {pred.device}; backbone embed {net.config.embed_dim} x depth {net.config.depth}; "
               f"{frames} frames x 2 hands; amp {pred.amp}")
    base = None
    for bs in batch_size:
        pred.batch_size = bs
        pred.predict(imgs[:1], boxes[:2], idx[:2], right[:2], K)  # warm-up
        sync()
        t0 = time.perf_counter()
        pred.predict(imgs, boxes, idx, right, K)
        sync()
        dt = time.perf_counter() - t0
        fps = frames / dt
        base = base or fps
        typer.echo(f"batch {bs:>4}: {fps:8.2f} frames/s  ({2 * fps:8.2f} hands/s; x{fps / base:.2f} vs batch {batch_size[0]})")
