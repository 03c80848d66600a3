"""The take-source interface and its registry.

A take source turns one kind of path (a take folder with images or a video, a RealSense recording, a
Record3D export, a ROS 2 bag) into a :class:`demoforge.lib.takes.types.Take`: intrinsics, the frame
index with each frame's timestamp and problems, and its :class:`TakeDecoder` (``Take.decoder``), which
streams RGB (uint8) and depth (float32 metres along the camera z, registered to the RGB image,
0 = invalid) frame by frame. Every source owns its decoding: demoforge.lib.takes.reader's
``iter_frames`` / ``iter_depth`` / ``read_frame`` only ask the take's decoder. A source also says what
holds a take's content besides its path (:meth:`TakeSource.cache_key_inputs`: a recording's side
folder), which the stage cache hashes with it.

Adding a source::

    class MySource(TakeSource):
        name = "mine"; description = "..."
        @classmethod
        def claims(cls, path): ...          # cheap: suffix, a header, a file in the folder
        def open(self, path, *, require_pose=True, prefer="images", cache_dir=None, **options):
            ...                             # -> Take(..., decoder=MyDecoder(...))
    register_source("mine", MySource)
"""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from demoforge.lib.errors import UnknownNameError
from demoforge.lib.registry import Registry
from demoforge.lib.takes.types import Take, TakeError


class TakeDecoder(abc.ABC):
    """How an opened take's frames are decoded (``Take.decoder``); each take source gives its own.

    Decoding never raises for one bad frame: a frame whose RGB cannot be had is flagged on
    ``take.frames`` and left out, a frame whose depth cannot be had gets all-zero depth (flagged).
    """

    #: True when decoding the frames' RGB also reads and checks their depth (a recording's frames come
    #: as RGB-D pairs), so a separate depth pass would find nothing new
    checks_depth_with_rgb: bool = False

    @property
    def info(self) -> dict:
        """Source details (a recording's topics, device, depth scale ...); empty for a take folder."""
        return {}

    @abc.abstractmethod
    def rgbd(self, take: Take, idx: list[int], batch_size: int, num_workers: int
             ) -> Iterator[list[tuple[int, np.ndarray, np.ndarray]]]:
        """The frames ``idx`` (increasing, each with usable RGB by its status so far) decoded, in
        groups of at most ``batch_size``: (index, RGB uint8 (H, W, 3), depth float32 metres (H, W),
        invalid = 0). ``num_workers``: threads that may decode in parallel."""

    @abc.abstractmethod
    def depth(self, take: Take, batch_size: int, num_workers: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Every frame's depth in order, whatever its RGB: (indices (B,), depth float32 (B, H, W))."""

    @abc.abstractmethod
    def lone_depth(self, take: Take, index: int) -> np.ndarray:
        """The depth of a frame whose RGB is unusable (what :func:`read_frame` returns with None)."""


class TakeSource(abc.ABC):
    """One kind of take on disk."""

    name: str = ""
    description: str = ""

    @classmethod
    @abc.abstractmethod
    def claims(cls, path: Path) -> bool:
        """True if ``path`` is this kind of take (decided from names and headers, never by decoding)."""

    @abc.abstractmethod
    def open(self, path: Path, *, require_pose: bool = True, prefer: str = "images", cache_dir: Any = None,
             **options: Any) -> Take:
        """The opened take, with its :class:`TakeDecoder`; raises :class:`TakeError` (one line: what is
        wrong, how to fix it). ``prefer`` and ``cache_dir`` are a take folder's choices (images or
        video; where a truncated video's recovered stream goes), ignored by sources without them;
        ``options`` are the source's own (a ROS 2 bag's topics)."""

    @classmethod
    def cache_key_inputs(cls, path: Path) -> dict[str, Path]:
        """What holds this take's content besides ``path`` itself, by name (a recording's side folder:
        ``{"sidecar": folder}``): the stage cache hashes each with the path (demoforge.tasks.common)."""
        return {}


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


def claiming_source(path: Path) -> type[TakeSource] | None:
    """The first registered source that claims ``path`` (an existing path), or None."""
    for name in SOURCES.names():
        cls = get_source(name)
        if cls.claims(path):
            return cls
    return None


def source_for(path: Path) -> type[TakeSource]:
    """The first registered source that claims ``path``; :class:`TakeError` when none does."""
    if not path.exists():
        raise TakeError(f"{path}: take folder does not exist (expected rgb/ or rgb.mp4, depth/, camera.json; "
                        f"or a recording file)")
    cls = claiming_source(path)
    if cls is not None:
        return cls
    if path.is_dir() and not (path / "camera.json").is_file():
        raise TakeError(f"{path / 'camera.json'}: camera.json is missing; write it with K (3x3), width, height and "
                        f"T_world_camera (4x4 camera-to-world) (fps optional, default 30); or give {KINDS}")
    raise TakeError(f"{path}: not a take demoforge can read; expected {KINDS}")


def cache_key_inputs(path: str | Path) -> dict[str, Path]:
    """What holds the content of the take at ``path`` besides the path itself, by name, as the source
    that claims it says (:meth:`TakeSource.cache_key_inputs`); nothing for a path no source claims
    (any other file or folder given to a stage)."""
    path = Path(path)
    if not path.exists():
        return {}
    cls = claiming_source(path)
    return {} if cls is None else cls.cache_key_inputs(path)
