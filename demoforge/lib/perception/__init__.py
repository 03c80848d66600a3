"""Perception on top of the hand detectors: what a per-frame detector's output may be trusted for.

Detectors (demoforge.lib.perception.detectors) answer frame by frame; this package holds the detector-agnostic logic that
looks across frames -- the temporal hand tracker (:mod:`demoforge.lib.perception.tracking`), which turns
per-frame detections into hand tracks born only on sustained evidence, with a stable left/right
identity, checked against the depth image, and a per-hand verdict on whether the take's trajectory
of that hand can be trusted.
"""
