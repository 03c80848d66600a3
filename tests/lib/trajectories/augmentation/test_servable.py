"""lib/trajectories/augmentation/servable.py: a database drawn where a robot can serve it."""

import numpy as np
import pytest

from demoforge.lib.sim.robots import get_robot
from demoforge.lib.sim.robots.aloha.screening import screen_episodes
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import generate_episodes
from demoforge.lib.trajectories.augmentation.servable import generate_servable
from demoforge.lib.trajectories.augmentation.source import from_scripted_demo


@pytest.fixture(scope="module")
def pouring_source():
    t = get_task("pouring")
    return from_scripted_demo(t, t.scripted_demo(0))


def _right_half(batch, rows):
    """A stand-in robot that serves the scenes moved to the right (dx > 0) only."""
    return batch.params[rows, 0, 0] > 0.0


def test_every_final_placement_is_served_and_the_kinds_are_kept(pouring_source):
    plain = generate_episodes(pouring_source, n=400, n_mirrored=200, seed=3)
    draw = generate_servable(pouring_source, _right_half, n=400, n_mirrored=200, seed=3, rounds=8)
    b = draw.batch
    assert draw.served[1:].all() and draw.rounds >= 1
    assert (b.params[1:, 0, 0] > 0).all() and b.valid[1:].all()
    assert (b.kind == plain.kind).all()  # each row keeps its kind: translated, then mirrored
    np.testing.assert_array_equal(b.params[0], 0.0)  # episode 0 stays the demonstration
    kept = (plain.params[1:, 0, 0] > 0) & plain.valid[1:]  # served at the first draw: untouched
    np.testing.assert_array_equal(b.params[1:][kept], plain.params[1:][kept])
    redrawn = b.params[1:][~kept, 0, 0]
    assert redrawn.min() > 0 and redrawn.max() < 0.15 and np.ptp(redrawn) > 0.1  # the same range, right half
    again = generate_servable(pouring_source, _right_half, n=400, n_mirrored=200, seed=3, rounds=8)
    np.testing.assert_array_equal(again.batch.params, b.params)  # reproducible
    assert draw.judged > 401  # the redraws were judged too


def test_zero_rounds_is_the_plain_draw(pouring_source):
    plain = generate_episodes(pouring_source, n=100, n_mirrored=50, seed=1)
    draw = generate_servable(pouring_source, _right_half, n=100, n_mirrored=50, seed=1, rounds=0)
    np.testing.assert_array_equal(draw.batch.params, plain.params)
    assert draw.rounds == 0 and draw.served[1:].sum() < 100


def test_the_arms_screening_serves_the_redrawn_open_container_database():
    t = get_task("open_container")
    src = from_scripted_demo(t, t.scripted_demo(0))
    arms = get_robot("aloha", "2f140")

    def serves(batch, rows):
        return screen_episodes(arms, "open_container", batch.episode_actions(rows), batch.lengths[rows],
                               batch.keypoints[rows]).executable

    plain = generate_episodes(src, n=80, n_mirrored=40, seed=0)
    first_share = serves(plain, np.arange(1, 81)).mean()
    draw = generate_servable(src, serves, n=80, n_mirrored=40, seed=0, rounds=8)
    assert first_share < 0.3  # the uniform draw: most placements out of the arms' reach or range
    assert draw.served[1:].mean() >= 0.95
    rows = np.flatnonzero(draw.served)
    assert serves(draw.batch, rows).all()  # the written batch's episodes are the ones judged
