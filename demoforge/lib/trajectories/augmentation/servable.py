"""An episode database whose placements a robot can serve: the episodes are drawn as generate_episodes draws
them, a robot judges which it can execute (`serves`: the arms' screening), and the placements of the others
are drawn again from the same distribution, up to `rounds` times. The result is the uniform draw restricted to
the placements the robot serves (rejection sampling), each episode keeping its kind (translated or mirrored).

    draw = generate_servable(source, serves, n=10_000, n_mirrored=5_000, seed=0, rounds=12, **generation)
    draw.batch      # the EpisodeBatch to write
    draw.served     # (n + 1,) bool: the robot's verdict on each final placement (episode 0: the demonstration)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from demoforge.lib.trajectories.augmentation.generate import EpisodeBatch, draw_placements, generate_episodes
from demoforge.lib.trajectories.augmentation.source import DemoSource

#: generate_episodes' options that shape the placements' distribution (the redraws use the same)
PLACEMENT_OPTIONS = ("translation_range", "yaw_range", "independent", "stack_radius")
#: episodes judged at once (the screening holds their actions: about 5 MB each per 100 steps)
JUDGE_CHUNK = 1024
#: candidates drawn per missing episode in a round, at most
MAX_CANDIDATES = 16

#: serves(batch, rows) -> (len(rows),) bool: whether the robot can execute those episodes of the batch
Serves = Callable[[EpisodeBatch, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ServableDraw:
    batch: EpisodeBatch
    served: np.ndarray  # (n + 1,) bool, the robot's verdict on each final placement
    rounds: int  # rounds of redrawing that ran
    judged: int  # placements the robot judged in all

    @property
    def share(self) -> float:
        return float(self.served.mean())


def _judge(serves: Serves, batch: EpisodeBatch, rows: np.ndarray) -> np.ndarray:
    """Valid (generation's own checks) and served, for rows of batch, JUDGE_CHUNK at a time."""
    ok = batch.valid[rows].copy()
    for i in range(0, len(rows), JUDGE_CHUNK):
        part = ok[i:i + JUDGE_CHUNK]  # a view: what serves says lands in ok
        todo = rows[i:i + JUDGE_CHUNK][part]
        if len(todo):
            part[part] = np.asarray(serves(batch, todo), bool)
    return ok


def generate_servable(source: DemoSource, serves: Serves, n: int = 10_000, n_mirrored: int = 5_000, seed: int = 0,
                      rounds: int = 8, progress: Callable[[int, int, int], None] | None = None,
                      **generation) -> ServableDraw:
    """generate_episodes(source, n, n_mirrored, seed, **generation), every augmented episode the robot does not
    serve (or that generation rejects) drawn again in up to `rounds` rounds; episode 0 stays the demonstration,
    served or not. A round draws about 1 / (the served rate so far) candidates per missing episode (at most
    MAX_CANDIDATES) and keeps each one's first served candidate. progress(round, missing, served) after the
    first draw (round 0) and each round."""
    if rounds < 0:
        raise ValueError(f"rounds must be >= 0, got {rounds}")
    n_plain = n - n_mirrored
    first = generate_episodes(source, n=n, n_mirrored=n_mirrored, seed=seed, **generation)
    served = _judge(serves, first, np.arange(len(first)))
    placements = first.params[1:].copy()
    rng = np.random.default_rng([seed, 1])  # the redraws' own stream: the first draw is generate_episodes' own
    shape = {k: generation[k] for k in PLACEMENT_OPTIONS if k in generation}
    judged, hits, ran = n, int(served[1:].sum()), 0
    if progress is not None:
        progress(0, n - hits, int(served.sum()))
    while ran < rounds:
        missing = np.flatnonzero(~served[1:])  # rows 1.. of the batch, plain before mirrored
        if not len(missing):
            break
        ran += 1
        per = int(np.clip(np.ceil(judged / max(hits, 1)), 1, MAX_CANDIDATES))
        slots = np.repeat(missing, per)  # each missing episode's candidates, in row order (plain ones first)
        k_mirr = int((slots >= n_plain).sum())
        fresh = draw_placements(source, len(slots), k_mirr, rng, **shape)
        trial = generate_episodes(source, n=len(slots), n_mirrored=k_mirr, seed=seed, placements=fresh, **generation)
        ok = _judge(serves, trial, np.arange(1, len(trial)))
        judged, hits = judged + len(slots), hits + int(ok.sum())
        first_ok = np.flatnonzero(ok)[np.unique(slots[ok], return_index=True)[1]]  # each slot's first success
        placements[slots[first_ok]] = fresh[first_ok]
        served[1 + slots[first_ok]] = True
        if progress is not None:
            progress(ran, len(missing), int(served.sum()))
    batch = first if judged == n else generate_episodes(source, n=n, n_mirrored=n_mirrored, seed=seed,
                                                       placements=placements, **generation)
    return ServableDraw(batch, served, ran, judged + 1)
