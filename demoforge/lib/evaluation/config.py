"""What the main job (`make evaluate`, flows/evaluate.py) runs: every option declared once.

``demoforge evaluate`` builds an :class:`EvaluateConfig` from its flags, the ``evaluate`` flow takes it
whole, the whole-run cache key (demoforge.runtime.run_cache) is its fields, and the report prints
them as the run's parameters.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from demoforge.lib.robot_spec import RobotSpec
from demoforge.lib.synth import MIRROR_CHOICES, mirror_flags

__all__ = ["DETECTORS", "GRID_ROBOTS", "ROBOTS", "EvaluateConfig", "MIRROR_CHOICES"]

# The hand detectors every take is ingested with, side by side: the simulated one (the ground truth
# through an error model; every later stage builds on its ingest) and MediaPipe, a real detector.
DETECTORS = ("simulated", "mediapipe")
# The robots every task's sample is executed with, side by side (their labels: demoforge.lib.robot_spec.RobotSpec):
# the floating grippers, the ALOHA arms with their own fingers and with the 2F-140.
ROBOTS = ("grippers", "aloha", "aloha+2f140")
# The arms Table 3's LLM-free and policy columns are judged with too, beside the first robot: the 2F-140 fits
# every object of the library (ALOHA's own fingers do not open around the bottle)
GRID_ROBOTS = ("aloha+2f140",)


def _names(value: Sequence[str] | str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    return (value,) if isinstance(value, str) else tuple(value)


@dataclass(frozen=True)
class EvaluateConfig:
    """tasks: the tasks of the synthetic takes (None: all six); takes: synthetic takes per task and
    mirror flag; seed: their first seed (also of databases, query scenes and policy); mirror: both,
    no or yes; episodes: episodes per task database; arctic_root: ARCTIC's folder (None: the
    DEMOFORGE_ARCTIC_ROOT setting, else no ARCTIC table); sim_episodes: episodes per task executed in
    MuJoCo; stability_episodes / stability_repeats: the stability check (0 episodes skips it);
    llm_tasks: tasks of Table 3; grid_scenes: its query scenes (protocol thesis, first take; 0 skips
    it); trials: of those, the scenes of the three LLM strategies; llm_backend, llm_options,
    llm_structured, llm_number_format: the LLM (demoforge.flows.table3); variation_trials: scenes per
    task and variation kind of the Table 4 analogue; policy_tasks, policy_epochs, policy_waypoints,
    policy_trials: the learned policy (0 trials skips it); scaling_scenes, scaling_sizes, scaling_steps: the small
    data-scaling table of the policy tasks with the first grid robot (0 scenes skips it); detectors: the hand detectors each take is
    ingested with, side by side (the simulated one always); robots: the robots (`name` or `name+hand`)
    each task's sample is executed with, side by side (the stability check and the other evaluations
    use the first); grid_robots: the arm robots Table 3's LLM-free and policy columns are judged with
    too, beside the first robot (each retrieving from and learning from the episodes its screening lets
    through)."""

    tasks: tuple[str, ...] | None = None
    takes: int = 1
    seed: int = 0
    mirror: str = "both"
    episodes: int = 10_000
    arctic_root: str | None = None
    sim_episodes: int = 20
    stability_episodes: int = 10
    stability_repeats: int = 3
    llm_tasks: tuple[str, ...] = ("pouring",)
    trials: int = 1
    grid_scenes: int = 5
    llm_backend: str = "local"
    llm_options: Mapping[str, Any] = field(default_factory=dict)
    llm_structured: bool | None = None
    llm_number_format: str | None = None
    variation_trials: int = 2
    policy_tasks: tuple[str, ...] = ("pouring",)
    policy_epochs: int = 6
    policy_waypoints: int = 40
    policy_trials: int = 5
    scaling_scenes: int = 6
    scaling_sizes: tuple[int, ...] = (1, 50)
    scaling_steps: int = 600
    detectors: tuple[str, ...] = DETECTORS
    robots: tuple[str, ...] = ROBOTS
    grid_robots: tuple[str, ...] = GRID_ROBOTS

    def __post_init__(self):
        for name in ("tasks", "llm_tasks", "policy_tasks", "detectors", "robots", "grid_robots"):  # CLI or JSON lists
            object.__setattr__(self, name, _names(getattr(self, name)))
        object.__setattr__(self, "scaling_sizes", tuple(int(n) for n in self.scaling_sizes))
        if not self.robots:
            raise ValueError("robots must name at least one robot")
        for name in ("robots", "grid_robots"):  # checked here, once: an unknown robot or hand is a RobotError
            object.__setattr__(self, name, tuple(dict.fromkeys(RobotSpec.parse(r).label for r in getattr(self, name) or ())))
        mirror_flags(self.mirror)  # refuses an unknown choice
        if int(self.takes) < 1 or int(self.episodes) < 1:
            raise ValueError(f"need takes >= 1 and episodes >= 1, got {self.takes} and {self.episodes}")
        counts = ("sim_episodes", "stability_episodes", "trials", "grid_scenes", "variation_trials",
                  "policy_trials", "scaling_scenes")
        negative = [n for n in counts if int(getattr(self, n)) < 0]
        if negative:
            raise ValueError(f"{negative[0]} must be >= 0, got {getattr(self, negative[0])}")

    @property
    def robot_specs(self) -> tuple[RobotSpec, ...]:
        """`robots` as RobotSpecs (the first: the stability check's and the single-robot evaluations')."""
        return tuple(RobotSpec.parse(r) for r in self.robots)

    @property
    def grid_robot_specs(self) -> tuple[RobotSpec, ...]:
        return tuple(RobotSpec.parse(r) for r in self.grid_robots)

    def replace(self, **changes: Any) -> "EvaluateConfig":
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, Any]:
        """The fields as plain JSON-able values (lists for tuples): the run key and the report's parameters."""
        return {k: (list(v) if isinstance(v, tuple) else dict(v) if isinstance(v, Mapping) else v)
                for k, v in ((f.name, getattr(self, f.name)) for f in dataclasses.fields(self))}
