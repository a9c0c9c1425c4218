r"""The crane's load chart, from the machine description: the largest payload at a pose.

At a crane pose (and a base attitude), held still, the actuator efforts and the wheels'
normal forces are affine in the payload mass ``m`` (the dynamics are linear in the inertial
parameters; the payload's centre of mass is fixed in its body). The rated payload is the
largest ``m`` for which

* every servo can hold the pose: each cylinder's force stays within its pressure x area range
  (``[-p A_B, p A_A]``, `HydraulicCylinder.force_range`), each rotary drive's torque within
  its effort limit;
* no wheel's normal force falls below the threshold, with the best diagonal load split the
  suspension can set: the four normal forces satisfy the three equilibrium rows (total
  vertical force, roll and pitch moments) exactly, and the remaining direction ``n`` (the
  chassis warp, set by the suspension servos) is free. That is a linear program in ``(m,
  t)``: ``max m`` subject to ``f_p0 + m f_p1 + t n >= f_min`` and the effort bounds.

The efforts and the ground wrench come from Pinocchio's RNEA of the description
(`models.pinocchio_model`), evaluated at two payload masses; the efforts of a closed chain
are the tree's joint torques mapped through the chain's Jacobian (virtual work, eqs. 6-7).
Simplifications: static (no crane motion, no driving), flat ground under the wheels (the
contact points are the wheels' lowest points for the base attitude given), the warp free
within the servos' range (not bounded by how far the suspension can twist the chassis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.optimize import linprog

from models.description import Machine
from models.errors import ModelError
from models.pinocchio_model import PAYLOAD_PAIR_MASSES, PinocchioMachine, payload_pair
from models.state import MachineState

__all__ = ["RatedLoad", "effort_ranges", "load_chart", "rated_payload"]

_M0, _M1 = PAYLOAD_PAIR_MASSES  # [kg] the two payload masses the affine maps are read at
_MAX_PAYLOAD = 1e4  # [kg] the LP's upper bound (a rated load is far below)


@dataclass(frozen=True)
class RatedLoad:
    """The rated payload at one pose.

    Attributes:
        mass: Largest payload [kg] (0 when even an empty grapple is out of the limits).
        limit: What limits it: a coordinate's name (its actuator) or ``tipping``.
        forces: The wheels' normal forces with that payload and the best split [N], (4,).
        sensitivity: How the wheels' forces change with the payload at this pose [N/kg],
            (4,): the least-norm solution of the equilibrium rows (no warp), the part a
            sudden load change sets before the suspension moves the split.
    """

    mass: float
    limit: str
    forces: np.ndarray
    sensitivity: np.ndarray


def _models(machine: Machine) -> tuple[PinocchioMachine, PinocchioMachine]:
    return payload_pair(machine)


def _efforts_and_wrench(pm: PinocchioMachine, state: MachineState):
    q, v, a = pm.configuration(state)
    tau = pin.rnea(pm.model, pm.data, q, v, a)
    jac, _ = pm.coordinates.jacobian(state.q)  # tree joints <- independent coordinates
    tree_tau = tau[pm._tree_v_idx]
    return jac.T @ tree_tau, tau[:6].copy()


def effort_ranges(machine: Machine) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) effort of each independent coordinate [N or N m], shape (13,) each.

    A chain's cylinder: ``(-p A_B, p A_A)`` (`HydraulicCylinder.force_range`); a direct
    drive: its effort limit; anything else (the wheels): unbounded.
    """
    names = machine.coordinates.independent_names
    lo, hi = np.full(len(names), -np.inf), np.full(len(names), np.inf)
    for i, name in enumerate(names):
        if name in machine.chains:
            lo[i], hi[i] = machine.chains[name].cylinder.force_range
        elif name in machine.direct_drives:
            e = machine.direct_drives[name].effort_limit
            lo[i], hi[i] = -e, e
    return lo, hi


def _ground_rows(pm: PinocchioMachine, state: MachineState) -> tuple[np.ndarray, float]:
    """The equilibrium rows (3, 4) of the normal forces, and the contact points' height.

    The ground is a plane under the wheels parallel to the chassis (its normal fb's z axis,
    as on a slope the chassis stands on): each wheel touches it at its centre less one radius
    along fb's z, and its normal force acts along fb's z. Returns the rows ``(1, p_y,
    -p_x)`` per wheel and the mean contact height ``z_c`` in fb [m] (`_normal_rows`).
    """
    machine = pm.machine
    q, _, _ = pm.configuration(state)
    pin.framesForwardKinematics(pm.model, pm.data, q)
    base = pm.data.oMf[pm.frame_id[machine.bodies[0].name]]
    rows = np.zeros((3, 4))
    heights = np.zeros(4)
    for k, wheel in enumerate(machine.wheels):
        p = base.actInv(pm.data.oMf[pm.frame_id[wheel]]).translation.copy()
        p[2] -= machine.wheel_radius
        rows[:, k] = (1.0, p[1], -p[0])
        heights[k] = p[2]
    return rows, float(heights.mean())


def _normal_rows(wrench: np.ndarray, contact_height: float) -> np.ndarray:
    """The right-hand side of the normal forces' rows from the ground wrench (fb, at fb).

    The ground's tangential forces (friction, carrying the weight's share along a slope;
    their sums are the wrench's ``f_x, f_y``) act at the contact points' height ``z_c``, so
    their moment moves the roll and pitch rows: ``sum p_y f_z = m_x + z_c f_y``,
    ``-sum p_x f_z = m_y - z_c f_x``. Left out, a 10 deg side slope moves 2 kN from each
    wheel of one side to the other (MuJoCo, `tests/test_load_chart.py`).
    """
    fx, fy, fz, mx, my = wrench[:5]
    return np.array([fz, mx + contact_height * fy, my - contact_height * fx])


def rated_payload(machine: Machine, q, threshold_n,
                  base_rotation=None, effort_fraction: float = 1.0) -> RatedLoad:
    """The largest payload the machine can hold at the pose ``q`` (module docstring).

    Args:
        machine: The machine description (its payload's shape; its mass is not used).
        q: Independent coordinates, shape (13,).
        threshold_n: The smallest normal force every wheel must keep [N]: one for all, or
            one per wheel (4,) (a controller's threshold plus its per-wheel margins).
        base_rotation: Base attitude (world <- fb), (3, 3); level if None.
        effort_fraction: The share of each effort range the servos may use, in (0, 1]: a
            controller that keeps a margin on its cylinders' forces holds this much.

    Raises:
        ModelError: ``threshold_n`` not a finite force >= 0 (or four of them), or
            ``effort_fraction`` not in (0, 1].
    """
    try:
        thr = np.asarray(threshold_n, float)
    except (TypeError, ValueError):
        thr = np.array(np.nan)
    if thr.shape not in ((), (4,)) or not (np.all(np.isfinite(thr)) and np.all(thr >= 0)):
        raise ModelError(f"threshold_n must be a finite force >= 0 [N] or four of them, got "
                         f"{threshold_n!r}")
    if not (isinstance(effort_fraction, (int, float)) and 0 < effort_fraction <= 1):
        raise ModelError(f"effort_fraction must be in (0, 1], got {effort_fraction!r}")
    rot = np.eye(3) if base_rotation is None else np.asarray(base_rotation, float)
    zero = np.zeros(13)
    state = MachineState(np.zeros(3), rot, np.zeros(6), np.zeros(6), q, zero, zero)
    p0, p1 = _models(machine)
    e0, w0 = _efforts_and_wrench(p0, state)
    e1, w1 = _efforts_and_wrench(p1, state)
    de, dw = (e1 - e0) / (_M1 - _M0), (w1 - w0) / (_M1 - _M0)
    e_at0, w_at0 = e0 - _M0 * de, w0 - _M0 * dw  # affine maps at zero payload
    a, height = _ground_rows(p0, state)
    pinv = np.linalg.pinv(a)
    null = np.linalg.svd(a)[2][-1]
    f0, f1 = pinv @ _normal_rows(w_at0, height), pinv @ _normal_rows(dw, height)
    lo, hi = effort_ranges(machine)
    lo, hi = effort_fraction * lo, effort_fraction * hi
    names = machine.coordinates.independent_names
    # Each servo alone: lo <= e0 + m de <= hi bounds m from above (m >= 0).
    best, limit = _MAX_PAYLOAD, "none"
    for i in np.flatnonzero(np.isfinite(hi)):
        for bound, sign in ((hi[i], 1.0), (lo[i], -1.0)):
            slope, room = sign * de[i], sign * (bound - e_at0[i])
            if room < 0:
                return RatedLoad(0.0, names[i], f0.copy(), f1)
            if slope > 0 and room / slope < best:
                best, limit = room / slope, names[i]
    # Tipping with the best split: max m s.t. f0 + m f1 + t n >= f_min (variables m, t).
    res = linprog(c=[-1.0, 0.0], A_ub=np.column_stack([-f1, -null]),
                  b_ub=f0 - thr, bounds=[(0.0, _MAX_PAYLOAD), (None, None)],
                  method="highs")
    if res.status != 0:
        return RatedLoad(0.0, "tipping", f0.copy(), f1)
    if res.x[0] < best:
        best, limit = float(res.x[0]), "tipping"
    # The split at the rated mass: the one that maximizes the smallest force.
    res = linprog(c=[0.0, -1.0], A_ub=np.column_stack([-null, np.ones(4)]),
                  b_ub=f0 + best * f1, bounds=[(None, None), (None, None)], method="highs")
    t = res.x[0] if res.status == 0 else 0.0
    return RatedLoad(float(best), limit, f0 + best * f1 + t * null, f1)


def load_chart(machine: Machine, threshold_n: float, slews_deg=(0.0, 30.0, 60.0),
               telescopes=(0.05, 0.3, 0.55, 0.8, 1.05), lift_deg: float = 20.0,
               tilt_deg: float = -40.0, base_rotation=None) -> list[dict]:
    """Rated payloads over slew angles and telescope extensions (outer boom near level).

    Args:
        machine: The machine description.
        threshold_n: The smallest normal force every wheel must keep [N].
        slews_deg: Slew angles [deg].
        telescopes: Telescope extensions [m].
        lift_deg: The lift angle [deg].
        tilt_deg: The tilt angle [deg].
        base_rotation: Base attitude (world <- fb), (3, 3); level if None.

    Returns:
        One dict per pose: ``slew_deg``, ``telescope_m``, ``reach_m`` (horizontal distance of
        the tool point from the slew axis), ``rated_kg``, ``limit``.
    """
    ch = machine.chains
    out = []
    pm = _models(machine)[0]
    for slew in slews_deg:
        for tel in telescopes:
            q = machine.coordinates.home()
            q[2] = ch["slew"].chain.stroke_from_angle(np.radians(slew))
            q[3] = ch["lift"].chain.stroke_from_angle(np.radians(lift_deg))
            q[4] = ch["tilt"].chain.stroke_from_angle(np.radians(tilt_deg))
            q[5] = tel
            q[6] = -np.radians(lift_deg + tilt_deg)
            r = rated_payload(machine, q, threshold_n, base_rotation)
            zero = np.zeros(13)
            st = MachineState(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), q, zero, zero)
            qq, _, _ = pm.configuration(st)
            pin.framesForwardKinematics(pm.model, pm.data, qq)
            tcp = pm.data.oMf[pm.frame_id["tcp"]].translation
            slew_axis = pm.data.oMf[pm.frame_id["slew"]].translation
            reach = float(np.hypot(*(tcp - slew_axis)[:2]))
            out.append({"slew_deg": float(slew), "telescope_m": float(tel), "reach_m": reach,
                        "rated_kg": r.mass, "limit": r.limit})
    return out
