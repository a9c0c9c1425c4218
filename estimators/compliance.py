r"""The machine's compliance: chassis warp stiffness and the servo-deflection fourth row.

The diagonal load split ``n = (+1, -1, -1, +1)`` (FL, RL, FR, RR) is statically
indeterminate: the equilibrium rows (eqs. 25-28) leave it free, and only the compliances
between the rigid chassis and the ground fix it. This module derives both compliances from
the machine description and uses them twice.

**1. Warp stiffness** (`WarpCompliance`). Per bogie (half distance ``a`` between the two
wheel centres' horizontal arms about the pivot, chain coefficient ``k1 = d theta / dx``,
eq. 6), the suspension servo ``F = kp (s - x)`` acts on the bogie angle with the generalized
force ``F / k1`` (virtual work), so at fixed setpoint the bogie's rotational stiffness is
``K_theta = kp / k1^2`` and a setpoint step turns the bogie by ``k1 ds``. A load change
``delta n`` loads the left bogie by the moment ``+2 a delta`` and the right one by ``-2 a
delta``; the rigid chassis' heave, roll and pitch are orthogonal to ``n``, so the
compatibility along ``n`` on flat ground is ``delta sum_i 1/k_t,i = -2 a (d theta_L -
d theta_R)``. With ``d theta = k1 ds +- 2 a delta / K_theta``::

    delta = -2 a (k1_L ds_L - k1_R ds_R) / (sum_i 1/k_t,i + 4 a^2 (1/K_L + 1/K_R))

For equal sides this is ``delta = k_w (ds_L - ds_R)`` with

    k_w = (a |k1| / 2) * k_series,   1/k_series = (sum_i 1/k_t,i) / 4 + 1/k_s,
    k_s = kp / (2 a^2 k1^2)          (servo stiffness per wheel along n),

i.e. the per-wheel series stiffness of servo and tyre, times the per-wheel displacement
along ``n`` that a rigid setpoint step would give (``a |k1| / 2`` per metre of setpoint
difference). ``k1`` (and so ``k_w``) depends on the bogie strokes. Neglected: the geometric
stiffness of the static cylinder force (``F dk1/dx / k1^3``, 0.1 % of ``kp / k1^2``) and of
the wheel loads on the bogie arms (0.02 %), the chassis pitch (arms taken in the chassis
frame), a fore-aft asymmetry of the arms (``a`` is their mean) and the friction forces.

**Tyre (contact) stiffness** of MuJoCo's soft contact (`contact_force`,
`tyre_stiffness`), from MuJoCo's documented constraint model: with ``solref = (tc,
zeta)``, ``solimp = (d0, dmax, width, mid, power)`` and penetration ``r`` the reference
acceleration is ``a_ref = -b v - k r`` with ``k = d(r) / (dmax^2 tc^2 zeta^2)`` and the
regularizer ``R = (1 - d) / d * A_hat`` (``A_hat``: MuJoCo's diagonal approximation of the
constraint's inverse inertia). At rest (zero constraint acceleration, friction inside the
cone) the inverse dynamics give ``f = a_ref / R``, so

    F(r) = d(r)^2 r / (dmax^2 tc^2 zeta^2 (1 - d(r)) A_hat),

with ``d(r)`` MuJoCo's polynomial sigmoid. No approximation of the contact law is made;
``A_hat`` is MuJoCo's ``body_invweight0`` of the wheel body (the mean translational inverse
inertia at the model's ``qpos0``, computed by MuJoCo's compiler from the inertias of the
description; the world adds nothing). The tyre stiffness is the tangent ``dF/dr`` at the
wheel's load: about 6.0e7 N/m at 12.5 kN, ~14x the servos' ``k_s`` (4.4e6 N/m).

**2. The compliance fourth row** (`compliance_forces`, `ComplianceEstimator`): the bogie
moment balances of the ``cylinder-force`` closure, with the suspension cylinder forces
predicted from the servo's deflection, ``F = kp (s - x) - kv x_dot`` clipped to the force
range, from the setpoint ``s`` (known to the axis controller, `MachineState.servo_setpoint`)
and the stroke sensors alone. ``kp`` = `ServoSpec.kp` (~1.0e8 N/m for the suspension) is of
the order of a cylinder's oil-column stiffness ``beta (A_a^2 / V_a + A_b^2 / V_b)``
(`oil_column_stiffness`: 1.5e8 N/m at mid stroke for the 0.10/0.06 m, 0.25 m suspension
cylinder with beta = 1.5 GPa and no hose volume, ~1e8 N/m with 0.3 L of hoses per side).
The row is sensitive to stroke noise through ``kp``: 1 um of stroke error is 100 N of
cylinder force, ~15 N (0.1 % of the static load) at a wheel. On MuJoCo runs (flat and 10 deg
rough, crane and suspension moving; `tests/test_compliance.py`) the mean error over the
four-contact samples is 0.001-0.02 % of the static wheel load with exact strokes (as with the
measured cylinder forces), 0.02-0.03 % with strokes quantized at 1 um and ~0.1 % (max 0.4 %)
with 2 um noise on top; the d-beta row is at ~16 % on the same samples.

What is simplified, and when this holds on a real machine: the simulated servo is a
*proportional* position loop with a finite stiffness ``kp``; its steady deflection ``s - x``
is the load, so setpoint and stroke measure the force. A real valve-controlled cylinder
under an integrating position loop (a flow valve integrates the position error) has no
steady deflection: the oil column's compression is taken up by the flow, the stroke returns
to the setpoint whatever the load, and ``s - x`` says nothing about the force. There this
row needs pressure transducers (``F = p_a A_a - p_b A_b``, the ``cylinder-force`` row). It
holds where the axis is deliberately compliant (a proportional loop, or a load-holding
valve with a known leakage/stiffness), and only if ``kp`` is known: on the real cylinder
the oil-column stiffness varies with stroke, temperature and entrained air (beta 1-1.6 GPa),
so ``kp`` would need calibration. The anti-windup of the simulator (the setpoint kept within
1.5 full-force deflections of the stroke) moves ``s`` but keeps ``F = kp (s - x)`` exact; at
the force limit the actuator saturates and ``compliance_forces`` clips the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from estimators.errors import EstimatorInputError
from models.coordinates import N_INDEPENDENT
from models.description import HydraulicCylinder, Machine
from models.mujoco import CONTACT_SOLIMP, CONTACT_SOLREF, build_model, servo_specs
from models.state import MachineState
from models.terrain import flat

__all__ = ["ComplianceEstimator", "WarpCompliance", "WarpGains", "compliance_forces",
           "contact_force", "contact_impedance", "oil_column_stiffness", "tyre_stiffness"]

SUSPENSION = (0, 1)  # independent indices of bogie_L, bogie_R


def contact_impedance(r, solimp=CONTACT_SOLIMP) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's impedance ``d(r)`` and ``dd/dr`` at penetration ``r`` [m] (>= 0).

    The polynomial sigmoid of ``solimp = (d0, dmax, width, mid, power)``: ``y = x^p /
    mid^(p-1)`` below ``mid``, ``1 - (1-x)^p / (1-mid)^(p-1)`` above, ``x = r / width``
    clipped to [0, 1], ``d = d0 + y (dmax - d0)``.
    """
    d0, dmax, width, mid, power = solimp
    x = np.clip(np.asarray(r, float) / width, 0.0, 1.0)
    low = x <= mid
    y = np.where(low, x ** power / mid ** (power - 1),
                 1.0 - (1.0 - x) ** power / (1.0 - mid) ** (power - 1))
    dy = np.where(low, power * x ** (power - 1) / mid ** (power - 1),
                  power * (1.0 - x) ** (power - 1) / (1.0 - mid) ** (power - 1))
    dy = np.where((x <= 0.0) | (x >= 1.0), 0.0, dy) / width
    return d0 + y * (dmax - d0), dy * (dmax - d0)


def contact_force(r, inv_weight: float, solref=CONTACT_SOLREF,
                  solimp=CONTACT_SOLIMP) -> tuple[np.ndarray, np.ndarray]:
    """Static normal force of MuJoCo's soft contact and its tangent stiffness.

    ``F = d^2 r / (dmax^2 tc^2 zeta^2 (1 - d) A_hat)`` (module docstring).

    Args:
        r: Penetration [m], >= 0, any shape.
        inv_weight: ``A_hat``, the contact's diagonal inverse inertia [1/kg].
        solref: (timeconst [s], dampratio [-]), both > 0.
        solimp: MuJoCo's five impedance parameters.

    Returns:
        (force [N], stiffness dF/dr [N/m]), each of the shape of ``r``.
    """
    tc, zeta = solref
    r = np.asarray(r, float)
    d, dd = contact_impedance(r, solimp)
    c = 1.0 / (solimp[1] ** 2 * tc ** 2 * zeta ** 2 * inv_weight)
    g = d * d * r / (1.0 - d)
    dg = ((2.0 * d * dd * r + d * d) * (1.0 - d) + d * d * r * dd) / (1.0 - d) ** 2
    return c * g, c * dg


def tyre_stiffness(load, inv_weight: float, solref=CONTACT_SOLREF,
                   solimp=CONTACT_SOLIMP) -> tuple[np.ndarray, np.ndarray]:
    """Penetration and tangent stiffness of the contact at a normal ``load``.

    Args:
        load: Normal force [N], > 0, shape (n,) or scalar.
        inv_weight: ``A_hat`` [1/kg] (scalar or broadcastable to ``load``).
        solref: (timeconst [s], dampratio [-]).
        solimp: MuJoCo's five impedance parameters.
        solref, solimp: As in `contact_force`.

    Returns:
        (penetration [m], stiffness [N/m]), shape of ``load``.

    Raises:
        EstimatorInputError: A load is not positive and finite.
    """
    f = np.asarray(load, float)
    if not np.all(np.isfinite(f) & (f > 0)):
        raise EstimatorInputError(f"wheel loads must be positive and finite [N], got {f}")
    lo, hi = np.zeros_like(f), np.full_like(f, 1.0)
    for _ in range(60):  # F(r) increases monotonically: bisection to ~1e-18 m
        mid = 0.5 * (lo + hi)
        big = contact_force(mid, inv_weight, solref, solimp)[0] > f
        hi, lo = np.where(big, mid, hi), np.where(big, lo, mid)
    r = 0.5 * (lo + hi)
    return r, contact_force(r, inv_weight, solref, solimp)[1]


def oil_column_stiffness(cylinder: HydraulicCylinder, stroke: float,
                         bulk_modulus: float = 1.5e9, dead_volume: float = 0.0) -> float:
    """Hydraulic stiffness of a cylinder held by closed ports [N/m].

    ``k = beta (A_a^2 / V_a + A_b^2 / V_b)``, ``V_a = A_a x + V_0``,
    ``V_b = A_b (L - x) + V_0``.

    Args:
        cylinder: Bore, rod and stroke ``L``.
        stroke: ``x`` [m], inside (0, L) unless ``dead_volume > 0``.
        bulk_modulus: Effective ``beta`` of the oil [Pa] (1.4-1.6 GPa for mineral oil).
        dead_volume: ``V_0`` per chamber (hoses, valve block) [m^3].
    """
    va = cylinder.area_piston * stroke + dead_volume
    vb = cylinder.area_rod * (cylinder.stroke - stroke) + dead_volume
    if va <= 0 or vb <= 0:
        raise EstimatorInputError(f"stroke {stroke} m leaves an empty chamber of "
                                  f"'{cylinder.name}' (stroke {cylinder.stroke} m)")
    return bulk_modulus * (cylinder.area_piston ** 2 / va + cylinder.area_rod ** 2 / vb)


@dataclass(frozen=True)
class WarpGains:
    """The chassis warp by the suspension setpoints at one configuration.

    ``df = n (gain_left ds_L - gain_right ds_R)``, ``n = (+1, -1, -1, +1)``.

    Attributes:
        gains: (left, right) [N/m per wheel along n per metre of setpoint].
        tyre: Tangent contact stiffness per wheel [N/m], shape (4,), FL, RL, FR, RR.
        servo: Servo stiffness per wheel along n, ``kp / (2 a^2 k1^2)`` per side [N/m].
        arm: Half wheel spacing ``a`` per side [m]. k1: ``d theta / dx`` per side [rad/m].
    """

    gains: tuple[float, float]
    tyre: np.ndarray
    servo: tuple[float, float]
    arm: tuple[float, float]
    k1: tuple[float, float]

    @property
    def stiffness(self) -> float:
        """``k_w`` [N/m per wheel along n per metre of ``s_L - s_R``]: the mean gain."""
        return 0.5 * (self.gains[0] + self.gains[1])


class WarpCompliance:
    """Chassis warp stiffness of a machine, from its description (module docstring).

    Construction compiles the machine's MuJoCo model once (servo gains, the contacts'
    ``body_invweight0``); `gains` is then a few scalar formulas.

    Args:
        machine: The machine description (two suspension chains ``bogie_L``, ``bogie_R``;
            wheels FL, RL on the left bogie, FR, RR on the right one).
        solref, solimp: The wheel contacts' MuJoCo parameters.
    """

    def __init__(self, machine: Machine, solref=CONTACT_SOLREF, solimp=CONTACT_SOLIMP):
        self.machine = machine
        self.solref, self.solimp = tuple(solref), tuple(solimp)
        coords = machine.coordinates
        self._chains = []
        for i in SUSPENSION:
            binding = coords.binding(i)
            if binding is None:
                raise EstimatorInputError(f"coordinate {coords.independent_names[i]!r} is "
                                          f"not a suspension chain")
            wheels = [b for b in machine.bodies if b.parent == binding.driven_joint
                      and b.name in machine.wheels]
            if len(wheels) != 2:
                raise EstimatorInputError(f"bogie {binding.driven_joint!r} carries "
                                          f"{len(wheels)} wheels, expected 2")
            pos = np.array([w.position[[0, 2]] for w in wheels])  # (x, z) in the bogie
            self._chains.append((binding.chain, pos))
        specs = servo_specs(machine)
        self.kp = np.array([specs[i].kp for i in SUSPENSION])
        model = build_model(machine, flat())
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, w) for w in machine.wheels]
        self.inv_weight = model.body_invweight0[ids, 0].copy()  # [1/kg], FL, RL, FR, RR
        self.static_load = machine.total_mass * machine.gravity / 4
        self._static_tyre = tyre_stiffness(np.full(4, self.static_load), self.inv_weight,
                                           self.solref, self.solimp)[1]

    def gains(self, q, wheel_loads=None) -> WarpGains:
        """The warp gains at the strokes of ``q`` and the given wheel loads.

        Args:
            q: Independent coordinates, shape (13,) (only the two suspension strokes are
                used) [m].
            wheel_loads: Normal forces [N], shape (4,), FL, RL, FR, RR; None: the static
                wheel load (total weight / 4) on every wheel. Loads below 10 % of that are
                raised to it (a nearly unloaded tyre is soft, and the warp is then set by
                the three other wheels).

        Raises:
            EstimatorInputError: Wrong shape or non-finite values; a stroke outside its
                chain's range.
        """
        q = np.asarray(q, float)
        if q.shape != (N_INDEPENDENT,) or not np.all(np.isfinite(q)):
            raise EstimatorInputError(f"q must be 13 finite coordinates, got shape {q.shape}")
        loads = (np.full(4, self.static_load) if wheel_loads is None
                 else np.asarray(wheel_loads, float))
        if loads.shape != (4,) or not np.all(np.isfinite(loads)):
            raise EstimatorInputError(f"wheel_loads must be 4 finite forces [N], got {loads}")
        if wheel_loads is None:  # cached: then a call is a few scalar formulas (~0.15 ms)
            k_t = self._static_tyre
        else:
            loads = np.maximum(loads, 0.1 * self.static_load)
            k_t = tyre_stiffness(loads, self.inv_weight, self.solref, self.solimp)[1]
        arms, k1s = [], []
        for (chain, pos), x in zip(self._chains, q[list(SUSPENSION)]):
            chain.check_stroke(float(x))
            k1, _ = chain.driven_rate_coefficients(float(x))
            theta = chain.joint_angle(float(x))
            # Horizontal arm of each wheel centre about the pivot, bogie turned by theta
            # (axis -y: +x turns towards +z): dz/dtheta = x cos(theta) - z sin(theta).
            h = pos[:, 0] * math.cos(theta) - pos[:, 1] * math.sin(theta)
            arms.append(0.5 * float(h.max() - h.min()))
            k1s.append(float(k1))
        a = 0.5 * (arms[0] + arms[1])
        rot = [kp / k1 ** 2 for kp, k1 in zip(self.kp, k1s)]  # K_theta [N m/rad]
        den = float(np.sum(1.0 / k_t)) + 4.0 * a * a * (1.0 / rot[0] + 1.0 / rot[1])
        gains = (-2.0 * a * k1s[0] / den, -2.0 * a * k1s[1] / den)
        servo = tuple(float(k / (2.0 * a * a)) for k in rot)
        return WarpGains(gains, k_t, servo, (arms[0], arms[1]), (k1s[0], k1s[1]))

    def stiffness(self, q=None, wheel_loads=None) -> float:
        """``k_w`` [N/m per wheel along n per metre of ``s_L - s_R``] (`WarpGains`).

        Args:
            q: Independent coordinates (13,); the machine's home pose if None.
            wheel_loads: See `gains`.
        """
        q = self.machine.coordinates.home() if q is None else q
        return self.gains(q, wheel_loads).stiffness


def compliance_forces(machine: Machine, state: MachineState, specs=None) -> np.ndarray:
    """Suspension cylinder forces predicted from the servos' deflection [N], shape (2,).

    ``F = kp (s - x) - kv x_dot`` clipped to `ServoSpec.force_range`, with ``s`` =
    ``state.servo_setpoint[:2]``, ``x``, ``x_dot`` the measured strokes and stroke rates
    (positive extends, order bogie_L, bogie_R).

    Args:
        machine: The machine description.
        state: The measured state, with ``servo_setpoint``.
        specs: `servo_specs` of the machine (computed if None; pass them in a loop).

    Raises:
        EstimatorInputError: The state has no servo setpoints.
    """
    if state.servo_setpoint is None:
        raise EstimatorInputError("the compliance row needs state.servo_setpoint")
    specs = servo_specs(machine) if specs is None else specs
    idx = list(SUSPENSION)
    s = np.asarray(state.servo_setpoint, float)[idx]
    f = np.array([specs[i].kp for i in idx]) * (s - state.q[idx]) \
        - np.array([specs[i].kv for i in idx]) * state.qd[idx]
    lo = np.array([specs[i].force_range[0] for i in idx])
    hi = np.array([specs[i].force_range[1] for i in idx])
    return np.clip(f, lo, hi)


class ComplianceEstimator:
    """The cylinder-force closure on stroke sensors alone (no pressure transducers).

    Replaces ``state.suspension_force`` by `compliance_forces` and calls ``closure`` (an
    estimator with ``fourth="cylinder-force"``); nothing is recompiled.

    Args:
        machine: The machine description.
        closure: E.g. ``NormalForceEstimator(machine, fourth="cylinder-force")``.
    """

    def __init__(self, machine: Machine, closure):
        self.machine = machine
        self.closure = closure
        self.specs = servo_specs(machine)

    def _with_forces(self, state: MachineState) -> MachineState:
        return state.replace(suspension_force=compliance_forces(self.machine, state,
                                                                self.specs))

    def estimate(self, state: MachineState):
        """The closure's `Estimate` with the predicted cylinder forces."""
        return self.closure.estimate(self._with_forces(state))

    def linearize(self, state: MachineState):
        """The closure's `ForceLinearization` with the predicted cylinder forces."""
        return self.closure.linearize(self._with_forces(state))
