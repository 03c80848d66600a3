"""Take sources: what a take is on disk (a take folder with images or an mp4, a RealSense recording, a
Record3D export, a ROS 2 bag), each one module behind one interface (:class:`TakeSource`, whose opened
take decodes with its :class:`TakeDecoder`) and a registry; :func:`demoforge.lib.takes.open_take` asks
them in order which one claims a path."""

from demoforge.lib.takes.sources.base import (
    KINDS, SOURCES, TakeDecoder, TakeSource, UnknownTakeSource, available_sources, cache_key_inputs, claiming_source,
    find_takes, get_source, register_source, source_for, take_root,
)
from demoforge.lib.takes.sources.recording import (
    Recording, RecordingDecoder, RecordingIndex, RecordingSource, place_on_time_axis, remember_options, sidecar_dir,
)

__all__ = [
    "KINDS", "SOURCES", "Recording", "RecordingDecoder", "RecordingIndex", "RecordingSource", "TakeDecoder",
    "TakeSource", "UnknownTakeSource", "available_sources", "cache_key_inputs", "claiming_source", "find_takes",
    "get_source", "place_on_time_axis", "register_source", "remember_options", "sidecar_dir", "source_for",
    "take_root",
]
