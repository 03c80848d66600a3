"""The embodiment: two free-floating parallel-jaw grippers (Robotiq 2F-140 class) as MJCF.

Gripper frame = the pose's frame (docs/architecture.md, Conventions): origin = the pinch point between the two
fingertip pads, z = approach direction (towards the fingertips), x = closing direction (from the
left finger to the right finger), y = z x x.

Physics, not kinematics:
* the gripper base is a free body (gravity compensated like an arm's controller would) that follows
  a mocap target through a soft WELD equality (solref `weld_solref`): it is pushed back by contacts
  and cannot pass through the table or objects without large constraint forces;
* the two fingers are slide joints along x, coupled symmetric by a joint equality (like the
  2F-140's linkage), driven by ONE position actuator on the fixed tendon (left + right travel) whose
  force is clipped to `grip_force`: each pad squeezes with at most `grip_force` newtons;
* finger command speed is rate-limited to `speed` (aperture m/s) by the executor;
* pads have friction `pad_friction` and condim 4 (torsional friction of a real pad's contact patch);
  grasped objects are NEVER welded: a grasp holds only through contact forces and friction;
* all gripper geoms use collision bits 3/3: they touch objects (bits 1 and 3), the table and the
  floor (bit 2) and the other gripper.

Default parameters = Robotiq 2F-140: stroke 140 mm, grip force 10-125 N (default 40 N), closing
speed 30-250 mm/s (default 250 mm/s), about 1 kg.  Pads 22 x 22 mm (6 mm thick) at the tips of
80 mm fingers; the pinch point lies `tip_offset` (6 mm) behind the fingertip ends, i.e. the pad
spans [-16, +6] mm along the approach axis around the pinch point (a human pinch touches with the
fingertips, so the gripper's pinch point is near its fingertip ends, not at the pad centre).

Mapping of the human action's g (docs/architecture.md: 1 open, 0 closed) to the gripper (documented, general):
* g >= 0.5 -> open to `open_width` (default: fully open = stroke);
* the close command is issued `close_lead_s` (0.3 s) before g switches from 1 to 0: a human closes
  the hand during the frames before the "closed" label, while the gripper needs stroke / speed
  (0.56 s) to close; 0.3 s is the human's closing time in the scripted takes (the hand is already at
  the grasp pose then), so the fingers are not closing while the gripper still approaches;
* a release (g 0 -> 1) opens to the held width + `release_margin` (4 cm) and fully only after the
  pinch target moved `reopen_distance` (5 cm) away, so a release next to the table does not ram a
  finger into it;
* g < 0.5  -> close: position target `-squeeze` (below any object's width), so the actuator force
  saturates at `grip_force` once the pads touch the object: the human aperture (thumb-index
  distance) is NOT the gripper's opening.
"""

from __future__ import annotations

from dataclasses import dataclass, asdict


@dataclass(frozen=True)
class GripperSpec:
    name: str = "robotiq_2f140"
    stroke: float = 0.140  # m, full opening between the pads
    grip_force: float = 40.0  # N per pad when squeezing (2F-140: 10-125 N)
    speed: float = 0.25  # m/s aperture speed (2F-140: 0.03-0.25)
    open_width: float | None = 0.11  # g = 1 opening (m); None = full stroke
    squeeze: float = 0.03  # m, closed command = -squeeze (target below any object width)
    pad_half: tuple = (0.003, 0.011, 0.011)  # pad half sizes (x thickness, y width, z length)
    tip_offset: float = 0.006  # m from the pinch point to the fingertip end along +z
    finger_len: float = 0.080  # m, palm face to fingertip end
    finger_thick: float = 0.010  # m, finger link thickness (outside the pad)
    pad_friction: tuple = (1.0, 0.02, 0.002)
    palm_half: tuple = (0.045, 0.03, 0.035)  # housing half sizes; the open fingers reach beyond it
    close_lead_s: float = 0.3  # s: a close command is issued this long before g switches to 0
    release_margin: float = 0.04  # m: a release opens to the held width + this ...
    reopen_distance: float = 0.05  # ... and fully (open_width) once the pinch moved this far away
    base_mass: float = 0.9  # kg (palm + wrist coupling)
    finger_mass: float = 0.05  # kg each
    weld_solref: tuple = (0.01, 1.0)  # soft weld mocap -> gripper base
    kv_scale: float = 1.0  # finger actuator damping relative to critical

    @property
    def opening(self) -> float:
        return self.stroke if self.open_width is None else float(min(max(self.open_width, 0.0), self.stroke))

    @property
    def kp(self) -> float:
        # saturate at grip_force for any object: force = kp * (target travel - travel) >= grip_force once
        # the target is `squeeze` beyond the contact point (tendon length = both fingers' travel)
        return 2.0 * self.grip_force / self.squeeze

    @property
    def kv(self) -> float:
        m = 2 * self.finger_mass + 0.02  # finger masses + armature
        return self.kv_scale * 2.0 * (self.kp * m) ** 0.5

    def ctrl_for_width(self, width):
        """Actuator target (total finger travel) for a commanded aperture width (m)."""
        return self.stroke - width

    def to_dict(self) -> dict:
        return asdict(self)


COLORS = ("0.25 0.35 0.85 1", "0.85 0.3 0.25 1")
BITS = 'contype="3" conaffinity="3"'
# finger contacts: priority 1 -> the pad's own friction / condim / solver parameters govern its contacts;
# solimp close to 1 keeps a 40 N squeeze on a 50 g object from sinking mm into it (MuJoCo's contact
# softness is mass-relative: the default 0.9-0.95 impedance lets light objects penetrate a pad)
PAD_SOL = 'priority="1" solref="0.005 1" solimp="0.99 0.999 0.0005 0.5 2"'


def mjcf_numbers(*v) -> str:
    """Numbers as an MJCF attribute value (6 significant digits)."""
    return " ".join(f"{float(x):.6g}" for x in v)


_f = mjcf_numbers


def hand_body(spec: GripperSpec, p: str, col: str, wrist: bool = True) -> str:
    """The inside of one 2F-140 body in the gripper frame (pinch point at the origin, z = approach):
    palm, (the wrist coupling of a free-floating gripper,) the pinch site and the two fingers."""
    px, py, pz = spec.pad_half
    half_open = spec.stroke / 2
    tip = spec.tip_offset
    palm_face = tip - spec.finger_len
    th = spec.finger_thick
    link_hz = spec.finger_len / 2
    fr = _f(*spec.pad_friction)
    fingers = []
    for side, sgn in (("l", -1), ("r", 1)):
        # finger body origin = pad inner face centre line at full opening; travel along -sgn * x
        fingers.append(f"""
<body name="{p}_finger_{side}" pos="{_f(sgn * half_open, 0, 0)}" gravcomp="1">
  <joint name="{p}_{side}" type="slide" axis="{_f(-sgn, 0, 0)}" range="0 {half_open:.6g}" armature="0.01" damping="0.5" solreflimit="0.004 1"/>
  <geom name="{p}_pad_{side}" type="box" size="{_f(px, py, pz)}" pos="{_f(sgn * px, 0, tip - pz)}" {BITS} {PAD_SOL}
        friction="{fr}" condim="4" mass="{spec.finger_mass * 0.2:.6g}" rgba="0.15 0.15 0.15 1"/>
  <geom name="{p}_link_{side}" type="box" size="{_f(th / 2, py + 0.001, link_hz)}"
        pos="{_f(sgn * (2 * px + th / 2), 0, tip - link_hz)}" {BITS} {PAD_SOL} friction="{fr}" condim="4"
        mass="{spec.finger_mass * 0.8:.6g}" rgba="{col}"/>
</body>""")
    palm_hx = spec.palm_half[0]
    coupling = (f"""
  <geom name="{p}_wrist" type="cylinder" size="0.035 0.025" pos="{_f(0, 0, palm_face - 2 * spec.palm_half[2] - 0.025)}" {BITS}
        mass="{spec.base_mass * 0.4:.6g}" rgba="{col}"/>""" if wrist else "")
    return f"""
  <geom name="{p}_palm" type="box" size="{_f(palm_hx, spec.palm_half[1], spec.palm_half[2])}" pos="{_f(0, 0, palm_face - spec.palm_half[2])}" {BITS}
        mass="{spec.base_mass * 0.6:.6g}" rgba="0.3 0.3 0.32 1"/>{coupling}
  <site name="{p}_pinch" pos="0 0 0" size="0.004" rgba="1 1 0 1" group="3"/>
  {''.join(fingers)}"""


def finger_drive(spec: GripperSpec, p: str) -> dict[str, str]:
    """One hand's finger coupling, tendon, force-limited actuator and finger-finger contact exclusion
    (MJCF fragments: keys equality, tendon, actuator, contact). The fingers of any hand driven this
    way (joints `<p>_l`, `<p>_r`: travel from fully open, 0, to closed) follow the executor's
    finger command (`ctrl` = total travel = stroke - width)."""
    return {"equality": f'<joint name="{p}_couple" joint1="{p}_r" joint2="{p}_l" polycoef="0 1 0 0 0" solref="0.005 1"/>',
            "tendon": f'<fixed name="{p}_grip"><joint joint="{p}_l" coef="1"/><joint joint="{p}_r" coef="1"/></fixed>',
            "actuator": (f'<position name="{p}_grip" tendon="{p}_grip" kp="{spec.kp:.6g}" kv="{spec.kv:.6g}" '
                         f'forcerange="{_f(-spec.grip_force, spec.grip_force)}" ctrlrange="{_f(-0.05, spec.stroke + spec.squeeze + 0.05)}"/>'),
            "contact": f'<exclude body1="{p}_finger_l" body2="{p}_finger_r"/>'}


def gripper_sections(spec: GripperSpec) -> dict[str, str]:
    """MJCF fragments for both free-floating grippers: keys worldbody, equality, tendon, actuator, contact."""
    wb, eq, tn, ac, ct = [], [], [], [], []
    for a in range(2):
        p = f"g{a}"
        col = COLORS[a]
        wb.append(f"""
<body name="{p}_target" mocap="true" pos="{_f(-0.3 + 0.6 * a, -0.15, 0.2)}">
  <geom type="sphere" size="0.006" rgba="{col[:-1]}0.3" contype="0" conaffinity="0" group="3"/>
</body>
<body name="{p}_base" pos="{_f(-0.3 + 0.6 * a, -0.15, 0.2)}" gravcomp="1">
  <freejoint name="{p}_free"/>{hand_body(spec, p, col)}
</body>""")
        eq.append(f'<weld name="{p}_drive" body1="{p}_target" body2="{p}_base" relpose="0 0 0 1 0 0 0" '
                  f'solref="{_f(*spec.weld_solref)}"/>')
        drive = finger_drive(spec, p)
        eq.append(drive["equality"])
        tn.append(drive["tendon"])
        ac.append(drive["actuator"])
        ct.append(drive["contact"])
    return {"worldbody": "\n".join(wb), "equality": "\n".join(eq), "tendon": "\n".join(tn),
            "actuator": "\n".join(ac), "contact": "\n".join(ct)}
