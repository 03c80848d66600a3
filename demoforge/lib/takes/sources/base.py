"""The take-source interface and its registry.

A take source turns one kind of path (a take folder, a RealSense recording, a Record3D export, a ROS 2
bag) into a :class:`demoforge.lib.takes.types.Take`: intrinsics, the frame index with each frame's
timestamp and problems, and, for a recording, a decoder that streams RGB (uint8) and depth (float32
metres along the camera z, registered to the RGB image, 0 = invalid) frame by frame.

Adding a source::

    class MySource(TakeSource):
        name = "mine"; description = "..."
        @classmethod
        def claims(cls, path): ...          # cheap: suffix, a header, a file in the folder
        def open(self, path, *, require_pose=True, **options): ...  # -> Take
    register_source("mine", MySource)
"""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Any

from demoforge.lib.errors import UnknownNameError
from demoforge.lib.registry import Registry
from demoforge.lib.takes.types import Take, TakeError


class TakeSource(abc.ABC):
    """One kind of take on disk."""

    name: str = ""
    description: str = ""

    @classmethod
    @abc.abstractmethod
    def claims(cls, path: Path) -> bool:
        """True if ``path`` is this kind of take (decided from names and headers, never by decoding)."""

    @abc.abstractmethod
    def open(self, path: Path, *, require_pose: bool = True, **options: Any) -> Take:
        """The opened take; raises :class:`TakeError` (one line: what is wrong, how to fix it)."""


class UnknownTakeSource(TakeError, UnknownNameError):
    """A take source name that is not registered (the message lists the registered ones)."""


# name -> "module:Class" (imported on first use: pyrealsense2 and rosbags load only when needed);
# the order is the order :func:`source_for` asks them in
SOURCES: Registry[type[TakeSource]] = Registry("take source", {
    "folder": "demoforge.lib.takes.sources.folder:FolderSource",
    "mp4": "demoforge.lib.takes.sources.folder:Mp4Source",
    "realsense": "demoforge.lib.takes.sources.realsense:RealSenseSource",
    "rosbag2": "demoforge.lib.takes.sources.rosbag2:RosBag2Source",
    "record3d": "demoforge.lib.takes.sources.record3d:Record3DSource",
}, error=UnknownTakeSource)

#: what a take can be, for error messages
KINDS = ("a take folder (camera.json + rgb/ or rgb.mp4 + depth/), a RealSense recording (.bag, .db3), "
         "a Record3D export (.r3d or its folder), or a ROS 2 bag (.mcap, .db3 or its folder)")


def register_source(name: str, source: type[TakeSource] | str) -> None:
    """Add (or replace) a take source; sources registered later are asked after the built-in ones."""
    SOURCES.register(name, source)


def available_sources() -> list[str]:
    return list(SOURCES.names())


def get_source(name: str) -> type[TakeSource]:
    """The source class registered as `name` (imported now if it was not yet); an unknown name is a
    TakeError listing the registered ones."""
    return SOURCES.get(name)


def take_root(path: str | Path) -> Path:
    """The path whose content is the take (its cache key): a take folder's video given as a file stands
    for the whole folder (depth/, camera.json), anything else for itself. Resolved."""
    p = Path(path).resolve()
    if p.is_file() and p.suffix.lower() == ".mp4" and (p.parent / "camera.json").is_file():
        return p.parent
    return p


def find_takes(root: Path) -> list[Path]:
    """Every take under ``root`` (any depth), sorted: take folders (camera.json) and recordings. A
    claimed folder is not searched further (a bag folder's .db3 is the bag, not another take), and
    recordings' side folders (``*.demoforge``) are skipped."""
    found: list[Path] = []

    def claimed(p: Path) -> bool:
        for name in SOURCES.names():
            if name != "mp4" or p.is_dir():
                if get_source(name).claims(p):
                    return True
        return False

    def walk(folder: Path) -> None:
        for p in sorted(folder.iterdir()):
            if p.name.startswith(".") or p.name.endswith(".demoforge"):
                continue
            if p.is_dir():
                if claimed(p):
                    found.append(p)
                else:
                    walk(p)
            elif p.suffix.lower() != ".mp4" and claimed(p):
                found.append(p)

    walk(root)
    return sorted(found)


def source_for(path: Path) -> type[TakeSource]:
    """The first registered source that claims ``path``; :class:`TakeError` when none does."""
    if not path.exists():
        raise TakeError(f"{path}: take folder does not exist (expected rgb/ or rgb.mp4, depth/, camera.json; "
                        f"or a recording file)")
    for name in SOURCES.names():
        cls = get_source(name)
        if cls.claims(path):
            return cls
    if path.is_dir() and not (path / "camera.json").is_file():
        raise TakeError(f"{path / 'camera.json'}: camera.json is missing; write it with K (3x3), width, height and "
                        f"T_world_camera (4x4 camera-to-world) (fps optional, default 30); or give {KINDS}")
    raise TakeError(f"{path}: not a take demoforge can read; expected {KINDS}")
