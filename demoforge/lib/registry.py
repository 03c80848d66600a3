"""One registry for the things demoforge looks up by name: robots (demoforge.lib.robot_spec), take
sources (lib/takes/sources), hand detectors (lib/perception/detectors) and LLM backends (lib/llm).

    DETECTORS = Registry("hand detector", {"simulated": "demoforge.lib.perception.detectors.simulated:SimulatedDetector"})
    DETECTORS.register("mine", MyDetector)          # an object, or a lazy "module:attribute" string
    DETECTORS.names()                                # ("simulated", "mine"): in the order registered
    DETECTORS.get("simulated")                       # imports the module now, once
    DETECTORS.get("nosuch")                          # UnknownNameError: one line listing the names

A lazy entry is imported on the first :meth:`Registry.get`, never before: the command line lists and
checks the names without loading MediaPipe, llama.cpp, pyrealsense2 or MuJoCo. An unknown name is an
:class:`~demoforge.lib.errors.UnknownNameError` (a user error: one line, exit code 2), or the subclass
a registry is made with (``RobotError``, a take source's ``TakeError``) where callers catch that.
"""

from __future__ import annotations

import importlib
from typing import Generic, Iterator, Mapping, TypeVar

from demoforge.lib.errors import UnknownNameError

T = TypeVar("T")

__all__ = ["Registry", "UnknownNameError", "unknown_name"]


def unknown_name(kind: str, name: object, choices, error: type[UnknownNameError] = UnknownNameError) -> UnknownNameError:
    """The error for a `kind` named `name` that is none of `choices`: ``unknown robot 'ur5'; choose one of:
    grippers, aloha``."""
    choices = tuple(choices)
    return error(f"unknown {kind} {name!r}; choose one of: {', '.join(choices) or '(none)'}",
                 kind=kind, name=str(name), choices=choices)


class Registry(Generic[T]):
    """Names -> objects (classes, factories), each given as the object or as a lazy "module:attribute"."""

    def __init__(self, kind: str, entries: Mapping[str, T | str] | None = None,
                 error: type[UnknownNameError] = UnknownNameError):
        self.kind = kind
        self.error = error
        self._entries: dict[str, T | str] = dict(entries or {})

    def register(self, name: str, target: T | str) -> None:
        """Add (or replace) `name`: the object, or "module:attribute" imported on first :meth:`get`."""
        if isinstance(target, str) and target.count(":") != 1:
            raise ValueError(f"a lazy {self.kind} is 'module:attribute', got {target!r}")
        self._entries[name] = target

    def names(self) -> tuple[str, ...]:
        """The registered names, in the order they were registered."""
        return tuple(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._entries)

    def check(self, name: str) -> str:
        """`name` if it is registered, else the one-line error listing the names (nothing is imported)."""
        if name not in self._entries:
            raise unknown_name(self.kind, name, self.names(), self.error)
        return name

    def is_loaded(self, name: str) -> bool:
        """Whether `name`'s object is at hand (registered as an object, or already imported)."""
        return not isinstance(self._entries[self.check(name)], str)

    def get(self, name: str) -> T:
        """The object registered as `name`, its module imported now if it is a lazy entry (once)."""
        entry = self._entries[self.check(name)]
        if isinstance(entry, str):
            module, attr = entry.split(":")
            entry = getattr(importlib.import_module(module), attr)
            self._entries[name] = entry
        return entry

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}: {', '.join(self.names())})"
