"""ik_qp (lib/sim/robots/ik_qp.py): the IK's quadratic program without mink's and qpsolvers' per-call layers
is mink's, bit for bit, and the geom pairs it leaves out are ones MuJoCo finds nothing near."""

import mink
import mujoco
import numpy as np
import pytest
import qpsolvers
from scipy.spatial.transform import Rotation

from tests.support.aloha import ARMS, ARMS_2F140, fk as _fk


@pytest.mark.parametrize("robot", [ARMS, ARMS_2F140])
def test_the_ik_step_is_minks_bit_for_bit(robot):
    """ik_qp.StepQP (the IK's QP without mink's and qpsolvers' per-call layers) gives the step mink.build_ik and
    qpsolvers' DAQP give, to the last bit, at configurations all over the ranges (the collision limits active
    and not), each arm followed or held, both time steps the IK uses; the geom pairs it leaves out as far
    (ik_qp.FarPairs) are ones MuJoCo finds nothing within the detection distance of."""
    ik = robot.ik("pouring")
    assert ik.qp.lean
    rng = np.random.default_rng(0)
    kept = 0
    for k in range(60):
        q = np.clip(ik.rest + rng.normal(scale=0.8, size=12), ik.lower, ik.upper)
        target = _fk(robot, np.clip(q + rng.normal(scale=0.1, size=12), ik.lower, ik.upper)[None])[0]
        wxyz = Rotation.from_quat(target[:, 3:7]).as_quat(scalar_first=True)
        ik.cfg.update(q)
        ik._set_targets(target[:, :3], wxyz, np.array([True, k % 3 > 0]))
        dt = 1.0 if k % 2 else 1 / 30
        want = qpsolvers.solve_problem(mink.build_ik(ik.cfg, ik.tasks, dt, 1e-12, ik.limits), solver="daqp")
        got = ik.qp.solve(dt)
        assert want.found and got is not None and np.array_equal(got, want.x), k
        # the pairs it leaves out as far: MuJoCo finds nothing within their detection distance
        far = ik.qp.far(ik.cfg.data)
        for lim in ik.qp.pairwise:
            for (g1, g2), out in zip(lim.geom_id_pairs, far[ik.qp.far.of(lim)]):
                dist = mujoco.mj_geomDistance(ik.model, ik.cfg.data, g1, g2, lim.collision_detection_distance, None)
                assert not out or dist == lim.collision_detection_distance, (k, g1, g2, dist)
        kept += len(far) - sum(far)
    assert 0 < kept < 60 * len(far)  # some pairs left out, some not
