"""Failure classification of one executed episode.

Outcome = success, or exactly one failure reason (FAILURES).  Rules, in this order:

1. "invalid_action" (executor, before simulating): NaN / inf values, wrong shape, quaternion norm off
   by more than `quat_tol`, g outside [0, 1], bad object input.
2. Hard failures, which fail an episode even if the task predicate holds (a robot dataset must not
   contain them); the earliest in time wins. Planned before physics, for a robot with arms
   (lib/sim/robots; the simulation runs up to that frame, so an earlier collision still wins):
   * "unreachable"     after inverse kinematics a pinch pose is more than 1 cm or 5 degrees off its
     target at some step (the pose lies outside what the arm can reach with that orientation);
   * "joint_limit"     the same, with a joint held at its position limit or moving at its velocity
     limit at that step (the arm could reach the pose but its joint range or speed cannot follow);
   * "wider_than_stroke" a hand closes on an object whose grasp width is not less than the hand's
     opening (it cannot get its fingers around it);
   and found in physics:
   * "arm_collision"   any contact between a geom of the left gripper and one of the right gripper;
   * "table_collision" a gripper pushes on the table (or floor) with a normal force above
     `table_force_limit` (15 N): a path through the table is stopped by the table, the soft drive
     weld then presses the gripper onto it;
   * "left_workspace"  a gripper's pinch point or an object's origin leaves task.workspace grown by
     `workspace_margin` (5 cm), e.g. an object knocked off the table (a hand of an arm robot: by its
     binding's `hand_workspace_slack` more, for the arm's own ready pose and transits);
   * "link_collision"  an arm link (not the hand: its fingers and housing keep the rules above) touches
     the table, an object or the other arm.
3. If the task predicate holds: success.
4. Otherwise the earliest explanation found; else "predicate_not_met":
   * "missed_grasp"   an arm closed (g < 0.5) and moved >= 3 cm while closed, but no object was ever
     between both fingers (both fingers in contact) in that closed interval; or an object was
     squeezed but did not follow the gripper (it slipped out before the gripper had moved 3 cm); or
     an arm never closed at all in the episode;
   * "object_dropped" an object held by both fingers drifted more than 3 cm in the gripper frame while
     the gripper stayed closed (slip / loss), or the gripper opened while moving faster than
     `release_speed` (0.05 m/s) with the object held (released mid-transfer).
"""

from __future__ import annotations

import numpy as np

FAILURES = ("invalid_action", "missed_grasp", "object_dropped", "arm_collision", "table_collision",
            "left_workspace", "predicate_not_met", "unreachable", "joint_limit", "link_collision",
            "wider_than_stroke")
HARD = ("arm_collision", "table_collision", "left_workspace", "unreachable", "joint_limit", "link_collision",
        "wider_than_stroke")

PLANNED = ("unreachable", "joint_limit", "wider_than_stroke")  # found before physics (lib/sim/robots)

MOVE_MIN = 0.03  # m the gripper must travel while closed for a missed grasp to matter
DRIFT_MAX = 0.03  # m object drift in the gripper frame -> lost
RELEASE_SPEED = 0.05  # m/s


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of True runs in a 1-D bool array."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _quat_to_mat(q):  # xyzw (..., 4)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def classify(sc, opt, fps, pred_ok, pred_detail, hist, gp, touch, arm_contact, table_force, g_cmd, n_action, diag=None,
             link_contact=None, plan_events=()):
    names = sc.task.object_names
    events: list[tuple[float, str, str]] = [(e.frame / fps, e.failure, e.detail) for e in plan_events]
    if link_contact is not None and link_contact.any():
        f = int(np.argmax(link_contact))
        pair = (diag or {}).get("link_pair")
        events.append((f / fps, "link_collision", f"an arm link touches {'/'.join(pair) if pair else 'something'} "
                       f"at t = {f / fps:.2f} s"))

    # ---- hard failures
    if arm_contact.any():
        f = int(np.argmax(arm_contact))
        events.append((f / fps, "arm_collision", f"left and right gripper in contact at t = {f / fps:.2f} s"
                       + (f" ({' / '.join((diag or {}).get('arm_pair', []))})" if (diag or {}).get("arm_pair") else "")))
    tf = table_force.max(axis=1)
    if (tf > opt.table_force_limit).any():
        f = int(np.argmax(tf > opt.table_force_limit))
        arm = int(np.argmax(table_force[f]))
        events.append((f / fps, "table_collision",
                       f"arm {arm} pushes on the table with {table_force[f, arm]:.0f} N at t = {f / fps:.2f} s "
                       f"(max {tf.max():.0f} N, limit {opt.table_force_limit:.0f} N)"))
    lo = sc.workspace[0] - opt.workspace_margin
    hi = sc.workspace[1] + opt.workspace_margin
    gpos = gp[..., :3]
    opos = hist[..., :3, 3]
    slack = sc.binding.hand_workspace_slack
    out_g = ((gpos < lo - slack) | (gpos > hi + slack)).any(-1)  # (T, 2)
    out_o = ((opos < lo) | (opos > hi)).any(-1)  # (T, n_obj)
    if out_g.any() or out_o.any():
        fg = int(np.argmax(out_g.any(1))) if out_g.any() else 10**9
        fo = int(np.argmax(out_o.any(1))) if out_o.any() else 10**9
        if fg <= fo:
            arm = int(np.argmax(out_g[fg]))
            events.append((fg / fps, "left_workspace",
                           f"gripper {arm} at {np.round(gpos[fg, arm], 3).tolist()} outside the workspace at t = {fg / fps:.2f} s"))
        else:
            k = int(np.argmax(out_o[fo]))
            events.append((fo / fps, "left_workspace",
                           f"{names[k]} at {np.round(opos[fo, k], 3).tolist()} outside the workspace at t = {fo / fps:.2f} s"))
    # earliest first; at the same instant a failure found while planning (the cause: an unreachable
    # pose, a too wide object) before what physics then shows (e.g. the stretched arm leaving the workspace)
    hard = sorted((e for e in events if e[1] in HARD), key=lambda e: (e[0], e[1] not in PLANNED, e[1], e[2]))
    if hard:
        return hard[0][1], hard[0][2], sorted(events)
    if pred_ok:
        return None, f"success: {pred_detail}", sorted(events)

    # ---- explanations of a failed predicate
    R = _quat_to_mat(gp[..., 3:7])  # (T, 2, 3, 3)
    both = touch[:, :, 0, :] & touch[:, :, 1, :]  # (T, 2, n_obj)
    anyf = touch[:, :, 0, :] | touch[:, :, 1, :]
    closed = g_cmd < 0.5
    speed = np.zeros(gpos.shape[:2])
    speed[1:-1] = np.linalg.norm(gpos[2:] - gpos[:-2], axis=-1) * fps / 2
    for arm in range(2):
        runs = _runs(closed[:, arm])
        if not runs:
            events.append((0.0, "missed_grasp", f"arm {arm} never closed its gripper"))
            continue
        for s, e in runs:
            moved = np.linalg.norm(gpos[s:e, arm] - gpos[s, arm], axis=-1)
            held = both[s:e, arm]  # (L, n_obj)
            if not held.any():
                if moved.max() >= MOVE_MIN:
                    events.append((s / fps, "missed_grasp",
                                   f"arm {arm} closed at t = {s / fps:.2f} s and moved {moved.max() * 100:.0f} cm "
                                   f"without an object between both fingers"))
                continue
            f0, k = np.argwhere(held)[0]
            f0 = s + int(f0)
            rel = lambda f: R[f, arm].T @ (opos[f, k] - gpos[f, arm])  # noqa: E731
            r0 = rel(f0)
            lost = None
            for f in range(f0 + 1, e):
                if np.linalg.norm(rel(f) - r0) > DRIFT_MAX and not both[f, arm, k]:
                    lost = f
                    break
            if lost is not None:
                moved_at = np.linalg.norm(gpos[lost, arm] - gpos[f0, arm])
                if moved_at < MOVE_MIN:
                    events.append((lost / fps, "missed_grasp",
                                   f"arm {arm} squeezed {names[k]} but it did not follow the gripper "
                                   f"(lost at t = {lost / fps:.2f} s)"))
                else:
                    events.append((lost / fps, "object_dropped",
                                   f"{names[k]} slipped out of closed gripper {arm} at t = {lost / fps:.2f} s"))
                continue
            if e < len(g_cmd) and anyf[e - 1, arm, k] and speed[e, arm] > RELEASE_SPEED:
                events.append((e / fps, "object_dropped",
                               f"gripper {arm} opened on {names[k]} while moving at {speed[e, arm]:.2f} m/s "
                               f"(t = {e / fps:.2f} s)"))
    soft = sorted(e for e in events if e[1] not in HARD)
    if soft:
        return soft[0][1], f"{soft[0][2]}; predicate: {pred_detail}", sorted(events)
    return "predicate_not_met", pred_detail, sorted(events)
