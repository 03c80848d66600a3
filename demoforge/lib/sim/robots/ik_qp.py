"""One IK iteration's quadratic program of ArmsIK (ik.py), without mink's and qpsolvers' per-call Python layers.

    qp = StepQP(configuration, tasks, limits)   # mink's FrameTasks (sites), an optional PostureTask, its limits
    dq = qp.solve(dt)                            # mink.build_ik(...) solved with DAQP: the step, or None

Each iteration mink.build_ik assembles the objective of the two pinch-site frame tasks and the posture task
and the inequalities of the configuration and collision limits, and qpsolvers hands them to DAQP. For
ArmsIK's fixed tasks and limits that assembly, a few hundred small numpy calls through mink's classes, costs
more than the solve. StepQP does the same arithmetic, in the same order, on the same arrays: mink's own
native Lie-group operations (the ones its FrameTask calls), MuJoCo's site Jacobian, the same weights,
products and stacking, mink's collision limits as they are, and DAQP called with the arguments qpsolvers
passes it. The step is bit for bit mink's (tests/lib/sim/robots/test_ik_qp.py compares the two); where mink runs
without its native operations (MINK_DISABLE_NATIVE), or with other tasks, solve() is mink's own path.
"""

from __future__ import annotations

from ctypes import c_int
from typing import Sequence

import numpy as np

DAMPING = 1e-12  # mink.build_ik's global Levenberg-Marquardt damping, as ArmsIK passes it
NO_LOWER = -1e30  # qpsolvers' lower bound of a one-sided inequality for DAQP
# m a geom pair's distance lower bound must exceed its detection distance by for FarPairs to leave it out: far
# above the rounding of the bound and of MuJoCo's single-precision mesh vertices
FAR_SLACK = 1e-3


class StepQP:
    """mink.build_ik(configuration, tasks, dt, DAMPING, limits) solved by DAQP (see the module docstring)."""

    def __init__(self, configuration, tasks: Sequence, limits: Sequence):
        # imported where the solver is built, as ik.py imports mink (DAQP is qpsolvers' backend)
        import daqp
        import mink
        import mujoco
        import qpsolvers

        self.mink, self.qpsolvers, self.daqp, self.mujoco = mink, qpsolvers, daqp, mujoco
        self.cfg, self.tasks, self.limits = configuration, list(tasks), list(limits)
        model = configuration.model
        self.nv = model.nv
        native = getattr(mink.tasks.frame_task, "_native", None)
        frames = [t for t in self.tasks if type(t) is mink.FrameTask and t.frame_type == "site"]
        postures = [t for t in self.tasks if type(t) is mink.PostureTask and t._v_ids is None]
        config = [lim for lim in self.limits if type(lim) is mink.ConfigurationLimit]
        others = [lim for lim in self.limits if type(lim) is not mink.ConfigurationLimit]
        # the fast path only for what it reproduces: site frame tasks first, then at most one posture task, the
        # configuration limit (hinge and slide joints, no ball joint) first among the limits
        self.lean = (native is not None and getattr(mink.configuration, "_native", None) is native
                     and self.tasks == frames + postures and len(postures) <= 1 and len(config) == 1
                     and self.limits[0] is config[0] and not len(config[0]._ball_qposadr)
                     and config[0].projection_matrix is not None)
        if not self.lean:
            return
        self.native = native
        self.frames = [(t, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, t.frame_name)
                        if isinstance(t.frame_name, str) else int(t.frame_name)) for t in frames]
        self.posture = postures[0] if postures else None
        rows = 6 * len(self.frames)
        self.W = np.empty((rows + (self.nv if self.posture is not None else 0), self.nv))
        self.e, self.jac = np.empty(len(self.W)), np.empty((6, self.nv))
        if self.posture is not None:  # its Jacobian is the identity: the weighted one is a constant
            self.W[rows:] = self.posture.cost[:, None] * np.eye(self.nv)
        self.config, self.others = config[0], others
        # the collision limits whose pairs mink checks one by one (no broadphase of its own): their far pairs are
        # left out by FarPairs first
        self.pairwise = [lim for lim in others if type(lim) is mink.CollisionAvoidanceLimit
                         and not (lim.broadphase and lim.max_num_contacts >= lim.broadphase_min_pairs)]
        self.far = FarPairs(model, self.pairwise, mujoco)
        self.other_pairs = [(lim, self.far.of(lim) if any(lim is p for p in self.pairwise) else None) for lim in others]
        P = self.config.projection_matrix
        self.config_G = np.vstack([P, -P])
        self.sense_dtype = np.dtype(c_int)  # numpy's ctypes lookup costs more than the array

    def solve(self, dt: float) -> np.ndarray | None:
        """The step dq (nv,) of mink's QP at the configuration's current joints, None when DAQP finds none."""
        if not self.lean:
            result = self.qpsolvers.solve_problem(
                self.mink.build_ik(self.cfg, self.tasks, dt, DAMPING, self.limits), solver="daqp")
            return result.x if result.found else None
        H, c = self._objective()
        G, h = self._inequalities(dt)
        lower = np.empty(len(h))
        lower.fill(NO_LOWER)  # np.full's values, without its Python layer
        x, _, exitflag, _ = self.daqp.solve(H, c, G, h, lower, np.zeros(len(h), dtype=self.sense_dtype),
                                            primal_start=None)
        return x if exitflag > 0 else None

    def _objective(self) -> tuple[np.ndarray, np.ndarray]:
        """mink's _compute_qp_objective: H = W^T W + (damping + sum of the tasks' mu) I, c = -e W, the weighted
        Jacobians W and errors e stacked task by task (into arrays kept from call to call: the posture task's
        rows of W are constant)."""
        native, mujoco = self.native, self.mujoco
        d, model, nv = self.cfg.data, self.cfg.model, self.nv
        W, e, jac, mu_total = self.W, self.e, self.jac, 0.0
        for i, (task, site) in enumerate(self.frames):  # FrameTask._error_and_jacobian, Task._weighted_residual
            rows = slice(6 * i, 6 * i + 6)
            xmat = d.site_xmat[site]
            frame = native.xmat_xpos_to_wxyz_xyz(xmat, d.site_xpos[site])
            mujoco.mj_jacSite(model, d, jac[:3], jac[3:], site)
            local = native.se3_rotation_adjoint_from_xmat(xmat) @ jac  # Configuration.get_frame_jacobian
            target = task.transform_target_to_world.wxyz_xyz
            error = native.se3_rminus(target, frame)
            jacobian = -native.se3_jlog(native.se3_inverse_multiply(target, frame)) @ local
            weighted_error = task.cost * (-task.gain * error)
            np.multiply(task.cost[:, None], jacobian, out=W[rows])
            e[rows] = weighted_error
            mu_total += task.lm_damping * float(weighted_error @ weighted_error)
        if self.posture is not None:  # PostureTask.compute_error: q minus its target
            task = self.posture
            error = np.empty(nv)
            mujoco.mj_differentiatePos(model, error, 1.0, task.target_q, d.qpos)
            weighted_error = task.cost * (-task.gain * error)
            e[6 * len(self.frames):] = weighted_error
            mu_total += task.lm_damping * float(weighted_error @ weighted_error)
        H = W.T @ W
        c = -(e @ W)
        H.flat[:: nv + 1] += DAMPING + mu_total
        return H, c

    def _inequalities(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """mink's _compute_qp_inequalities: the configuration limit's rows (ConfigurationLimit's arithmetic), then
        each other limit's own."""
        lim, model, q = self.config, self.cfg.model, self.cfg.data.qpos
        delta_q_max, delta_q_min = np.empty(self.nv), np.empty(self.nv)
        self.mujoco.mj_differentiatePos(model, delta_q_max, 1.0, q, lim.upper)
        self.mujoco.mj_differentiatePos(model, delta_q_min, 1.0, lim.lower, q)
        G_list = [self.config_G]
        h_list = [lim.gain * delta_q_max[lim.indices], lim.gain * delta_q_min[lim.indices]]
        far = self.far(self.cfg.data)
        for other, pairs in self.other_pairs:
            if pairs is not None:
                G, h = self._collision(other, dt, far[pairs])
            else:
                G, h = other.compute_qp_inequalities(self.cfg, dt)
            if G is not None or h is not None:  # Constraint.inactive
                G_list.append(G)
                h_list.append(h)
        return np.concatenate(G_list), np.concatenate(h_list)  # np.vstack and np.hstack of these 2-D and 1-D arrays

    def _collision(self, lim, dt: float, far: list[bool]) -> tuple[np.ndarray, np.ndarray]:
        """mink's CollisionAvoidanceLimit.compute_qp_inequalities without its broadphase (as mink skips it for
        fewer than broadphase_min_pairs pairs): a row per geom pair within its detection distance, the pair's
        normal velocity bounded. far: per pair, FarPairs proves it beyond it (mj_geomDistance would return
        the detection distance itself, which mink skips)."""
        mujoco, model, data = self.mujoco, self.cfg.model, self.cfg.data
        upper_bound = np.empty(lim.max_num_contacts)
        upper_bound.fill(np.inf)
        coefficient_matrix = np.zeros((lim.max_num_contacts, model.nv))
        fromto, normal, jac1, jac2 = lim._fromto, lim._normal, lim._jac1, lim._jac2
        distmax, min_dist = lim.collision_detection_distance, lim.minimum_distance_from_collisions
        for idx, ((geom1_id, geom2_id), skip) in enumerate(zip(lim.geom_id_pairs, far)):
            if skip:
                continue
            dist = mujoco.mj_geomDistance(model, data, geom1_id, geom2_id, distmax, fromto)
            if abs(dist - distmax) < 1e-12:
                continue
            # compute_contact_normal_jacobian
            normal[:] = fromto[3:] - fromto[:3]
            mujoco.mju_normalize3(normal)
            mujoco.mj_jac(model, data, jac2, None, fromto[3:], model.geom_bodyid[geom2_id])
            mujoco.mj_jac(model, data, jac1, None, fromto[:3], model.geom_bodyid[geom1_id])
            jac2 -= jac1
            row = normal @ jac2
            if dist > min_dist:
                upper_bound[idx] = (lim.gain * (dist - min_dist) / dt) + lim.bound_relaxation
            else:
                upper_bound[idx] = lim.bound_relaxation
            coefficient_matrix[idx] = (-1.0 if dist >= 0 else 1.0) * row
        return coefficient_matrix, upper_bound


class FarPairs:
    """Which geom pairs of collision limits are provably farther apart than their detection distance, from the
    geoms' bounding spheres (MuJoCo's geom_rbound about geom_xpos) and, for a box, its faces: the distance of two
    geoms is at least that of their centres less both radii, and at least that of one's centre from the box
    less its radius. A pair is far when that lower bound exceeds the detection distance by FAR_SLACK; for such a
    pair mj_geomDistance returns the detection distance itself (its distances are bounded from above by it) and
    mink's limit skips it, so leaving it out changes no row. Pairs with an unbounded geom (a plane, a height
    field) are never far."""

    def __init__(self, model, limits: Sequence, mujoco):
        pairs = [(g1, g2) for lim in limits for g1, g2 in lim.geom_id_pairs]
        self.slices, start = {}, 0
        for lim in limits:
            self.slices[id(lim)] = slice(start, start + len(lim.geom_id_pairs))
            start += len(lim.geom_id_pairs)
        g1, g2 = (np.array([p[k] for p in pairs], int) for k in (0, 1))
        rb, kind = model.geom_rbound, model.geom_type
        solid = {int(t) for t in (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE,
                                  mujoco.mjtGeom.mjGEOM_ELLIPSOID, mujoco.mjtGeom.mjGEOM_CYLINDER,
                                  mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_MESH)}
        bounded = np.array([int(kind[a]) in solid and int(kind[b]) in solid and rb[a] > 0 and rb[b] > 0
                            for a, b in zip(g1, g2)], bool)
        reach = np.array([lim.collision_detection_distance for lim in limits for _ in lim.geom_id_pairs]) + FAR_SLACK
        self.g1, self.g2 = g1, g2
        # the squared centre distance beyond which a pair is far (never, for an unbounded geom)
        self.apart = np.where(bounded, (rb[g1] + rb[g2] + reach) ** 2, np.inf)
        box = int(mujoco.mjtGeom.mjGEOM_BOX)
        is_box2, is_box1 = kind[g2] == box, kind[g1] == box
        self.boxed = np.flatnonzero(is_box1 | is_box2)  # pairs with a box: the other's centre against it
        self.box = np.where(is_box2, g2, g1)[self.boxed]
        self.other = np.where(is_box2, g1, g2)[self.boxed]
        self.box_size = model.geom_size[self.box]
        self.box_apart = np.where(bounded[self.boxed], (rb[self.other] + reach[self.boxed]) ** 2, np.inf)

    def of(self, lim) -> slice:
        """The limit's pairs in the mask __call__ returns."""
        return self.slices[id(lim)]

    def __call__(self, data) -> list[bool]:
        """Per pair: it is provably beyond its detection distance at the data's geom poses."""
        x = data.geom_xpos
        d = x[self.g1] - x[self.g2]
        d *= d
        far = d.sum(axis=1) > self.apart
        if len(self.boxed):
            # the other geom's centre in the box's frame (R^T v as v R), its distance from the box (0 inside)
            R = data.geom_xmat[self.box].reshape(-1, 3, 3)
            out = np.abs(np.matmul((x[self.other] - x[self.box])[:, None], R)[:, 0])
            out -= self.box_size
            np.maximum(out, 0.0, out=out)
            out *= out
            far[self.boxed] |= out.sum(axis=1) > self.box_apart
        return far.tolist()


__all__ = ["FarPairs", "StepQP"]
