"""The paper's full-dynamics normal-force method, eqs. (9)-(30) and Sec. III-B.

Pipeline for one state (every step written once against an array backend ``ops``, see
`estimators.tree`, so that the same code runs in numpy and as a CasADi graph):

1. Forward recursion of twists and accelerations from fb through the tree, with the closed
   chains driven by their strokes (eqs. 2-10), and the Euler-Poincare wrench of every body
   (eq. 11), weights included through the base acceleration offset (`estimators.spatial`).
2. Backward accumulation to fb. By Theorem 1 the closed chains need no distribution factors:
   the total is the sum of all body wrenches carried to fb, grouped as the crane ``F_m``
   (eq. 14), the chassis/bogie/cylinder/piston wrench ``F_B`` (eq. 15) and the wheels
   ``F_w*`` (eqs. 16-17). `paper_wrenches` returns that breakdown.
3. ``F_Xi`` (eq. 20): the wrench the ground's normal forces must supply once the measured
   friction (tangential) forces ``F_a`` are accounted for at their contact points (eq. 19).
4. The 3x4 system (eqs. 25-28) from the force, roll-moment and pitch-moment rows, with the
   wheel and contact positions taken from the actual bogie angles and the measured contact
   points (the wheel's lowest point when not measured), not the constants of eq. (21).
5. A fourth row closes it: the empirical D-beta row (eq. 29) or, when the suspension cylinder
   forces are measured, the two bogie pitch-moment balances (least squares in the null space
   of the 3x4 system, so the three equilibrium rows stay exact). Wheels out of contact drop
   their column (Sec. III-B): three wheels give a 3x3 system, fewer flag tipping.

Sign and frame conventions (the paper leaves them implicit):

* Contact frames are aligned with fb (eqs. 22-23), so ``f_z`` is the force along the fb z
  axis, positive when the ground pushes the wheel up. The terrain-normal component is
  reported too (`Estimate.normal_forces_terrain`).
* ``F_Xi`` here is the wrench the normal contact forces must exert *on the machine*:
  ``F_Xi = W - sum_k Ad*_{c_k -> fb} F_a_k`` with ``W`` the total Euler-Poincare wrench
  (weights included) in fb. The paper's eq. (20) writes the same balance with the opposite
  sign of ``F_r`` (reaction on the ground); the resulting ``f_z`` are the same.
* Tangential forces not explained by the measured friction (``F_Xi(1:2)``) are taken to act
  at the mean height of the contact points in contact, which reproduces eq. (28) exactly when
  all contacts lie at the paper's common height ``z_w - r``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators import spatial
from estimators.tree import NumpyOps, TreeDynamics, TreeModel
from models.description import WHEEL_ORDER

__all__ = [
    "D_BETA_COEFFICIENTS",
    "PaperWrenches",
    "Selectors",
    "chain_base_wrench",
    "contact_points",
    "d_beta_row",
    "normal_force_system",
    "paper_wrenches",
    "select_system",
]

# Eq. (29) orders the unknowns FL, FR, RR, RL (eq. 27): [D-1, 1-D, -D, D] x = beta. By name,
# each wheel's coefficient is a*D + c; mapped here to the package order FL, RL, FR, RR.
_D_BETA_BY_NAME = {"FL": (1.0, -1.0), "FR": (-1.0, 1.0), "RR": (-1.0, 0.0), "RL": (1.0, 0.0)}
D_BETA_COEFFICIENTS = np.array([_D_BETA_BY_NAME[k] for k in WHEEL_ORDER])  # (4, 2): [a, c]


def d_beta_row(d):
    """The row of eq. (29) in the order FL, RL, FR, RR: coefficient ``a_k D + c_k``."""
    return [a * d + c for a, c in D_BETA_COEFFICIENTS]


@dataclass(frozen=True)
class Selectors:
    """Numeric choices that fix the linear system (Sec. III-B), for one state or for N.

    For one state (`select_system`) the fields are scalars and (4,) arrays; for N states
    (`select_systems`) they carry a leading axis N.

    Attributes:
        mode: ``d-beta``, ``cylinder-force``, ``3-contact`` or ``tipping``.
        mask: 1.0 for wheels in contact, else 0.0, shape (4,).
        height_weights: Weights of the contact heights in the residual-force height,
            shape (4,), summing to 1.
        s_dbeta: 1.0 when the fourth row is the D-beta row.
        s_cylinder: 1.0 when the fourth row comes from the bogie balances.
        lost: One-hot of the wheel that lost contact (3-contact mode), shape (4,).
        tipping: Fewer than three wheels in contact.
    """

    mode: str | np.ndarray
    mask: np.ndarray
    height_weights: np.ndarray
    s_dbeta: float | np.ndarray
    s_cylinder: float | np.ndarray
    lost: np.ndarray
    tipping: bool | np.ndarray

    def rows(self, sl: slice) -> Selectors:
        """The selectors of the states ``sl`` of a batch."""
        return Selectors(self.mode[sl], self.mask[sl], self.height_weights[sl],
                         self.s_dbeta[sl], self.s_cylinder[sl], self.lost[sl], self.tipping[sl])

    def row(self, i: int) -> Selectors:
        """The selectors of state ``i`` of a batch."""
        return Selectors(str(self.mode[i]), self.mask[i], self.height_weights[i],
                         float(self.s_dbeta[i]), float(self.s_cylinder[i]), self.lost[i],
                         bool(self.tipping[i]))


def select_systems(in_contact, fourth: str, has_cylinder_force: bool) -> Selectors:
    """Choose the system of each state from its contact flags and the fourth-row option.

    The one place the contact mode is decided: four wheels give the fourth row (eq. 29 or
    the bogie balances), three the 3-contact system with the lost wheel's column dropped,
    fewer the tipping least-squares (Sec. III-B).

    Args:
        in_contact: Contact flags, shape (N, 4) (or (4,)), order FL, RL, FR, RR.
        fourth: ``d-beta`` or ``cylinder-force``.
        has_cylinder_force: Whether the states carry the suspension cylinder forces;
            without them ``cylinder-force`` falls back to ``d-beta``.

    Returns:
        `Selectors` with a leading axis N.
    """
    c = np.asarray(in_contact, bool).reshape(-1, 4)
    mask = c.astype(float)
    nc = c.sum(axis=1)
    hw = np.where(nc[:, None] > 0, mask / np.maximum(nc, 1)[:, None], 0.25)
    cyl = fourth == "cylinder-force" and has_cylinder_force
    four = nc == 4
    lost = (~c & (nc == 3)[:, None]).astype(float)
    mode = np.where(four, "cylinder-force" if cyl else "d-beta",
                    np.where(nc == 3, "3-contact", "tipping"))
    return Selectors(mode, mask, hw, (four & (not cyl)).astype(float),
                     (four & cyl).astype(float), lost, nc < 3)


def select_system(in_contact, fourth: str, has_cylinder_force: bool) -> Selectors:
    """`select_systems` for one state: scalars and (4,) arrays."""
    return select_systems(in_contact, fourth, has_cylinder_force).row(0)


def contact_points(ops, tree: TreeModel, dyn: TreeDynamics, rotation_world_fb):
    """Lowest point of each wheel in fb [m]: 4 vectors, order FL, RL, FR, RR.

    A sphere wheel touches flat ground straight below its centre; a disc wheel at the rim
    point furthest along gravity. Both follow the actual bogie angles (beyond eq. 21).
    """
    down = -(rotation_world_fb.T @ ops.const([0.0, 0.0, 1.0]))
    out = []
    for w, axis in zip(tree.wheels, tree.wheel_axes):
        d = down
        if not tree.wheel_is_sphere:
            s = dyn.rotation_fb[w] @ ops.const(axis)
            d = down - s * ops.dot(down, s)
            d = d / ops.norm_2(d)
        out.append(dyn.position_fb[w] + tree.wheel_radius * d)
    return out


def _vec3_entries(ops, v):
    return ops.entry(v, 0), ops.entry(v, 1), ops.entry(v, 2)


def normal_force_system(ops, tree: TreeModel, dyn: TreeDynamics, rotation_world_fb,
                        points_measured, use_measured, force_in_fb, mask, height_weights,
                        s_dbeta, s_cylinder, lost, d, beta, suspension_force) -> dict:
    """Assemble and solve the normal-force system, eqs. (19)-(29), for one state.

    Args:
        ops: Array backend.
        tree: The tree.
        dyn: Its recursion result for the state.
        rotation_world_fb: Base orientation, (3, 3).
        points_measured: Measured contact points in fb, 4 vectors [m].
        use_measured: 1.0 to use the measured point of a wheel, 0.0 for its lowest point (4).
        force_in_fb: Measured ground force per wheel in fb, 4 vectors [N]; only its fb x-y
            part (the friction F_a) is used.
        mask: Contact mask (4), from `select_system`.
        height_weights: Weights of the residual-force height (4), from `select_system`.
        s_dbeta: 1.0 when the fourth row is eq. (29).
        s_cylinder: 1.0 when the fourth row comes from the bogie balances.
        lost: One-hot of the wheel out of contact in 3-contact mode (4).
        d: Parameter D of eq. (29) [-].
        beta: Parameter beta of eq. (29) [N].
        suspension_force: Cylinder forces (L, R) [N] (used when ``s_cylinder`` is 1).

    Returns:
        Dict with ``x`` (normal forces f_z, order FL, RL, FR, RR) [N], ``A`` (3x4), ``b``
        (3,), ``xi`` (F_Xi, eq. 20), ``M`` (4x4 system), ``cond`` (1-norm condition number),
        ``points`` (4 contact points used) and the bogie rows ``C`` (2x4), ``dc`` (2,).
    """
    bottoms = contact_points(ops, tree, dyn, rotation_world_fb)
    points = [u * pm + (1 - u) * pb for u, pm, pb in zip(
        [use_measured[k] for k in range(4)], points_measured, bottoms)]
    ez = ops.const([0.0, 0.0, 1.0])
    fa = [f - ez * ops.dot(f, ez) for f in force_in_fb]  # friction F_a: fb x-y part
    # Eq. (19)-(20): friction wrenches carried from the contact frames (aligned with fb) to fb.
    xi = dyn.base_wrench
    for p, f in zip(points, fa):
        xi = xi - ops.vcat([f, ops.cross(p, f)])
    xs, ys, zs = zip(*[_vec3_entries(ops, p) for p in points])
    h = sum(height_weights[k] * zs[k] for k in range(4))
    m = [mask[k] for k in range(4)]
    # Eqs. (25)-(28), generalised to the actual contact points.
    a = ops.rows([[m[k] for k in range(4)],
                  [m[k] * ys[k] for k in range(4)],
                  [-m[k] * xs[k] for k in range(4)]])
    xi1, xi2, xi3, xi4, xi5 = (ops.entry(xi, i) for i in range(5))
    b = ops.vcat([xi3, xi4 + h * xi2, xi5 - h * xi1])
    # Null vector of A from its 3x3 minors: the one direction eqs. (25)-(28) leave free.
    cols = [ops.col(a, j) for j in range(4)]
    nvec = ops.vcat([(-1) ** j * ops.det3(ops.hcat([cols[i] for i in range(4) if i != j]))
                     for j in range(4)])
    # Bogie pitch balances (cylinder-force mode): the chain's generalised force equation
    # J_x^T (tau_tree - tau_contact) = F_cyl, with tau_contact the ground forces' moment
    # about the bogie axis; one row in the two normal forces of that bogie. Tangential forces
    # not explained by the measured friction are left out here: how they split between the
    # bogies is unknown.
    crow, drow = [], []
    for j, ci in enumerate(tree.suspension):
        c = tree.chains[ci]
        k1, k2 = dyn.k1[ci], dyn.k2[ci]
        joints = ((c.driven, k1), (c.barrel, k2), (c.piston, 1.0))
        gen = 0.0
        for bi, jac in joints:
            body = tree.bodies[bi]
            # MuJoCo-style armature and damping act on the joints, not through the base.
            gen = gen + jac * (dyn.joint_force[bi] + body.armature * dyn.qdd[bi]
                               + body.damping * dyn.qd[bi])
        o = dyn.position_fb[c.driven]
        axis = dyn.rotation_fb[c.driven] @ ops.const(tree.bodies[c.driven].axis)
        row = [0.0] * 4
        rhs = gen - suspension_force[j]
        for k in tree.side_wheels[j]:
            arm = points[k] - o
            row[k] = m[k] * k1 * ops.dot(axis, ops.cross(arm, ez))
            rhs = rhs - k1 * ops.dot(axis, ops.cross(arm, fa[k]))
        crow.append(row)
        drow.append(rhs)
    cmat = ops.rows(crow)
    dvec = ops.vcat(drow)
    cn = cmat @ nvec
    r_cyl = cmat.T @ cn
    rhs_cyl = ops.dot(cn, dvec)
    # |r_cyl|, with a floor inside the root: in 3-contact and tipping modes r_cyl is 0 and
    # the derivative of a bare sqrt there is inf (inf * 0 = NaN in every d/dq column of the
    # bogie strokes, although s_cylinder = 0 drops the row). The floor changes no value.
    scale = ops.sqrt(ops.dot(r_cyl, r_cyl) + 1e-300)
    r_db = d_beta_row(d)
    row4 = [s_dbeta * r_db[k] + s_cylinder * ops.entry(r_cyl, k) / scale + lost[k]
            for k in range(4)]
    rhs4 = s_dbeta * beta + s_cylinder * rhs_cyl / scale
    mmat = ops.vstack([a, ops.rows([row4])])
    minv = ops.inv(mmat)
    x = minv @ ops.vcat([b, rhs4])
    cond = ops.norm_1(mmat) * ops.norm_1(minv)
    return dict(x=x, A=a, b=b, xi=xi, M=mmat, cond=cond, points=points, C=cmat, dc=dvec,
                null=nvec)


# ---------------------------------------------------------------------- paper breakdown
@dataclass(frozen=True)
class PaperWrenches:
    """The groups of eq. (18) for one state (numpy).

    Attributes:
        crane_in_m: ``F_m`` (eq. 14) in the manipulator base frame m [N, N m], (6,).
        transform_fb_to_m: Pose of m in fb, (4, 4).
        suspension_in_fb: ``F_B`` (eq. 15): chassis, bogies, cylinders and pistons, (6,).
        wheels_local: ``F_w*`` of each wheel in its own frame (eq. 16), (4, 6).
        transform_fb_to_wheels: Pose of each wheel frame in fb, (4, 4, 4).
        total_in_fb: ``Ad* F_m + F_B + sum Ad* F_w*``: the whole machine's wrench, (6,).
    """

    crane_in_m: np.ndarray
    transform_fb_to_m: np.ndarray
    suspension_in_fb: np.ndarray
    wheels_local: np.ndarray
    transform_fb_to_wheels: np.ndarray
    total_in_fb: np.ndarray


def _pose(dyn: TreeDynamics, i: int) -> np.ndarray:
    return spatial.se3(dyn.rotation_fb[i], dyn.position_fb[i])


def paper_wrenches(tree: TreeModel, dyn: TreeDynamics) -> PaperWrenches:
    """Group the body wrenches as eqs. (14), (15) and (16)-(17) do (numpy only)."""
    t_fb_m = tree.transform_fb_to_m
    t_m_fb = spatial.se3_inverse(t_fb_m)
    f_m = np.zeros(6)
    f_b = np.zeros(6)
    for i, body in enumerate(tree.bodies):
        if body.group == "crane":  # eq. (14): F_m = sum Ad*_{G_i^m} F_i
            f_m += spatial.coadjoint(t_m_fb @ _pose(dyn, i)) @ dyn.wrench[i]
        elif body.group == "suspension":  # eq. (15)
            f_b += spatial.coadjoint(_pose(dyn, i)) @ dyn.wrench[i]
    wheels = np.array([dyn.wrench[w] for w in tree.wheels])
    poses = np.array([_pose(dyn, w) for w in tree.wheels])
    total = spatial.coadjoint(t_fb_m) @ f_m + f_b  # eq. (18) without the ground
    for t, f in zip(poses, wheels):
        total = total + spatial.coadjoint(t) @ f
    return PaperWrenches(f_m, t_fb_m, f_b, wheels, poses, total)


def chain_base_wrench(tree: TreeModel, dyn: TreeDynamics, chain: str,
                      alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Theorem 1 on one cylinder chain, with distribution factors ``(alpha, 1 - alpha)``.

    The wrench ``F_E`` that the successors of the driven link exert (its subtree minus
    itself) is split: ``eta_1 = alpha F_E`` goes down the driven link (first serial chain,
    eqs. 9), ``eta_2 = (1 - alpha) F_E`` through the rod eye into the piston and the barrel
    (second chain, eqs. 10), eq. (12). Both are summed in the chain base frame Bc.

    Args:
        tree: The tree.
        dyn: Its recursion result (numpy).
        chain: Chain name (``lift``, ``bogie_L``, ...).
        alpha: Distribution factor alpha_1 (any real; eq. 12 asks for [0, 1]).

    Returns:
        ``(total_in_bc, driven_joint_wrench)``: the chain's total wrench in Bc, which
        Theorem 1 says does not depend on ``alpha``, and the wrench through the driven joint
        (in the driven body's frame), which does.
    """
    c = next(ch for ch in tree.chains if ch.name == chain)
    bc = tree.bodies[c.driven].parent
    t_fb_bc = _pose(dyn, bc)
    t_bc_fb = spatial.se3_inverse(t_fb_bc)
    t_drv = _pose(dyn, c.driven)
    f_e = dyn.subtree_wrench[c.driven] - dyn.wrench[c.driven]  # successors' wrench, in B1
    eta1, eta2 = alpha * f_e, (1.0 - alpha) * f_e  # eq. (12)
    first = dyn.wrench[c.driven] + eta1
    t_pis = _pose(dyn, c.piston)
    # eta_2 enters the piston at the closure point; carried as a wrench it is frame-free.
    piston = dyn.wrench[c.piston] + spatial.coadjoint(spatial.se3_inverse(t_pis) @ t_drv) @ eta2
    t_bar = _pose(dyn, c.barrel)
    barrel = dyn.wrench[c.barrel] + spatial.coadjoint(spatial.se3_inverse(t_bar) @ t_pis) @ piston
    total = (dyn.wrench[bc]  # F*_Bc of the proof
             + spatial.coadjoint(t_bc_fb @ t_drv) @ first
             + spatial.coadjoint(t_bc_fb @ t_bar) @ barrel)
    return total, first


def evaluate(tree: TreeModel, rotation_world_fb, twist, acceleration, q, qd, qdd,
             points_measured, use_measured, force_in_fb, selectors: Selectors, d: float,
             beta: float, suspension_force, payload_mass: float | None = None
             ) -> tuple[TreeDynamics, dict]:
    """The whole pipeline for one state in numpy (the paper-faithful reference path).

    ``payload_mass`` [kg]: None, the description's (`TreeModel.dynamics`).
    """
    ops = NumpyOps
    dyn = tree.dynamics(ops, np.asarray(rotation_world_fb, float), np.asarray(twist, float),
                        np.asarray(acceleration, float), q, qd, qdd,
                        payload_mass=payload_mass)
    out = normal_force_system(
        ops, tree, dyn, np.asarray(rotation_world_fb, float), list(points_measured),
        use_measured, list(force_in_fb), selectors.mask, selectors.height_weights,
        selectors.s_dbeta, selectors.s_cylinder, selectors.lost, d, beta, suspension_force)
    return dyn, out
