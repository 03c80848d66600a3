"""How a take is ingested: each option declared once.

The CLI builds an :class:`IngestOptions` from its flags, the flows take it whole (``ingest_take``,
``augment_take_flow``, ``ingest_folder``), and each stage receives the fields it reads: its cache key
is those fields, so changing the pose smoothing re-runs the gripper mapping and what follows it,
never the hand detection. A deployment's JSON parameters (a dict) are converted to the object by
Prefect's parameter validation. The episode database's counterpart is
demoforge.lib.trajectories.augmentation.options.AugmentOptions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping

__all__ = ["GRASP_PRIORS", "IngestOptions", "STATE_METHODS"]

STATE_METHODS = ("auto", "otsu", "threshold")  # open/close when the take has no labelled ranges
GRASP_PRIORS = ("pose", "twist", "off")  # how a closed hand's grasp is kept rigid (lib/ingest/gripper_mapping.py)


@dataclass(frozen=True)
class IngestOptions:
    """Options of one take's ingest (``demoforge ingest``; README "Your own recording").

    detector: ``simulated`` (synthetic takes), ``mediapipe``, ``precomputed`` or ``hamer``;
    detector_options: that detector's settings (``path`` of precomputed predictions, HaMeR's
    ``checkpoint``/``mano_model``/``box_source``, MediaPipe's ``running_mode``); alignment:
    demoforge.lib.ingest.alignment.AlignmentConfig fields; tracker:
    demoforge.lib.perception.tracking.TrackerConfig fields; state_method: one of STATE_METHODS;
    smoothing: segment-wise pose smoothing window in frames (0 = off); grasp_prior: one of
    GRASP_PRIORS; table_clearance: lowest pinch height above the table top, m (None = off);
    accept_bad_depth: flag every row of a take whose depth fails a check instead of stopping;
    video: also write the overlay MP4."""

    detector: str = "simulated"
    detector_options: Mapping[str, Any] = field(default_factory=dict)
    alignment: Mapping[str, Any] = field(default_factory=dict)
    tracker: Mapping[str, Any] = field(default_factory=dict)
    state_method: str = "auto"
    smoothing: int = 0
    grasp_prior: str = "pose"
    table_clearance: float | None = 0.010
    accept_bad_depth: bool = False
    video: bool = False

    def __post_init__(self):
        if self.state_method not in STATE_METHODS:
            raise ValueError(f"state_method must be one of {', '.join(STATE_METHODS)}, got {self.state_method!r}")
        if self.grasp_prior not in GRASP_PRIORS:
            raise ValueError(f"grasp_prior must be one of {', '.join(GRASP_PRIORS)}, got {self.grasp_prior!r}")
        if int(self.smoothing) < 0:
            raise ValueError(f"smoothing must be >= 0 frames, got {self.smoothing}")
        if self.table_clearance is not None and float(self.table_clearance) < 0:
            raise ValueError(f"table_clearance must be >= 0 m or None (off), got {self.table_clearance}")

    def replace(self, **changes: Any) -> "IngestOptions":
        return dataclasses.replace(self, **changes)
