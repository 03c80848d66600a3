"""The six thesis tasks: objects, keypoints, placement sampling, scripted takes and success predicates.

Roles in the non-mirrored take: the left hand (arm 0) handles the manipulated object (object 0),
the right hand (arm 1) holds the receiving object (object 1).  The mirrored take is the reflection.

Segment.object: for skill segments the object the hand acts on / relative to (pour -> cup, drop ->
bin, holding -> the held receiving object); for motion segments the object of the next skill.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from . import objects as ob
from .base import (register_task, UP, Task, TaskObject, Track, inv_pose, local_point, make_pose, object_pose, side_pinch,
                   top_pinch, translated, unit, yaw_dir)
from .scripting import (AP_REST, CARRY_KEYFRAMES, Style, _bin_kp, _bottle_kp, _bowl_kp, _can_kp, _cup_kp, _kp, _rim4,
                        _tilt_deg, _whisk_kp, approach_dir, grasp_sequence, holder_script, home_pose, pinch_for,
                        release_sequence)


# ============================================================ pouring
class Pouring(Task):
    name = "pouring"
    keyframes = CARRY_KEYFRAMES
    faults = ("no_tilt",)
    B, C = ob.BOTTLE, ob.CUP
    objects = (
        TaskObject("bottle", "manipulated", 2 * ob.BOTTLE["R"], _bottle_kp(ob.BOTTLE), ob.bottle, symmetry=0),
        TaskObject("cup", "receiving", 2 * ob.CUP["R"], _cup_kp(ob.CUP), ob.cup, symmetry=0),
    )
    resizable = {"bottle": ("B", _bottle_kp, lambda d: 2 * d["R"]), "cup": ("C", _cup_kp, lambda d: 2 * d["R"])}

    def _sample_poses(self, rng):
        return np.stack([object_pose(rng.uniform(-0.25, -0.14), rng.uniform(0.18, 0.34), rng.uniform(-0.5, 0.5)),
                         object_pose(rng.uniform(0.03, 0.15), rng.uniform(0.22, 0.38), rng.uniform(-0.5, 0.5))])

    def _extra_bodies(self, placement):
        return ob.liquid(placement.object_poses[0], self.B)

    def _script(self, rng, poses, fault):
        st = Style(rng)
        B0, C0 = poses
        L, R = Track(home_pose(0, st), AP_REST), Track(home_pose(1, st), AP_REST)
        gC = side_pinch(C0[:3, 3] + [0, 0, st.u(0.04, 0.06)], approach_dir(1, C0[:3, 3], st), 1, st.u(0.0, 0.2))
        lift = st.u(0.015, 0.035)
        finish_holder = holder_script(R, gC, 1, self.objects[1].grasp_width, st, lift)
        ready = R.now
        C_task = translated(C0, [0, 0, lift])

        wB = self.objects[0].grasp_width
        gB = side_pinch(B0[:3, 3] + [0, 0, st.u(0.07, 0.10)], approach_dir(0, B0[:3, 3], st), 0, st.u(0.0, 0.2))
        grasp_sequence(L, gB, 0, wB, st)
        rel = inv_pose(gB) @ B0
        L.move(st.d(0.6), translated(gB, [0, 0, st.u(0.08, 0.12)]), None, "skill", 0)
        L.until(ready, "skill", 0)

        c = C_task[:3, 3]
        rim_z = c[2] + self.C["h"]
        d = unit([c[0] - B0[0, 3], c[1] - B0[1, 3], 0.0])
        axis = np.cross(UP, d)
        RB0 = Rotation.from_matrix(B0[:3, :3])
        mouth_local = np.array([0, 0, self.B["h"]])

        def bottle_at(theta, mouth):
            r = Rotation.from_rotvec(axis * theta) * RB0
            return make_pose(r, mouth - r.apply(mouth_local))

        m0 = c - d * st.u(0.115, 0.13) + [0, 0, rim_z - c[2] + st.u(0.02, 0.035) + self.B["h"]]
        m1 = c - d * st.u(0.015, 0.03) + [0, 0, rim_z - c[2] + st.u(0.03, 0.045)]
        th_max = math.radians(st.u(140, 150))
        L.move(st.d(1.2), pinch_for(bottle_at(0.0, m0), rel), None, "motion", 1)
        n_k = 8
        t_tilt = st.d(1.6)
        path = [(th_max * k / n_k, m0 + (m1 - m0) * (k / n_k)) for k in range(1, n_k + 1)]
        if fault == "no_tilt":
            L.hold(t_tilt + st.d(1.5) + st.d(1.2), "skill", 1)
        else:
            for th, m in path:
                L.move(t_tilt / n_k, pinch_for(bottle_at(th, m), rel), None, "skill", 1)
            L.hold(st.d(1.5), "skill", 1)
            t_back = st.d(1.2)
            for th, m in path[:-1][::-1] + [(0.0, m0)]:
                L.move(t_back / n_k, pinch_for(bottle_at(th, m), rel), None, "skill", 1)
        t_done = L.now
        place = translated(B0, [0, 0, 0.004])
        L.move(st.d(1.0), pinch_for(translated(place, [0, 0, st.u(0.05, 0.08)]), rel), None, "motion", 0)
        L.move(st.d(0.6), pinch_for(place, rel), None, "skill", 0)
        release_sequence(L, 0, wB, st, arm=0)
        finish_holder(t_done + 0.3)
        return L, R

    def success(self, model, data, history):
        import mujoco
        cup_T = history[-1, 1]
        n_in = 0
        n = ob.LIQUID["n"]
        r_in = self.C["R"] - self.C["t"] + 0.002
        for i in range(n):
            p = local_point(cup_T, data.xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"liquid_{i}")])
            if math.hypot(p[0], p[1]) < r_in and -0.005 < p[2] < self.C["h"] + 0.005:
                n_in += 1
        tilt = max(_tilt_deg(T) for T in history[:, 1])
        ok = n_in * 2 >= n and tilt < 30
        return ok, f"{n_in}/{n} liquid spheres in the cup, max cup tilt {tilt:.0f} deg"


# ============================================================ trash in bin
class TrashInBin(Task):
    name = "trash_in_bin"
    keyframes = CARRY_KEYFRAMES
    faults = ("release_far",)
    A, CN = ob.BIN, ob.CAN
    objects = (
        TaskObject("can", "manipulated", 2 * ob.CAN["R"], _can_kp(ob.CAN), ob.can, symmetry=0),
        TaskObject("bin", "receiving", ob.BIN["t"], _bin_kp(ob.BIN), ob.bin_, symmetry=4),
    )
    resizable = {"can": ("CN", _can_kp, lambda d: 2 * d["R"]), "bin": ("A", _bin_kp, lambda d: d["t"])}

    def _sample_poses(self, rng):
        return np.stack([object_pose(rng.uniform(-0.25, -0.13), rng.uniform(0.15, 0.32), rng.uniform(-0.6, 0.6)),
                         object_pose(rng.uniform(0.08, 0.18), rng.uniform(0.26, 0.4), rng.uniform(-0.4, 0.4))])

    def _script(self, rng, poses, fault):
        st = Style(rng)
        K0, B0 = poses
        a, t, h = self.A["half"], self.A["t"], self.A["h"]
        L, R = Track(home_pose(0, st), AP_REST), Track(home_pose(1, st), AP_REST)
        # right hand pinches the top of the bin's right wall near its back corner, thumb outside, index
        # inside: the side away from the can hand, so that the two hands keep a clearance that two robot
        # grippers (housings reaching ~20 cm behind the pinch point) can also keep
        p = B0 @ np.array([a - t / 2, st.u(0.03, 0.06), h - 0.01, 1.0])
        gB = top_pinch(p[:3], B0[:3, 0])
        lift = st.u(0.005, 0.015)
        finish_holder = holder_script(R, gB, 1, self.objects[1].grasp_width, st, lift)
        ready = R.now
        wK = self.objects[0].grasp_width
        gK = side_pinch(K0[:3, 3] + [0, 0, st.u(0.05, 0.08)], approach_dir(0, K0[:3, 3], st), 0, st.u(0.0, 0.2))
        grasp_sequence(L, gK, 0, wK, st)
        rel = inv_pose(gK) @ K0
        z_drop = h + lift + st.u(0.05, 0.08)  # can bottom height over the bin
        up = make_pose(K0[:3, :3], K0[:3, 3] + [0, 0, z_drop])
        L.move(st.d(0.8), pinch_for(up, rel), None, "skill", 0)
        L.until(ready, "skill", 0)
        if fault == "release_far":
            over = translated(up, [-st.u(0.04, 0.08), -0.03, 0.0])
        else:
            c = B0 @ np.array([st.u(-0.035, -0.015), st.u(-0.03, -0.01), 0, 1.0])  # away from the holding hand
            over = make_pose(K0[:3, :3], [c[0], c[1], z_drop])
        L.move(st.d(1.3), pinch_for(over, rel), None, "motion", 1)
        L.hold(st.d(0.2), "skill", 1)
        release_sequence(L, 1, wK, st, arm=0, retreat=UP * 0.06 - L.pose[:3, 2] * 0.04)
        finish_holder(L.now - st.d(1.0))
        return L, R

    def success(self, model, data, history):
        p = local_point(history[-1, 1], history[-1, 0][:3, 3] + history[-1, 0][:3, 2] * self.CN["h"] / 2)
        a = self.A["half"] - self.A["t"]
        ok = abs(p[0]) < a and abs(p[1]) < a and p[2] < self.A["h"]
        tilt = _tilt_deg(history[-1, 1])
        ok = ok and tilt < 30
        return ok, f"can centre in bin frame ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}); bin tilt {tilt:.0f} deg"


# ============================================================ paper in case
class PaperInCase(Task):
    name = "paper_in_case"
    keyframes = CARRY_KEYFRAMES
    faults = ("release_far",)
    K = ob.CASE
    objects = (
        TaskObject("paper_ball", "manipulated", 2 * ob.BALL["r"], _kp(
            ("ball_bottom", (0, 0, 0)), ("ball_center", (0, 0, ob.BALL["r"])), ("ball_top", (0, 0, 2 * ob.BALL["r"])),
            ("ball_left", (-ob.BALL["r"], 0, ob.BALL["r"])), ("ball_right", (ob.BALL["r"], 0, ob.BALL["r"]))),
            ob.paper_ball, symmetry=0),
        TaskObject("case", "receiving", ob.CASE["t"], _kp(
            ("case_base", (0, 0, 0)),
            ("case_front_left", (-ob.CASE["hx"], -ob.CASE["hy"], ob.CASE["h"])),
            ("case_front_right", (ob.CASE["hx"], -ob.CASE["hy"], ob.CASE["h"])),
            ("case_back_left", (-ob.CASE["hx"], ob.CASE["hy"], ob.CASE["h"])),
            ("case_back_right", (ob.CASE["hx"], ob.CASE["hy"], ob.CASE["h"])),
            ("case_lid_tip", tuple(ob.case_lid_tip_local()))), ob.case),
    )

    def _sample_poses(self, rng):
        return np.stack([object_pose(rng.uniform(-0.26, -0.15), rng.uniform(0.15, 0.3), rng.uniform(-np.pi, np.pi)),
                         object_pose(rng.uniform(0.03, 0.13), rng.uniform(0.26, 0.38), rng.uniform(-0.3, 0.3))])

    def _script(self, rng, poses, fault):
        st = Style(rng)
        P0, K0 = poses
        hx, hy, t, h = self.K["hx"], self.K["hy"], self.K["t"], self.K["h"]
        r = ob.BALL["r"]
        L, R = Track(home_pose(0, st), AP_REST), Track(home_pose(1, st), AP_REST)
        # right hand pinches the top of the case's right wall (away from the ball hand; the back is the lid)
        p = K0 @ np.array([hx - t / 2, st.u(-0.02, 0.015), h - 0.008, 1.0])
        gK = top_pinch(p[:3], K0[:3, 0])
        lift = st.u(0.003, 0.01)
        finish_holder = holder_script(R, gK, 1, self.objects[1].grasp_width, st, lift)
        ready = R.now
        wP = self.objects[0].grasp_width
        gP = top_pinch(P0[:3, 3] + [0, 0, r], yaw_dir(math.pi / 2 + st.u(-0.3, 0.3)))
        grasp_sequence(L, gP, 0, wP, st, back=0.08, up=0.0)
        rel = inv_pose(gP) @ P0
        z_carry = h + lift + st.u(0.04, 0.07)
        up = make_pose(P0[:3, :3], P0[:3, 3] + [0, 0, z_carry])
        L.move(st.d(0.7), pinch_for(up, rel), None, "skill", 0)
        L.until(ready, "skill", 0)
        if fault == "release_far":
            over = translated(up, [-st.u(0.04, 0.08), -0.03, 0.0])
            L.move(st.d(1.2), pinch_for(over, rel), None, "motion", 1)
            L.hold(st.d(0.6), "skill", 1)
        else:
            c = K0 @ np.array([st.u(-0.045, -0.02), st.u(-0.01, 0.005), 0, 1.0])  # away from the holding hand
            over = make_pose(P0[:3, :3], [c[0], c[1], z_carry])
            L.move(st.d(1.2), pinch_for(over, rel), None, "motion", 1)
            L.move(st.d(0.6), pinch_for(translated(over, [0, 0, h + lift + st.u(0.008, 0.015) - z_carry]), rel),
                   None, "skill", 1)
        release_sequence(L, 1, wP, st, arm=0, retreat=UP * 0.08)
        finish_holder(L.now - st.d(1.0))
        return L, R

    def success(self, model, data, history):
        p = local_point(history[-1, 1], history[-1, 0][:3, 3] + history[-1, 0][:3, 2] * ob.BALL["r"])
        ax, ay = self.K["hx"] - self.K["t"], self.K["hy"] - self.K["t"]
        ok = abs(p[0]) < ax and abs(p[1]) < ay and p[2] < self.K["h"]
        return ok, f"paper ball centre in case frame ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f})"


# ============================================================ mix bowl
class MixBowl(Task):
    name = "mix_bowl"
    faults = ("no_circle",)
    W, BW = ob.WHISK, ob.BOWL
    objects = (
        TaskObject("whisk", "manipulated", 2 * ob.WHISK["handle_r"], _whisk_kp(ob.WHISK), ob.whisk, symmetry=0),
        TaskObject("bowl", "receiving", ob.BOWL["t"], _bowl_kp(ob.BOWL), ob.bowl, symmetry=0),
    )
    resizable = {"whisk": ("W", _whisk_kp, lambda d: 2 * d["handle_r"]), "bowl": ("BW", _bowl_kp, lambda d: d["t"])}
    HANDLE_GRASP = ob.WHISK["grasp_z"]

    @staticmethod
    def whisk_rest_pose(x, y, yaw, dims: dict | None = None):
        """Whisk lying on the table, head towards the demonstrator; (x, y) = handle end.  `dims`: the
        whisk's dimensions (default ob.WHISK)."""
        w = dims or ob.WHISK
        a = ob.whisk_rest_tilt(w)
        r = Rotation.from_euler("z", yaw) * Rotation.from_euler("x", math.pi / 2 - a)
        rh = w["handle_r"]
        return make_pose(r, np.array([x, y, rh]) - r.apply([0, 0, rh]))

    def _sample_poses(self, rng):
        return np.stack([self.whisk_rest_pose(rng.uniform(-0.27, -0.16), rng.uniform(0.32, 0.42),
                                              rng.uniform(-0.35, 0.35), self.W),
                         object_pose(rng.uniform(0.04, 0.14), rng.uniform(0.25, 0.38), rng.uniform(-np.pi, np.pi))])

    def head_local_in_bowl(self, W, B):
        return local_point(B, W[:3, :3] @ [0, 0, self.W["head_z"]] + W[:3, 3])

    def _script(self, rng, poses, fault):
        st = Style(rng)
        W0, B0 = poses
        L, R = Track(home_pose(0, st), AP_REST), Track(home_pose(1, st), AP_REST)
        bw = self.BW
        # right hand pinches the rim on the bowl's right-back (world frame: the bowl is round, its yaw is
        # arbitrary), thumb outside: away from the whisk hand, whose hand reaches over the front of the bowl
        ang = math.radians(st.u(10, 45))
        radial = np.array([math.cos(ang), math.sin(ang), 0.0])
        p = B0[:3, 3] + radial * (bw["r_top"] + 0.0015) + [0, 0, bw["h"] - 0.008]
        gB = top_pinch(p, -radial, tilt_toward=-radial, tilt=0.35)  # fingers along the flaring wall
        lift = st.u(0.003, 0.008)
        finish_holder = holder_script(R, gB, 1, self.objects[1].grasp_width, st, lift)
        ready = R.now
        B_task = translated(B0, [0, 0, lift])

        wW = self.objects[0].grasp_width
        hp = W0 @ np.array([0, 0, self.W["grasp_z"], 1.0])
        perp = W0[:3, 0]
        gW = top_pinch(hp[:3], -perp)
        grasp_sequence(L, gW, 0, wW, st, back=0.07, up=0.0)
        rel = inv_pose(gW) @ W0
        W_up = translated(W0, [0, 0, st.u(0.05, 0.08)])
        L.move(st.d(0.6), pinch_for(W_up, rel), None, "skill", 0)
        L.until(ready, "skill", 0)
        # turn the whisk head-down (minimal rotation of its axis onto -z)
        u = W0[:3, 2]
        axis = unit(np.cross(u, [0, 0, -1.0]))
        turn = Rotation.from_rotvec(axis * math.acos(np.clip(-u[2], -1, 1)))
        R_vert = (turn * Rotation.from_matrix(W0[:3, :3])).as_matrix()
        c = B_task[:3, 3]
        head_z = c[2] + st.u(0.03, 0.04)
        rc = st.u(0.025, 0.035)
        phi0 = st.u(0, 2 * math.pi)
        sgn = 1 if rng.random() < 0.5 else -1

        def whisk_with_head_at(pt, rot=R_vert):
            return make_pose(rot, pt - rot @ [0, 0, self.W["head_z"]])

        start = c + [rc * math.cos(phi0), rc * math.sin(phi0), head_z - c[2]]
        above = start + [0, 0, bw["h"] + 0.05 - (head_z - c[2]) + self.W["head_r"]]
        mid_rot = (Rotation.from_rotvec(axis * 0.5 * math.acos(np.clip(-u[2], -1, 1))) * Rotation.from_matrix(W0[:3, :3])).as_matrix()
        mid_head = 0.5 * (W_up[:3, :3] @ [0, 0, self.W["head_z"]] + W_up[:3, 3]) + 0.5 * above + [0, 0, 0.08]
        L.move(st.d(0.8), pinch_for(whisk_with_head_at(mid_head, mid_rot), rel), None, "motion", 1)
        L.move(st.d(0.8), pinch_for(whisk_with_head_at(above), rel), None, "motion", 1)
        L.move(st.d(0.7), pinch_for(whisk_with_head_at(start), rel), None, "skill", 1)
        n_circ = 2
        per = st.d(1.3)
        if fault == "no_circle":
            L.hold(n_circ * per, "skill", 1)
        else:
            steps = 12 * n_circ
            for k in range(1, steps + 1):
                ph = phi0 + sgn * 2 * math.pi * k / 12
                pt = c + [rc * math.cos(ph), rc * math.sin(ph), head_z - c[2]]
                L.move(per / 12, pinch_for(whisk_with_head_at(pt), rel), None, "skill", 1)
        L.move(st.d(0.7), pinch_for(whisk_with_head_at(above), rel), None, "skill", 1)
        t_done = L.now
        place = translated(W0, [0, 0, 0.004])
        L.move(st.d(1.5), pinch_for(translated(place, [0, 0, st.u(0.05, 0.08)]), rel), None, "motion", 0)
        L.move(st.d(0.6), pinch_for(place, rel), None, "skill", 0)
        release_sequence(L, 0, wW, st, arm=0, retreat=UP * 0.07)
        finish_holder(t_done + 0.2)
        return L, R

    def success(self, model, data, history):
        bw = self.BW
        sweep, best, prev = 0.0, 0.0, None
        for W, B in zip(history[:, 0], history[:, 1]):
            p = self.head_local_in_bowl(W, B)
            r_in = bw["r_bot"] + p[2] * (bw["r_top"] - bw["r_bot"]) / bw["h"]
            inside = 0.0 < p[2] < bw["h"] and math.hypot(p[0], p[1]) < r_in
            if inside and math.hypot(p[0], p[1]) > 0.005:
                ang = math.atan2(p[1], p[0])
                if prev is not None:
                    sweep += (ang - prev + math.pi) % (2 * math.pi) - math.pi
                    best = max(best, abs(sweep))
                prev = ang
            else:
                sweep, prev = 0.0, None
        tilt = max(_tilt_deg(B) for B in history[:, 1])
        ok = best >= 2 * math.pi - 1e-6 and tilt < 25
        return ok, f"whisk head circled {math.degrees(best):.0f} deg inside the bowl; max bowl tilt {tilt:.0f} deg"


# ============================================================ open container
class OpenContainer(Task):
    name = "open_container"
    faults = ("no_lift",)
    CT, LD = ob.CONTAINER, ob.LID
    objects = (
        TaskObject("lid", "manipulated", 2 * ob.LID["knob"][1], _kp(
            ("lid_center", (0, 0, ob.LID["t"] / 2)), ("lid_knob", (0, 0, ob.LID["t"] + 2 * ob.LID["knob"][2])),
            ("lid_front", (0, -ob.LID["hy"], ob.LID["t"] / 2)), ("lid_left", (-ob.LID["hx"], 0, ob.LID["t"] / 2)),
            ("lid_right", (ob.LID["hx"], 0, ob.LID["t"] / 2))), ob.lid, symmetry=2),
        TaskObject("container", "receiving", 2 * ob.CONTAINER["hy"], _kp(
            ("container_base", (0, 0, 0)), ("container_center", (0, 0, ob.CONTAINER["h"] / 2)),
            ("container_front_left", (-ob.CONTAINER["hx"], -ob.CONTAINER["hy"], ob.CONTAINER["h"])),
            ("container_front_right", (ob.CONTAINER["hx"], -ob.CONTAINER["hy"], ob.CONTAINER["h"])),
            ("container_back_left", (-ob.CONTAINER["hx"], ob.CONTAINER["hy"], ob.CONTAINER["h"])),
            ("container_back_right", (ob.CONTAINER["hx"], ob.CONTAINER["hy"], ob.CONTAINER["h"]))), ob.container, symmetry=2),
    )

    def _sample_poses(self, rng):
        C = object_pose(rng.uniform(-0.02, 0.09), rng.uniform(0.25, 0.38), rng.uniform(-0.3, 0.3))
        return np.stack([translated(C, [0, 0, self.CT["h"]]), C])

    def _script(self, rng, poses, fault):
        st = Style(rng)
        L0, C0 = poses
        L, R = Track(home_pose(0, st), AP_REST), Track(home_pose(1, st), AP_REST)
        # the right hand grips the container across its width near its right end, below the lid's skirt;
        # it comes in level (not from above) and well aligned: the container (10 cm) leaves an opened
        # robot gripper (11 cm) half a centimetre each side, and the lid's skirt is wider than both
        # (height and downward pitch also keep the back of the hand / wrist off the table)
        p = C0 @ np.array([self.CT["hx"] - st.u(0.02, 0.035), 0, st.u(0.036, 0.044), 1.0])
        gC = side_pinch(p[:3], -C0[:2, 0], 1, st.u(0.08, 0.22))
        finish_holder = holder_script(R, gC, 1, self.objects[1].grasp_width, st, st.u(0.002, 0.005),
                                      up=0.0, jitter=0.002)
        ready = R.now
        wL = self.objects[0].grasp_width
        k = L0 @ np.array([0, 0, self.LD["t"] + self.LD["knob"][2], 1.0])
        gL = top_pinch(k[:3], L0[:3, 1])
        grasp_sequence(L, gL, 0, wL, st, back=0.08, up=0.0)
        rel = inv_pose(gL) @ L0
        L.until(ready, "skill", 0)
        if fault == "no_lift":
            L.hold(st.d(1.0), "skill", 0)
            release_sequence(L, 0, wL, st, arm=0, retreat=UP * 0.08)
        else:
            up = translated(L0, [0, 0, st.u(0.07, 0.10)])
            L.move(st.d(0.8), pinch_for(up, rel), None, "skill", 0)
            yaw = math.atan2(C0[1, 0], C0[0, 0])
            target_xy = C0[:3, 3] + Rotation.from_euler("z", yaw).apply([-st.u(0.2, 0.23), -st.u(0.0, 0.05), 0])
            target = object_pose(target_xy[0], target_xy[1], yaw + st.u(-0.3, 0.3), z=self.LD["skirt"] + 0.004)
            L.move(st.d(1.2), pinch_for(translated(target, [0, 0, st.u(0.05, 0.08)]), rel), None, "motion", 1)
            L.move(st.d(0.6), pinch_for(target, rel), None, "skill", 1)
            release_sequence(L, 1, wL, st, arm=0, retreat=UP * 0.08)
        finish_holder(L.now - st.d(1.0))
        return L, R

    def success(self, model, data, history):
        p = local_point(history[-1, 1], history[-1, 0][:3, 3])
        mx = self.CT["hx"] + self.LD["hx"] + 0.01
        my = self.CT["hy"] + self.LD["hy"] + 0.01
        ok = abs(p[0]) > mx or abs(p[1]) > my
        return ok, f"lid centre in container frame ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}); off if |x|>{mx:.3f} or |y|>{my:.3f}"


# ============================================================ empty vase
class EmptyVase(Task):
    name = "empty_vase"
    keyframes = CARRY_KEYFRAMES
    faults = ("no_pull",)
    V, F = ob.VASE, ob.FLOWERS
    objects = (
        TaskObject("flowers", "manipulated", 0.03, _kp(
            ("flowers_base", (0, 0, 0)), ("flowers_stem", (0, 0, 0.15)), ("flowers_top", (0, 0, ob.FLOWERS["top"])),
            ("blossom_left", (-ob.FLOWERS["side"], 0, ob.FLOWERS["side_top"])),
            ("blossom_right", (ob.FLOWERS["side"], 0, ob.FLOWERS["side_top"]))), ob.flowers, symmetry=0),
        TaskObject("vase", "receiving", 2 * ob.VASE["R"], _kp(
            ("vase_base", (0, 0, 0)), ("vase_center", (0, 0, ob.VASE["h"] / 2)),
            *_rim4("vase", ob.VASE["R"], ob.VASE["h"])), ob.vase, symmetry=0),
    )
    STEM_GRASP = 0.21

    def _sample_poses(self, rng):
        V = object_pose(rng.uniform(0.0, 0.1), rng.uniform(0.26, 0.38), rng.uniform(-np.pi, np.pi))
        F = translated(object_pose(V[0, 3], V[1, 3], rng.uniform(-0.4, 0.4)), [0, 0, 0.008])
        return np.stack([F, V])

    def _script(self, rng, poses, fault):
        st = Style(rng)
        F0, V0 = poses
        L, R = Track(home_pose(0, st), AP_REST), Track(home_pose(1, st), AP_REST)
        gV = side_pinch(V0[:3, 3] + [0, 0, st.u(0.07, 0.1)], approach_dir(1, V0[:3, 3], st), 1, st.u(0.0, 0.2))
        finish_holder = holder_script(R, gV, 1, self.objects[1].grasp_width, st, st.u(0.002, 0.005))
        ready = R.now
        wF = self.objects[0].grasp_width
        # the left hand pinches the main stem from the side along the flowers' local x (the plane of the
        # side stems): the side stems lie ahead of / behind the pinch, only the main stem is squeezed
        h = unit([F0[0, 0], F0[1, 0], 0.0])
        gF = side_pinch((F0 @ np.array([0, 0, self.STEM_GRASP + st.u(-0.01, 0.01), 1.0]))[:3],
                        h, 0, st.u(0.0, 0.12))
        grasp_sequence(L, gF, 0, wF, st)
        rel = inv_pose(gF) @ F0
        L.until(ready, "skill", 0)
        if fault == "no_pull":
            L.hold(st.d(1.0), "skill", 1)
            release_sequence(L, 1, wF, st, arm=0)
        else:
            up = translated(F0, [0, 0, self.V["h"] + st.u(0.05, 0.07)])
            L.move(st.d(1.2), pinch_for(up, rel), None, "skill", 1)
            side = translated(up, [-st.u(0.28, 0.32), st.u(-0.03, 0.03), 0.02])
            P_side = pinch_for(side, rel)
            L.move(st.d(1.0), P_side, None, "motion", 1)
            # lay the flowers down by rolling the hand 90 degrees about its (horizontal) approach
            # direction: the stem turns horizontal (blossoms away from the demonstrator), the back of the
            # hand stays level, and the pinch stays high enough (z_lay) for a gripper's housing
            z_lay = st.u(0.066, 0.072)

            def rolled(angle, z):
                return make_pose(Rotation.from_rotvec(h * -angle).as_matrix() @ P_side[:3, :3],
                                 [P_side[0, 3], P_side[1, 3], z])

            L.move(st.d(0.7), rolled(math.pi / 4, 0.5 * (P_side[2, 3] + z_lay) + 0.03), None, "motion", 1)
            L.move(st.d(0.7), rolled(math.pi / 2, z_lay + 0.03), None, "motion", 1)
            L.move(st.d(0.5), rolled(math.pi / 2, z_lay), None, "skill", 1)
            # open and slide the fingers back off the stem along the approach direction
            release_sequence(L, 1, wF, st, arm=0, retreat=-L.pose[:3, 2] * 0.08 + UP * 0.01)
        finish_holder(L.now - st.d(1.0))
        return L, R

    def success(self, model, data, history):
        F, V = history[-1, 0], history[-1, 1]
        pts = [local_point(V, F[:3, :3] @ [0, 0, z] + F[:3, 3]) for z in (0.0, 0.1)]
        out = all(math.hypot(p[0], p[1]) > self.V["R"] + 0.005 or p[2] > self.V["h"] + 0.005 for p in pts)
        p = pts[0]
        return out, f"flower base in vase frame ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}); out of the vase: {out}"


for _cls in (Pouring, TrashInBin, PaperInCase, MixBowl, OpenContainer, EmptyVase):
    register_task(_cls())
