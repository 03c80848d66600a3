"""Self-contained checkpoints of the learned policies (train.py's keypoint policy, chunk_train.py's
closed-loop policy): model.pt (format, config, weights) and config.json (the same config and the training
record), each written atomically; a short id from the sha256 of the config and the weights."""

from __future__ import annotations

import hashlib
import io
import json
import os
from pathlib import Path

import torch
from torch import nn


def weights_digest(model: nn.Module) -> str:
    """sha256 of the model's config and every tensor's bytes (in name order): equal digests = equal models."""
    h = hashlib.sha256(json.dumps(model.config.to_dict(), sort_keys=True).encode())
    for name, t in sorted(model.state_dict().items()):
        h.update(name.encode())
        h.update(t.detach().contiguous().numpy().tobytes())
    return h.hexdigest()


def save_model(model: nn.Module, folder: str | os.PathLike, fmt: str, checkpoint_id: str, meta: dict
               ) -> tuple[Path, Path]:
    """Write model.pt and config.json into folder, each atomically (temporary file + rename)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    torch.save({"format": fmt, "config": model.config.to_dict(), "state_dict": model.state_dict()}, buf)
    pt, js = folder / "model.pt", folder / "config.json"
    for path, data in ((pt, buf.getvalue()),
                       (js, json.dumps({"format": fmt, "checkpoint_id": checkpoint_id, "config": model.config.to_dict(),
                                        **meta}, indent=2, default=float).encode())):
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    return pt, js


def load_model(path: str | os.PathLike, fmt: str, build, train_command: str) -> nn.Module:
    """The model of a model.pt (or the folder holding it) of format `fmt`: build(config dict) -> module, the
    weights loaded, in eval mode. A missing file names `train_command`."""
    path = Path(path)
    if path.is_dir():
        path = path / "model.pt"
    if not path.is_file():
        raise FileNotFoundError(f"no policy checkpoint at {path}: train one with `{train_command}`")
    blob = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(blob, dict) or blob.get("format") != fmt:
        raise ValueError(f"{path} is not a demoforge policy checkpoint ({fmt})")
    model = build(blob["config"])
    model.load_state_dict(blob["state_dict"])
    model.eval()
    return model


__all__ = ["load_model", "save_model", "weights_digest"]
