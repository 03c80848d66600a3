"""Reading the released HaMeR checkpoint (``hamer.ckpt``) into :class:`demoforge.lib.perception.hamer.model.HamerNet`.

``hamer.ckpt`` is a PyTorch Lightning checkpoint: a dict whose ``state_dict`` holds the HAMER
module's tensors (hamer/models/hamer.py of github.com/geopavlakos/hamer):

* ``backbone.*`` and ``mano_head.*``: the network, loaded here with a strict key and shape check;
* ``discriminator.*`` (training's adversarial pose prior, LOSS_WEIGHTS.ADVERSARIAL > 0),
  ``mano.*`` (the smplx MANO layer's buffers) and ``initialized``: present in a training
  checkpoint, not needed for inference (MANO comes from the user's own model file), so ignored
  and reported as such.

Anything else is an unexpected key. The file also holds training state (optimizer, the yacs
config in ``hyper_parameters``); it is read with ``torch.load(weights_only=True)``: classes that
the safe loader does not know (yacs ``CfgNode``, Lightning's ``AttributeDict``) are replaced by
inert stand-ins, so no code from the file runs.
"""

from __future__ import annotations

import os
import pickle
import types
from dataclasses import dataclass, field
from pathlib import Path

import torch

from demoforge.lib.errors import UserError
from demoforge.lib.perception.hamer.model import HamerConfig, HamerNet

__all__ = ["CheckpointError", "KeyReport", "IGNORED_PREFIXES", "read_state_dict", "check_state_dict",
           "load_hamer", "save_random_checkpoint"]

#: checkpoint entries that inference does not use (see the module docstring)
IGNORED_PREFIXES = ("discriminator.", "mano.", "initialized")


class CheckpointError(UserError):
    """The checkpoint is missing, unreadable, or does not match the network."""


@dataclass
class KeyReport:
    missing: list[str] = field(default_factory=list)
    unexpected: list[str] = field(default_factory=list)
    shape_mismatch: list[tuple[str, tuple, tuple]] = field(default_factory=list)  # key, expected, found
    ignored: list[str] = field(default_factory=list)
    matched: int = 0

    @property
    def ok(self) -> bool:
        return not (self.missing or self.unexpected or self.shape_mismatch)

    def summary(self, limit: int = 8) -> str:
        def few(keys):
            keys = list(keys)
            s = ", ".join(keys[:limit])
            return s + (f", ... ({len(keys) - limit} more)" if len(keys) > limit else "")

        parts = [f"{self.matched} tensors match"]
        if self.missing:
            parts.append(f"{len(self.missing)} missing: {few(self.missing)}")
        if self.unexpected:
            parts.append(f"{len(self.unexpected)} unexpected: {few(self.unexpected)}")
        if self.shape_mismatch:
            parts.append(f"{len(self.shape_mismatch)} with other shapes: "
                         + few(f"{k} expected {list(e)} found {list(f)}" for k, e, f in self.shape_mismatch))
        if self.ignored:
            parts.append(f"{len(self.ignored)} ignored (discriminator / mano buffers / training state)")
        return "; ".join(parts)


def _stub_class(module: str, name: str) -> type:
    """An inert stand-in for a pickled class: a dict that accepts any arguments, items and state."""

    def __setstate__(self, state):
        if isinstance(state, dict):
            self.__dict__.update(state)
        else:
            self.__dict__["_state"] = state

    return type(name, (dict,), {"__module__": module, "__setstate__": __setstate__,
                                "__init__": lambda self, *a, **k: None})


_TORCH_REBUILD = ("_rebuild_tensor", "_rebuild_tensor_v2", "_rebuild_tensor_v3", "_rebuild_parameter",
                  "_rebuild_parameter_with_state", "_rebuild_from_type_v2", "_rebuild_qtensor",
                  "_rebuild_sparse_tensor", "_rebuild_device_tensor_from_numpy", "_rebuild_meta_tensor_no_storage",
                  "_rebuild_wrapper_subclass")
_SAFE_BUILTINS = ("set", "frozenset", "slice", "complex", "bytearray", "tuple", "list", "dict", "object")


class _RestrictedUnpickler(pickle.Unpickler):
    """Fallback when torch's weights-only loader refuses the file (it cannot fill dict subclasses
    such as yacs' CfgNode): tensors, storages, dtypes and numpy arrays load normally; every other
    class is replaced by an inert dict stand-in and no other callable is reachable."""

    def find_class(self, module: str, name: str):
        root = module.split(".")[0]
        if root == "torch":
            if (module in ("torch._utils", "torch._tensor") and name in _TORCH_REBUILD) \
                    or (module == "torch" and (name.endswith("Storage") or name in ("Size", "device")
                                               or isinstance(getattr(torch, name, None), torch.dtype))) \
                    or (module == "torch.storage" and name in ("TypedStorage", "UntypedStorage")) \
                    or (module == "torch.nn.parameter" and name == "Parameter"):
                return super().find_class(module, name)
            raise pickle.UnpicklingError(f"checkpoint refers to {module}.{name}; refusing to load it")
        if module == "collections" and name == "OrderedDict":
            return super().find_class(module, name)
        if module in ("builtins", "__builtin__"):
            if name in _SAFE_BUILTINS:
                return super().find_class(module, name)
            raise pickle.UnpicklingError(f"checkpoint refers to builtins.{name}; refusing to load it")
        if root == "numpy" and name in ("_reconstruct", "ndarray", "dtype", "scalar") or \
                (root == "numpy" and name.endswith("DType")):
            return super().find_class(module, name)
        if module == "_codecs" and name == "encode":
            return super().find_class(module, name)
        return _stub_class(module, name)


_restricted_pickle = types.ModuleType("demoforge_restricted_pickle")
_restricted_pickle.Unpickler = _RestrictedUnpickler  # type: ignore[attr-defined]
_restricted_pickle.load = lambda f, **kw: _RestrictedUnpickler(f, **kw).load()  # type: ignore[attr-defined]
_restricted_pickle.__dict__.update({k: getattr(pickle, k) for k in ("UnpicklingError", "HIGHEST_PROTOCOL")})


def _torch_load(path: Path):
    try:
        return torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except pickle.UnpicklingError:
        pass
    except RuntimeError as e:  # legacy (non-zip) files cannot be memory-mapped
        if "mmap" not in str(e):
            raise
        try:
            return torch.load(path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError:
            pass
    return torch.load(path, map_location="cpu", weights_only=False, pickle_module=_restricted_pickle)


def read_state_dict(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """The tensors of a HaMeR checkpoint: a Lightning ``.ckpt`` (its ``state_dict``) or a plain state dict."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise CheckpointError(f"HaMeR checkpoint not found: {path}. Pass the local path of hamer.ckpt "
                              "(from the HaMeR release, _DATA/hamer_ckpts/checkpoints/hamer.ckpt; licensed, "
                              "not downloaded by demoforge)")
    try:
        obj = _torch_load(path)
    except Exception as e:  # noqa: BLE001 - any unreadable file becomes one clear error
        raise CheckpointError(f"cannot read {path} as a PyTorch checkpoint: {type(e).__name__}: {e}") from e
    sd = obj.get("state_dict", obj) if isinstance(obj, dict) else None
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise CheckpointError(f"{path} holds no state_dict of tensors (found {type(obj).__name__}"
                              + (f" with keys {sorted(obj)[:10]}" if isinstance(obj, dict) else "") + ")")
    return dict(sd)


def check_state_dict(net: torch.nn.Module, sd: dict[str, torch.Tensor]) -> KeyReport:
    """Compare checkpoint tensors with the network's parameters and buffers (names and shapes)."""
    want = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    rep = KeyReport()
    for k, v in sd.items():
        if k in want:
            if tuple(v.shape) != want[k]:
                rep.shape_mismatch.append((k, want[k], tuple(v.shape)))
            else:
                rep.matched += 1
        elif k.startswith(IGNORED_PREFIXES):
            rep.ignored.append(k)
        else:
            rep.unexpected.append(k)
    rep.missing = [k for k in want if k not in sd]
    return rep


def load_hamer(path: str | os.PathLike, config: HamerConfig | None = None, strict: bool = True) -> tuple[HamerNet, KeyReport]:
    """Build a :class:`HamerNet` (released sizes unless ``config``) and load the checkpoint into it.

    With ``strict`` any missing, unexpected or mis-shaped key raises :class:`CheckpointError` naming
    them; otherwise the matching tensors are loaded and the report says what was not.
    """
    sd = read_state_dict(path)
    cfg = config or HamerConfig()
    with torch.device("meta"):  # shapes only: no 2.5 GB random initialisation before the check
        net = HamerNet(cfg)
    rep = check_state_dict(net, sd)
    if rep.ok:
        net.load_state_dict({k: v for k, v in sd.items() if k in rep_keys(net)}, strict=True, assign=True)
        return net.eval(), rep
    if strict:
        raise CheckpointError(f"{path} does not match the HaMeR network "
                              f"({'released sizes' if config is None else 'the given config'}): {rep.summary(limit=6)}. "
                              "Is it the released hamer.ckpt? Pass strict=False to load the matching part.")
    net = HamerNet(cfg)  # non-strict: random weights where the checkpoint has none
    bad = {k for k, _, _ in rep.shape_mismatch}
    net.load_state_dict({k: v for k, v in sd.items() if k in rep_keys(net) and k not in bad}, strict=False)
    return net.eval(), rep


def rep_keys(net: torch.nn.Module) -> set[str]:
    return set(net.state_dict().keys())


def save_random_checkpoint(path: str | os.PathLike, config: HamerConfig, seed: int = 0, std: float = 0.02,
                           extra_keys: bool = True, hyper_parameters: object | None = None) -> dict[str, torch.Tensor]:
    """Write a Lightning-style checkpoint with random weights in the released key layout (tests,
    benchmarks). ``extra_keys`` adds ``discriminator.*``, ``mano.*`` and ``initialized`` like the
    real file. Returns the network's state dict."""
    g = torch.Generator().manual_seed(seed)
    net = HamerNet(config)
    sd = {}
    for k, v in net.state_dict().items():
        if k.endswith("norm.weight") or k.endswith(("norm1.weight", "norm2.weight")):
            sd[k] = 1.0 + std * torch.randn(v.shape, generator=g)
        else:
            sd[k] = std * torch.randn(v.shape, generator=g)
    if "mano_head.init_cam" in sd:  # a positive crop scale like mano_mean_params.npz's (about 0.9)
        sd["mano_head.init_cam"] = torch.tensor([[0.9, 0.0, 0.0]]) + std * torch.randn(1, 3, generator=g)
    full = dict(sd)
    if extra_keys:
        full.update({"discriminator.D_conv1.weight": torch.randn(32, 9, 1, 1, generator=g),
                     "mano.v_template": torch.zeros(778, 3), "mano.joint_map": torch.arange(21),
                     "initialized": torch.tensor(True)})
    obj = {"state_dict": full, "epoch": 0, "global_step": 0, "pytorch-lightning_version": "2.1.0"}
    if hyper_parameters is not None:
        obj["hyper_parameters"] = hyper_parameters
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)
    return sd
