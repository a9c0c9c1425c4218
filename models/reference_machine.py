"""The reference machine: a skid-steer carrier with a 7-DoF hydraulic crane (5.1 t).

The carrier has two actively articulated bogies; the crane is a parallel-serial HIAB XS031
boom with a slew chain and a 3-DoF wrist added.

Every number is listed with its source in `SOURCES` (rendered in docs/machine.md). Sources:

* **XS031**: public figures of the HIAB XS031 crane (Tampere University VDC/FM/WMM models),
  as collected in the project's machine-facts sheet, sections 2-4 (geometry, cylinders,
  inertia). Flags F1 and F2 of that sheet are applied (physically consistent CoM/inertia of
  the piston rods and the telescope rod); F4 (author's beta3) is not: the CAD-exact geometry is
  used, which moves the telescope axis by 0.053 deg with respect to the published FK.
* **WMM**: the wheeled platform of the same sheet, section 5 (chassis mass/inertia, wheelbase,
  track, wheel radius and mass, crane mount).
* **design**: plausible heavy-duty values chosen here where the public sources have nothing
  (slew chain, bogies and their cylinders, wrist, tool, payload, wheel inertia, drive limits).

Frames: the floating base ``chassis`` frame (fb) sits on the bogie pivot axis, midway between
the bogies; x forward, y left, z up. The crane plane is the x-z plane of the ``slew`` body.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from models.chain import CylinderChain
from models.description import (
    Body,
    ChainBinding,
    Geom,
    HydraulicCylinder,
    Inertia,
    Joint,
    Loop,
    Machine,
    RotaryDrive,
    box_inertia,
    cylinder_inertia,
)
from models.errors import ModelError

BAR = 1e5
LPM = 1e-3 / 60  # [m^3/s] per litre/minute
# The XS031 lab model runs at 190 bar, where its lift cylinder cannot hold the 570 kg end
# section much beyond the initial pose (123 kN needed at full reach, 95.5 kN available).
# Production cranes of this class run 250-300 bar; 260 bar gives the crane a usable
# workspace with the published bores.
SUPPLY_PRESSURE = 260 * BAR
# Where the lift's stroke ends [m], boom 79.6 deg, short of the linkage's dead centre
# (0.553 m): see the "lift stroke range" note.
LIFT_STROKE_END = 0.49

# VDC planar frames are y-up with joint axes along z; ours are z-up with the crane plane x-z
# and the crane joint axes along -y. P maps VDC vectors to ours.
_P = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _vdc(mass, com, inertia, rot_vdc=None, origin=(0.0, 0.0, 0.0)) -> Inertia:
    """Inertia given in a VDC frame (rotated by rot_vdc in VDC axes, at ``origin`` in ours)."""
    r = _P if rot_vdc is None else _P @ rot_vdc
    return Inertia(mass, com, inertia).transformed(r, origin)


def _xz(a: float, b: float, y: float = 0.0) -> np.ndarray:
    """Plane point (a, b) of an x-z plane chain at lateral offset y."""
    return np.array([a, y, b])


def _xy(a: float, b: float, z: float = 0.0) -> np.ndarray:
    """Plane point (a, b) of an x-y plane chain at height z."""
    return np.array([a, b, z])


_AXIS_XZ = (0.0, -1.0, 0.0)  # positive rotation turns +x towards +z
_AXIS_XY = (0.0, 0.0, 1.0)

_STEEL = (0.55, 0.57, 0.6, 1.0)
_YELLOW = (0.95, 0.7, 0.1, 1.0)
_DARK = (0.15, 0.15, 0.15, 1.0)
_RED = (0.8, 0.2, 0.15, 1.0)


def _capsule_between(p0, p1, radius, rgba) -> Geom:
    """Visual capsule from p0 to p1 (body frame)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    z = d / length
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return Geom("capsule", (radius, length / 2), tuple((p0 + p1) / 2),
                np.column_stack([x, y, z]), rgba)


def _cylinder_bodies(prefix: str, parent: str, chain: CylinderChain, origin: np.ndarray,
                     embed, axis, barrel_mass: Inertia, piston_mass: Inertia,
                     bore: float, rod: float) -> tuple[Body, Body]:
    """Barrel (revolute about the base pivot) and piston (prismatic along the barrel)."""
    c = embed(*chain.base_pivot) + origin
    barrel = Body(f"{prefix}_barrel", parent, c, np.eye(3), Joint("revolute", axis),
                  barrel_mass,
                  (_capsule_between((0, 0, 0), (chain.dead_length + chain.stroke_max, 0, 0),
                                    bore / 2 + 0.01, _STEEL),))
    piston = Body(f"{prefix}_piston", barrel.name, (chain.dead_length, 0, 0), np.eye(3),
                  Joint("prismatic", (1.0, 0.0, 0.0), chain.stroke_range, damping=0.0),
                  piston_mass,
                  (_capsule_between((0, 0, 0), (chain.rod_length, 0, 0), rod / 2, _STEEL),))
    return barrel, piston


MAX_PAYLOAD_MASS = 10_000.0  # [kg] far above the crane's capacity; heavier is a typo


SEAL_FRICTION_FRACTION = 0.01  # of the rated force p_supply A_A


def _seal(bore: float, supply: float) -> float:
    """Seal friction [N] of a cylinder of ``bore`` [m] at ``supply`` [Pa]."""
    return SEAL_FRICTION_FRACTION * supply * math.pi * bore ** 2 / 4


def _sealed(cylinder: HydraulicCylinder) -> HydraulicCylinder:
    """``cylinder`` with its seal friction (`SEAL_FRICTION_FRACTION` of the rated force)."""
    return dataclasses.replace(cylinder, seal_friction=_seal(cylinder.bore,
                                                             cylinder.supply_pressure))


def build_reference_machine(payload_mass: float = 150.0,
                            lift_stroke_end: float = LIFT_STROKE_END) -> Machine:
    """Build the reference machine.

    Args:
        payload_mass: Mass of the payload held by the tool [kg], in (0, `MAX_PAYLOAD_MASS`].
        lift_stroke_end: Where the lift's stroke ends [m], in (0.3, 0.59]; from 0.553 m on the
            stroke runs to the linkage's dead centre, as the published XS031 figures do (for
            measurements of what the end stop avoids).

    Raises:
        ModelError: ``payload_mass`` or ``lift_stroke_end`` not a real number in its range.
    """
    def real(v):
        return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(
            v, (bool, np.bool_))

    if not real(payload_mass) or not 0.0 < payload_mass <= MAX_PAYLOAD_MASS:
        raise ModelError(f"payload_mass must be a number in (0, {MAX_PAYLOAD_MASS:g}] kg, got "
                         f"{payload_mass!r}")
    if not real(lift_stroke_end) or not 0.3 < lift_stroke_end <= 0.59:
        raise ModelError(f"lift_stroke_end must be a number in (0.3, 0.59] m, got "
                         f"{lift_stroke_end!r}")
    src: list[tuple[str, str, str]] = []
    supply = SUPPLY_PRESSURE

    def note(item, value, source):
        src.append((item, value, source))

    g = 9.81
    note("gravity", "9.81 m/s^2", "design (the XS031 models use 9.8066)")

    # ------------------------------------------------------------------ carrier
    wheel_r, wheel_m, wheel_w = 0.35, 60.0, 0.25
    half_wb, half_track = 1.15, 0.875
    bogie_y, axle_drop = 0.60, 0.10
    note("wheel radius", "0.35 m", "WMM R0")
    note("wheel mass", "60 kg", "WMM")
    note("wheel inertia", "spin 4.88, transverse 2.75 kg m^2",
         "design: tyre as hollow cylinder r 0.20-0.35 m, width 0.25 m")
    note("wheelbase / track", "2.30 m / 1.75 m", "WMM l1 + l2, 2 w")
    note("chassis", "2200 kg, box 2.5 x 0.7 x 0.5 m; I = diag(135.7, 1191.7, 1235.7) kg m^2 "
         "(solid box)", "WMM mBC and CAD box. WMM's BCI = diag(100, 1200, 1000) violates the "
         "triangle inequality (100 + 1000 < 1200), so the consistent box inertia is used")
    note("fb frame", "on the bogie pivot axis, 0.10 m above the wheel centres (0.45 m above "
         "flat ground at level bogies)", "design; matches WMM zC = R0 + 0.10")
    chassis = Body(
        "chassis", None, (0, 0, wheel_r + axle_drop), np.eye(3), Joint("free"),
        box_inertia(2200.0, (2.5, 0.7, 0.5)),
        (Geom("box", (1.25, 0.35, 0.25), rgba=_YELLOW),
),
    )
    # Engine, tank and ballast at the rear: without them the crane at full forward reach
    # puts the centre of mass ahead of the front axle (x = 1.21 m > 1.15 m).
    counterweight = Body("counterweight", "chassis", (-1.0, 0.0, 0.1), np.eye(3),
                         Joint("fixed"), box_inertia(900.0, (0.5, 0.7, 0.6)),
                         (Geom("box", (0.25, 0.35, 0.3), rgba=_DARK),))
    note("counterweight (engine, tank, ballast)", "900 kg box 0.5 x 0.7 x 0.6 m centred at "
         "(-1.0, 0, 0.1) m in fb", "design: keeps the CoM behind the front axle at full "
         "forward reach (WMM's chassis carries no crane counterweight)")
    bodies: list[Body] = [chassis, counterweight]
    loops: list[Loop] = []
    chains: dict[str, ChainBinding] = {}

    # Bogie suspension chain (x-z plane, axis -y: positive angle lifts the bogie's front).
    susp_cyl = dict(bore=0.10, rod=0.06, stroke=0.25, supply_pressure=supply,
                    rated_flow=80 * LPM, max_acceleration=1.0)
    note("seal friction", f"Coulomb, {SEAL_FRICTION_FRACTION:.0%} of each cylinder's rated "
         f"force p A_A (suspension {_seal(0.10, supply):.0f} N, crane {_seal(0.08, supply):.0f} "
         f"N)", "design: seal friction of heavy cylinders is ~0.5-3 % of the rated force; "
         "simulated only (MuJoCo frictionloss), not known to the estimators")
    note("suspension cylinders", "bore 0.10 m, rod 0.06 m, stroke 0.25 m, 80 L/min",
         "design (heavy short-stroke cylinder)")
    note("supply pressure", "260 bar, every cylinder", "design: the XS031 lab model's 190 bar "
         "cannot hold its own 570 kg end section at long reach (lift needs 123 kN at full "
         "reach, 95.5 kN available); 260 bar is in the range of production cranes")
    bogie_chain_geom = dict(base_pivot=(-0.55, 0.20), rod_eye=(0.0, 0.35), dead_length=0.08,
                            rod_length=0.37, stroke_max=0.25)
    note("suspension chain", "base pivot (-0.55, 0.20) m on chassis, rod eye (0, 0.35) m on "
         "bogie, L_c0 0.08 m, L_c 0.37 m", "design: about +-20 deg of bogie pitch")
    bogie_inertia = box_inertia(150.0, (2.4, 0.15, 0.25))
    note("bogie beam", "150 kg box 2.4 x 0.15 x 0.25 m", "design")
    wheel_inertia = cylinder_inertia(wheel_m, wheel_r, wheel_w, axis=1, inner_radius=0.20)
    for side, sgn in (("L", 1.0), ("R", -1.0)):
        bogie = Body(
            f"bogie_{side}", "chassis", (0, sgn * bogie_y, 0), np.eye(3),
            Joint("revolute", _AXIS_XZ), bogie_inertia,
            (Geom("box", (1.2, 0.075, 0.06), (0, 0, -0.05), rgba=_DARK),
             _capsule_between((0, 0, 0), (0, 0, 0.35), 0.05, _DARK)),
        )
        bodies.append(bogie)
        chain = CylinderChain(f"bogie_{side}", **bogie_chain_geom)
        cyl = _sealed(HydraulicCylinder(f"bogie_{side}", **susp_cyl))
        barrel, piston = _cylinder_bodies(
            f"bogie_{side}_cyl", "chassis", chain, np.array([0, sgn * bogie_y, 0.0]),
            lambda a, b: _xz(a, b), _AXIS_XZ,
            cylinder_inertia(22.0, 0.06, 0.5, axis=0, com=(0.25, 0, 0)),
            cylinder_inertia(14.0, 0.03, 0.45, axis=0, com=(0.2, 0, 0)), 0.10, 0.06)
        bodies += [barrel, piston]
        loops.append(Loop(f"bogie_{side}_rod_eye", piston.name, (chain.rod_length, 0, 0),
                          bogie.name, tuple(_xz(*chain.rod_eye))))
        chains[f"bogie_{side}"] = ChainBinding(chain, cyl, bogie.name, barrel.name, piston.name)
        for fr, x in (("F", half_wb), ("R", -half_wb)):
            wname = f"wheel_{fr}{side}"
            bodies.append(Body(
                wname, bogie.name, (x, sgn * (half_track - bogie_y), -axle_drop), np.eye(3),
                Joint("revolute", (0.0, 1.0, 0.0), damping=0.0), wheel_inertia,
                (Geom("sphere", (wheel_r,), rgba=_DARK, collision=True),
                 Geom("cylinder", (wheel_r, wheel_w / 2), rotation=_rx(math.pi / 2),
                      rgba=_DARK)),
            ))
    note("suspension cylinder masses", "barrel 22 kg, piston+rod 14 kg", "design")
    note("wheel collision shape", "sphere r 0.35 m (one contact point per wheel)",
         "design: the paper's one-contact assumption; a cylinder visual is drawn")

    # ------------------------------------------------------------------ crane
    mount = np.array([0.5, 0.0, 0.25])
    note("crane mount", "(0.5, 0, 0.25) m in fb: chassis top, 0.5 m forward", "WMM xCA, zCA")
    # XS031 planar geometry (VDC, y-up) -> ours.
    alpha1, alpha2 = 1.9515432018109, 0.24548563270531
    beta2 = math.atan2(45.757, 373.313)
    beta4 = math.atan2(88.061, 296.198)
    roll = math.radians(13.887)
    l11, l21 = 0.37610632101293, 0.30901132665325
    bc1 = np.array([0.185, 0.205])  # lift cylinder base pivot, slew frame (a, b)
    b11 = np.array([-0.189261, 1.14])  # lift joint
    tc1 = l11 * np.array([math.cos(beta2), -math.sin(beta2)])  # lift rod eye, link coords
    bc2 = np.array([0.473312, -0.039495])  # tilt cylinder base pivot, link coords
    b12 = np.array([1.596871, 0.100002])  # tilt joint, link coords
    tc2 = l21 * np.array([math.cos(beta4), -math.sin(beta4)])  # tilt rod eye, tilt coords
    p22 = np.array([0.353374, -0.0352769, 0.276893])  # extension mount, tilt-link frame
    note("XS031 geometry", "L1, L11, L2, L21, alpha1, alpha2, beta2, beta4, Tc1->Bc2, P22, "
         "P32->D22 as published; B11 at (-0.189, 1.14) m above the base bottom", "XS031 s2")

    # Slew chain (x-y plane of the chassis at z = 0.30 m; axis +z).
    slew_lever = 0.30
    probe = CylinderChain("slew", (-1.2, 0.0), (slew_lever, 0.0), 0.12, 0.80, 0.56)
    mid = 0.5 * sum(probe.angle_range)
    slew_chain = CylinderChain("slew", (-1.2, 0.0),
                               (slew_lever * math.cos(mid), slew_lever * math.sin(mid)),
                               0.12, 0.80, 0.56)
    note("slew chain", "horizontal four-bar: base pivot 1.2 m behind the slew axis, lever "
         "0.30 m, L_c0 0.12 m, L_c 0.80 m, stroke 0.56 m: about +-69 deg of slew",
         "design (XS031 has no slew joint)")
    slew_cyl = _sealed(HydraulicCylinder("slew", 0.08, 0.045, 0.56, supply, 60 * LPM, 1.0))
    note("slew cylinder", "bore 0.08 m, rod 0.045 m, 60 L/min", "design (XS031-like cylinder)")
    slew_plane_z = 0.30
    pillar = _vdc(307.29601379, [0.14178771, 0.16555780, 0.0],
                  [[5.89221108, 5.47611136, -1.963e-5], [5.47611136, 28.66965601, -2.455e-5],
                   [-1.963e-5, -2.455e-5, 29.7895595]], _rz(alpha1), _xz(*bc1))
    slew_ring = cylinder_inertia(40.0, 0.3, 0.1, axis=2, com=(0, 0, 0.05))
    note("pillar", "307.3 kg, CoM/inertia in Bc1", "XS031 s4 part 01")
    note("slew ring and lever", "40 kg", "design")
    slew = Body("slew", "chassis", mount, np.eye(3), Joint("revolute", _AXIS_XY),
                pillar + slew_ring,
                (Geom("cylinder", (0.3, 0.05), (0, 0, 0.05), rgba=_YELLOW),
                 _capsule_between((0.0, 0, 0.1), tuple(_xz(*b11)), 0.12, _YELLOW)))
    bodies.append(slew)
    barrel, piston = _cylinder_bodies(
        "slew_cyl", "chassis", slew_chain, np.array([mount[0], 0.0, slew_plane_z]),
        lambda a, b: _xy(a, b), _AXIS_XY,
        _vdc(17.36281648, [0.3578121, 0, 0], np.diag([0.03150902, 0.90735702, 0.90763033])),
        _vdc(10.34519231, [0.32981882, 0, 0], np.diag([0.0037072, 0.55759812, 0.55785997])),
        0.08, 0.045)
    bodies += [barrel, piston]
    loops.append(Loop("slew_rod_eye", piston.name, (slew_chain.rod_length, 0, 0), "slew",
                      tuple(_xy(*slew_chain.rod_eye, slew_plane_z - mount[2]))))
    chains["slew"] = ChainBinding(slew_chain, slew_cyl, "slew", barrel.name, piston.name)

    # Lift chain (x-z plane of the slew body; axis -y).
    lift_chain = CylinderChain("lift", tuple(bc1 - b11), tuple(tc1), 0.085, 0.745,
                               float(lift_stroke_end))
    lift_cyl = _sealed(HydraulicCylinder("lift", 0.080, 0.045, 0.59, supply, 100 * LPM, 1.0))
    note("lift/tilt cylinders", "bore 0.080, rod 0.045, stroke 0.59 m, L_c0 0.085, L_c 0.745 m, "
         "100 L/min", "XS031 s3")
    end = lift_chain.stroke_range[1]
    reach = f"[0, {end:.3f}] m (boom up to {math.degrees(lift_chain.joint_angle(end)):.1f} deg)"
    if end == lift_stroke_end:
        note("lift stroke range", f"{reach}: an end stop short of the linkage's dead centre at "
             "0.553 m (118.6 deg), where the triangle cuts the 0.59 m stroke. At 0.49 m the "
             "linkage gain dtheta/dx is 5.5 rad/m, twice its mid-stroke value; further up the "
             "servo's stiffness in boom angle (kp / gain^2) falls fast, and a boom past "
             "vertical overshoots its goal and falls back over the dead centre",
             "design (XS031 flag F3)")
    else:
        note("lift stroke range", f"{reach}: the 0.59 m stroke cut by the triangle at the "
             "linkage's dead centre, no end stop", "XS031 flag F3")
    lift_a = _vdc(25.52660174, [0.23805608, 0.13201777, 0],
                  [[0.28426, -0.06487287, 0], [-0.06487287, 0.54237481, 0],
                   [0, 0, 0.6789102]], _rz(-beta2))
    lift_b = _vdc(54.58702836, [0.54319901, 0.10543875, 0],
                  [[0.4807139, 0.52924041, 0], [0.52924041, 5.80912352, 0],
                   [0, 0, 5.97255351]], _rz(alpha2 - beta2), _xz(*bc2))
    lift = Body("lift", "slew", _xz(*b11), np.eye(3), Joint("revolute", _AXIS_XZ),
                lift_a + lift_b,
                (_capsule_between((0, 0, 0), tuple(_xz(*b12)), 0.09, _YELLOW),))
    bodies.append(lift)
    barrel_i = _vdc(17.36281648, [0.3578121, 0, 0], np.diag([0.03150902, 0.90735702,
                                                              0.90763033]))
    rod_i = _vdc(10.34519231, [0.32981882, 0, 0], np.diag([0.0037072, 0.55759812, 0.55785997]))
    note("cylinder barrel / rod", "17.36 kg / 10.35 kg; rod CoM 0.3298 m (flag F1 applied)",
         "XS031 s4 parts 03-06")
    barrel, piston = _cylinder_bodies("lift_cyl", "slew", lift_chain, _xz(*b11),
                                      lambda a, b: _xz(a, b), _AXIS_XZ, barrel_i, rod_i,
                                      0.08, 0.045)
    bodies += [barrel, piston]
    loops.append(Loop("lift_rod_eye", piston.name, (lift_chain.rod_length, 0, 0), "lift",
                      tuple(_xz(*tc1))))
    chains["lift"] = ChainBinding(lift_chain, lift_cyl, "lift", barrel.name, piston.name)

    # Tilt chain (x-z plane of the lift link).
    tilt_chain = CylinderChain("tilt", tuple(bc2 - b12), tuple(tc2), 0.085, 0.745, 0.59)
    tilt_cyl = _sealed(HydraulicCylinder("tilt", 0.080, 0.045, 0.59, supply, 100 * LPM, 1.0))
    tilt_i = _vdc(33.92850233, [0.60504569, 0.27199376, 2.484e-5],
                  [[1.18803886, -2.36786418, 0.00280315], [-2.36786418, 6.31493281, 0.00022322],
                   [0.00280315, 0.00022322, 7.40915161]], _rz(-beta4))
    ext_barrel_i = _vdc(9.26136143, [0.62192523, 0, 0],
                        np.diag([0.00662754, 1.48387017, 1.48398069]), _rx(roll), p22)
    note("tilt link + extension barrel", "33.93 kg + 9.26 kg", "XS031 s4 parts 07, 08")
    tilt = Body("tilt", "lift", _xz(*b12), np.eye(3), Joint("revolute", _AXIS_XZ),
                tilt_i + ext_barrel_i,
                (_capsule_between((0, 0, 0), tuple(p22 + [1.3, 0, 0]), 0.08, _YELLOW),))
    bodies.append(tilt)
    barrel, piston = _cylinder_bodies("tilt_cyl", "lift", tilt_chain, _xz(*b12),
                                      lambda a, b: _xz(a, b), _AXIS_XZ, barrel_i, rod_i,
                                      0.08, 0.045)
    bodies += [barrel, piston]
    loops.append(Loop("tilt_rod_eye", piston.name, (tilt_chain.rod_length, 0, 0), "tilt",
                      tuple(_xz(*tc2))))
    chains["tilt"] = ChainBinding(tilt_chain, tilt_cyl, "tilt", barrel.name, piston.name)

    # Telescope: prismatic along the tilt link; frame at the rod-end pin P32 at zero extension.
    p32 = p22 + np.array([0.041 + 1.2, 0.0, 0.0])
    rod_tel = _vdc(6.73059863, [0.56802906 - 1.2, 0, 0],
                   np.diag([0.00091463, 0.91789884, 0.91790043]), _rx(roll))
    end_obj = _vdc(570.18877059, [0.25466704, -0.13034397, -0.01302248],
                   [[46.81220713, 0.38607676, -0.00453819], [0.38607676, 71.92201786,
                                                              -1.14320993],
                    [-0.00453819, -1.14320993, 67.38128576]], _rx(roll))
    note("telescope", "rod 6.73 kg (flag F2 applied) + end boom section 570.19 kg; stroke "
         "0-1.1 m; 40 L/min", "XS031 s3, s4 parts 09, 10")
    tel = Body("telescope", "tilt", p32, np.eye(3),
               Joint("prismatic", (1.0, 0.0, 0.0), (0.0, 1.1)), rod_tel + end_obj,
               (_capsule_between((-1.3, 0, 0), (0.35, 0, 0), 0.065, _YELLOW),))
    bodies.append(tel)
    tcp = _P @ _rx(roll) @ np.array([0.40499744871392, -0.13130517281345, -0.013385243295654])
    tel_cyl = _sealed(HydraulicCylinder("telescope", 0.05, 0.03, 1.1, supply, 40 * LPM, 1.0))

    # Wrist (3-DoF), tool and payload.
    wrist_specs = (("wrist_pitch", _AXIS_XZ, (0, 0, 0), 30.0, (1.0, 3000.0, 2.0)),
                   ("wrist_roll", (1.0, 0.0, 0.0), (0, 0, -0.15), 25.0, (1.0, 2000.0, 2.0)),
                   ("rotator", (0.0, 0.0, 1.0), (0, 0, -0.15), 40.0, (1.5, 1000.0, 3.0)))
    note("wrist", "pitch 30 kg (1 rad/s, 3 kN m), roll 25 kg (1 rad/s, 2 kN m), rotator 40 kg "
         "(1.5 rad/s, 1 kN m), 0.15 m apart", "design (XS031 has no wrist)")
    parent, pos = "telescope", tuple(tcp)
    drives = {"telescope": RotaryDrive("telescope", tel_cyl.velocity_range[1],
                                       tel_cyl.force_range[1], 1.0)}
    for name, axis, offset, mass, (vmax, tmax, amax) in wrist_specs:
        p = pos if parent == "telescope" else offset
        bodies.append(Body(name, parent, p, np.eye(3),
                           Joint("revolute", axis, (-math.pi / 2, math.pi / 2), damping=50.0),
                           cylinder_inertia(mass, 0.08, 0.15, axis=2, com=(0, 0, -0.05)),
                           (Geom("cylinder", (0.08, 0.08), (0, 0, -0.05), rgba=_STEEL),)))
        drives[name] = RotaryDrive(name, vmax, tmax, amax)
        parent = name
    bodies.append(Body("tool", "rotator", (0, 0, -0.25), np.eye(3), Joint("fixed"),
                       box_inertia(60.0, (0.5, 0.3, 0.4)),
                       (Geom("box", (0.25, 0.15, 0.2), rgba=_DARK),)))
    bodies.append(Body("payload", "tool", (0, 0, -0.5), np.eye(3), Joint("fixed"),
                       box_inertia(payload_mass, (0.5, 0.5, 0.5)),
                       (Geom("box", (0.25, 0.25, 0.25), rgba=_RED),)))
    note("tool (grapple)", "60 kg box 0.5 x 0.3 x 0.4 m", "design")
    note("payload", f"{payload_mass:g} kg cube 0.5 m, 0.5 m below the tool", "design")
    note("wheel drives", "6 rad/s (2.1 m/s), 4 kN m per wheel; one command per side",
         "design (hydrostatic skid-steer)")

    return Machine(
        bodies=tuple(bodies),
        loops=tuple(loops),
        chains=chains,
        direct_drives=drives,
        wheels=("wheel_FL", "wheel_RL", "wheel_FR", "wheel_RR"),
        wheel_radius=wheel_r,
        wheel_drive=(6.0, 4000.0),
        crane_coordinates=("slew", "lift", "tilt", "telescope", "wrist_pitch", "wrist_roll",
                           "rotator"),
        suspension_coordinates=("bogie_L", "bogie_R"),
        payload="payload",
        tcp_body="rotator",
        tcp_position=(0.0, 0.0, -0.25),
        gravity=g,
        sources=tuple(src),
    )
