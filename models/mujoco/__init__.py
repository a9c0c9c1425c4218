"""MuJoCo model of a `Machine` on a `Terrain`, generated as MJCF and compiled through `MjSpec`.

The generator writes the menagerie layout: ``machine.xml`` (bodies, inertias, joints, loop
closures, cylinder tendons, actuators, default classes ``visual``, ``collision`` and
``loop_point``) and one ``scene_<terrain>.xml`` per terrain that includes it and adds the
ground, lights and the ``home`` keyframe (the machine placed on that ground with its chains
closed, from `TreeCoordinates.home`). `build_model` compiles exactly the same text in memory,
so the files on disk and the model used in code cannot differ. Body and joint names are the
description's; the free joint is named after the root body, actuators after the independent
coordinates they drive.

The model, and why (figures measured for the reference machine, see the tests and report):

* **Integrator** ``implicitfast``, **timestep** `DEFAULT_TIMESTEP` = 2 ms. Measured on the
  paper's open-loop scenarios: the chains stay closed to 0.015 mm; normal forces agree with a
  0.5 ms run to 1 % of the static wheel load until the trajectories part (stick-slip events
  are timing-sensitive); one step costs about 35 us. At 1 ms the scenarios run at half the
  speed for no visible gain; at 2.5 ms the explicit servo damping (below) must drop to
  ``zeta`` 0.02 and at 3 ms the stiff servos are unstable. Solver tolerance 1e-10: the
  contact forces of a state are reproducible to 1e-7 relative at no measurable cost.
* **Loop closures**: one ``connect`` equality per `Loop`, between two sites at the loop
  points (site form, so the chains need not be closed at ``qpos0``), ``solref = (2 h, 1)``
  (the stiffest MuJoCo accepts) and ``solimp = (0.99, 0.999, 1 mm)``. With MuJoCo's default
  ``solref``/``solimp`` the chains open by half a millimetre in the same scenarios.
* **Hydraulic cylinders** push along their pin-to-pin line: a spatial tendon from the base
  pivot (on the base link) to the rod eye (on the driven link), whose length is
  ``L_c0 + x + L_c``. The actuator ``F = kp (u - x)`` (``x`` read off the tendon) is clipped
  to `HydraulicCylinder.force_range`. Acting on the tendon rather than on the 10-kg piston
  joint keeps the cylinder force out of the loop constraint, which then only carries the
  piston's own inertia; the piston and barrel ride along passively.
* **Servo damping is explicit**. MuJoCo's ``implicitfast`` integrates actuator damping with
  ``M + h D`` while it solves the loop constraints with ``M``; with damping gains large
  enough to matter this mismatch opened the chains by 0.1-1 mm on rough terrain. The
  `scenarios.simulator.Simulator` therefore sets ``u = s - (kv / kp) x_dot`` before each
  step, which applies ``F = kp (s - x) - kv x_dot`` with the damping evaluated at the start of
  the step, and moves the setpoint ``s`` at the commanded rate (the valve): rate limited by
  `HydraulicCylinder.velocity_range`, kept within the stroke range and within full-force
  deflection of the stroke (anti-windup). Explicit damping is bounded by stability, so the
  crane's lift, tilt and telescope servos end up lightly damped (``zeta`` 0.04-0.08); see
  `servo_specs`. The bound depends on the pose (the slew's free inertia falls 15-fold with
  the crane upright), so the simulator caps each servo's damping at every few steps at what
  the current pose allows (`DampingSchedule`); elsewhere the designed damping applies.
  Standalone (in a viewer) ``ctrl`` is the stroke setpoint and the servos are undamped.
* **Telescope and wrist**: the same servo on their joints (``position`` actuators), limits
  from `Machine.direct_drives`.
* **Wheels**: ``velocity`` actuators ``tau = kv (u - omega)``, ``kv`` = `WHEEL_VELOCITY_GAIN`,
  speed and torque limits from `Machine.wheel_drive`; the simulator drives each side's pair
  with one command. ``kv`` = 5 kN m s/rad is a hydrostatic drive's speed droop (0.8 rad/s at
  full torque): with a near-rigid 20 kN m s/rad the skid-steering machine's rear wheels hop
  at the torque limit (stick-slip of the lateral scrub; 5 % contact loss on the flat run),
  which no real tyre's compliance would allow.
* **Contacts**: only the wheel spheres (class ``collision``) and the terrain collide (visual
  geoms have ``contype = conaffinity = 0``): one contact point per wheel on a plane, the
  paper's assumption. On a height field MuJoCo reports one contact per triangle prism a
  wheel reaches, several coincident ones on a flat patch or a ridge; the simulator keeps one
  per wheel and face (`ContactMerge`, module `contacts`). The terrain geom has
  ``priority = 1`` so its friction (`Terrain.friction`, condim 3, elliptic cone),
  ``solref = (10 ms, 1)`` (critically damped) and ``solimp = (1e-4, 0.95, 2 mm, 0.5, 2)``
  govern. The impedance rises from MuJoCo's minimum at zero penetration to 0.95 at 2 mm, so
  the contact force goes to zero continuously as a wheel unloads (a tyre's force-deflection
  law does), and the wheel sinks 1.1 mm at 3 kN, 1.36 mm at its static load of 12.6 kN,
  1.5 mm at 25 kN (tangent stiffness 1.8e7, 6.0e7, 1.2e8 N/m; `estimators.compliance`).
  With an impedance of 0.9 already at zero penetration (the earlier setting) the ground
  carried a wheel's 3 kN at 0.09 mm at rest and at 0.02 mm in motion: the force did not
  vanish with the penetration, and wheels lost contact for single 2 ms steps whenever they
  drifted a few micrometres up (development draws of the random family, master seed 1:
  2-4 ms drops to 0 N on 3 of 40 with the contacts merged; 0 of the 4 draws examined after).
  The friction rows are 3x as stiff (``impratio = 3``): MuJoCo's soft friction lets a held
  machine creep down a 15 deg side slope, at 4.7 mm/s with it (14 mm/s with 1, 4.0 mm/s with
  the earlier impedance). Simplified: no tyre model (carcass deflection, contact patch,
  rolling resistance).

Files: `constants` (the settings above), `contacts` (coincident contacts merged), `elements`
(MJCF building blocks, body poses), `servos` (servo gains from the tree's inertia),
`placement` (on a terrain, the keyframe), `mjcf` (machine and scene text), `build` (compile,
write), `index` (ids by name).
"""

from models.mujoco.build import build_model, build_spec, default_terrains, write_mjcf
from models.mujoco.constants import (
    CONTACT_IMPRATIO,
    CONTACT_SOLIMP,
    CONTACT_SOLREF,
    DEFAULT_TIMESTEP,
    EQUALITY_SOLIMP,
    SERVO_DAMPING_RATIO,
    SERVO_POSITION_ERROR,
    WHEEL_VELOCITY_GAIN,
)
from models.mujoco.contacts import MERGE_ANGLE, MERGE_DISTANCE, ContactMerge
from models.mujoco.elements import body_poses_in_fb
from models.mujoco.index import MujocoIndex
from models.mujoco.mjcf import machine_xml, scene_xml
from models.mujoco.placement import home_keyframe, place_on_terrain
from models.mujoco.servos import (
    DampingSchedule,
    ServoSpec,
    gravity_loads,
    reflected_inertia,
    servo_specs,
)

__all__ = [
    "CONTACT_IMPRATIO", "CONTACT_SOLIMP", "CONTACT_SOLREF", "ContactMerge", "DEFAULT_TIMESTEP",
    "DampingSchedule", "EQUALITY_SOLIMP", "MERGE_ANGLE", "MERGE_DISTANCE", "MujocoIndex",
    "SERVO_DAMPING_RATIO", "SERVO_POSITION_ERROR", "ServoSpec", "WHEEL_VELOCITY_GAIN",
    "body_poses_in_fb", "build_model", "build_spec", "default_terrains", "gravity_loads",
    "home_keyframe", "machine_xml", "place_on_terrain", "reflected_inertia", "scene_xml",
    "servo_specs", "write_mjcf",
]
