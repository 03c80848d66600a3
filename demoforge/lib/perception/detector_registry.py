"""The hand detectors by name (lib/perception/detectors): here, apart from their interface (numpy), so that the
command line checks and lists `--detector` without loading numpy, scipy or a backend."""

from __future__ import annotations

from typing import Any, Callable

from demoforge.lib.registry import Registry

#: name -> a callable returning a HandDetector (its class), or a lazy "module:attribute"; an unknown name
#: is an UnknownNameError (a user error, and a ValueError) listing the names
DETECTORS: Registry[Callable[..., Any]] = Registry("hand detector", {
    "hamer": "demoforge.lib.perception.hamer.backend:HamerDetector",
    "mediapipe": "demoforge.lib.perception.detectors.mediapipe_backend:MediaPipeDetector",
    "precomputed": "demoforge.lib.perception.detectors.precomputed:PrecomputedDetector",
    "simulated": "demoforge.lib.perception.detectors.simulated:SimulatedDetector",
})


def available_detectors() -> list[str]:
    return sorted(DETECTORS.names())
