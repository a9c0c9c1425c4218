"""Settings of the generated MuJoCo model (the reasons are in `models.mujoco`)."""

import math

from models.errors import ModelError

DEFAULT_TIMESTEP = 0.002  # [s]
EQUALITY_SOLREF_STEPS = 2.0  # loop-closure time constant in timesteps (MuJoCo's minimum)
EQUALITY_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)
CONTACT_SOLREF = (0.01, 1.0)  # [s], [-]
# Impedance from MuJoCo's minimum at zero penetration to 0.95 at 2 mm: the wheel's force
# vanishes continuously as it leaves the ground (see `models.mujoco`, Contacts).
CONTACT_SOLIMP = (0.0001, 0.95, 0.002, 0.5, 2.0)
# Friction rows 3x as stiff as the normal row (elliptic cones): with the impedance above a
# held machine creeps down a 15 deg side slope at 4.7 mm/s (14 mm/s with 1; 4.0 mm/s with
# the earlier contact).
CONTACT_IMPRATIO = 3.0
SERVO_POSITION_ERROR = {"slide": 2e-3, "hinge": 1e-2}  # [m], [rad] deflection at full force
SERVO_DAMPING_RATIO = 0.5  # [-] target at the locked reflected inertia (see servo_specs)
SERVO_EXPLICIT_DAMPING = 0.3  # [-] cap of h kv / m_free (one explicit damper: stable < 2)
SERVO_STABILITY_MARGIN = 1.25  # explicit damping must stay stable at this times the timestep
SERVO_EXPLICIT_LIMIT = 1.0  # [-] cap of h kv / m_free at the current pose (see DampingSchedule)
WHEEL_VELOCITY_GAIN = 5e3  # [N m s/rad]
SOLVER_TOLERANCE = 1e-10  # Newton converges in the same 2-4 iterations; forces repeatable
TERRAIN_BASE_DEPTH = 1.0  # [m] thickness of the height field below its lowest point
MACHINE_FILE = "machine.xml"

JOINT_TYPE = {"revolute": "hinge", "prismatic": "slide"}


def check_timestep(timestep: float) -> float:
    """``timestep`` [s] as a float in (0, half the contact time constant], else `ModelError`."""
    try:
        timestep = float(timestep)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"timestep must be a number [s], got {timestep!r}") from exc
    if not (math.isfinite(timestep) and 0 < timestep <= CONTACT_SOLREF[0] / 2):
        raise ModelError(f"timestep {timestep:g} s outside (0, {CONTACT_SOLREF[0] / 2:g}] s "
                         f"(the contact time constant must span two steps)")
    return timestep
