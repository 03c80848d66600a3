"""How a take's episode database is generated: each option declared once (the CLI builds an
:class:`AugmentOptions`, ``augment_take_flow`` takes it whole; see demoforge.lib.ingest.options)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping

__all__ = ["AugmentOptions"]


@dataclass(frozen=True)
class AugmentOptions:
    """How many episodes a database holds and how they are drawn (``demoforge augment``).

    n: episodes besides the original demonstration; n_mirrored: how many of them are mirrored across
    the YZ plane with the arms' roles swapped; seed: the sampling seed; generation:
    demoforge.lib.trajectories.augmentation.generate_episodes keyword arguments, e.g.
    ``{"mode": "thesis", "independent": True, "yaw_range": [-0.5, 0.5]}`` (empty: its defaults)."""

    n: int = 10_000
    n_mirrored: int = 5_000
    seed: int = 0
    generation: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        if int(self.n) < 1 or not 0 <= int(self.n_mirrored) <= int(self.n):
            raise ValueError(f"need n >= 1 and 0 <= n_mirrored <= n, got n={self.n}, n_mirrored={self.n_mirrored}")

    @classmethod
    def half_mirrored(cls, n: int, seed: int = 0, **generation: Any) -> "AugmentOptions":
        """n episodes, half of them mirrored (the thesis's split)."""
        return cls(n=n, n_mirrored=n // 2, seed=seed, generation=generation)

    def replace(self, **changes: Any) -> "AugmentOptions":
        return dataclasses.replace(self, **changes)
