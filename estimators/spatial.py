"""Screw-theory core on SE(3), se(3) and se*(3) (paper Sec. II, refs. [4], [5]).

Conventions used by the whole package:

* A twist is ``nu = [v; w]`` (linear first, as in the paper and in Pinocchio), shape (6,),
  [m/s, rad/s]; a spatial acceleration ``nu_dot`` is its time derivative in the same frame.
* A wrench is ``F = [f; m]``, shape (6,), [N, N m]. The pairing ``<F, nu> = F @ nu`` is the
  power [W].
* A pose ``T_ab`` (4x4 homogeneous matrix) is the pose of frame b in frame a:
  ``p_a = R_ab p_b + p_ab``.
* ``adjoint(T_ab)`` maps a twist in b to the same twist in a; ``coadjoint(T_ab)`` maps a wrench
  in b to the same wrench in a. ``coadjoint(T) = adjoint(T)^-T``, so the power is frame
  invariant.

Mapping to the paper's notation: the paper's ``G_A^B`` is the pose of B in A (``T_AB``);
``Ad_{G_A^B}`` (eq. 9) is ``adjoint(T_AB)`` and ``Ad*_{G_A^B}`` (eq. 13), which carries a
wrench from A to B, is ``adjoint(T_AB).T = coadjoint(T_BA)``.

The dual Lie-bracket ``ad_star(nu) = -ad(nu).T`` is the coadjoint representation of se(3) on
se*(3) (Featherstone's ``v x*``). The paper's eq. (11), ``F = M nu_dot - ad*_nu(M nu)``, uses
the other common convention ``ad*_nu = ad(nu).T``; both give the same Newton-Euler wrench
``F = M nu_dot - ad(nu).T M nu = M nu_dot + ad_star(nu) M nu``.

Gravity is handled as a *base acceleration offset*: a uniform field ``g`` acts on every body
exactly like an upward acceleration of the inertial frame, so the base spatial acceleration
is offset by ``[R_world_fb^T (g e_z); 0]`` (`gravity_offset`) and the recursion (eq. 9c, 10d-f)
carries it to every body, where ``M nu_dot`` then includes the body's weight. Pinocchio does
the same (``a_0 = -gravity``).
"""

from __future__ import annotations

import numpy as np

from models.description import Inertia
from models.rotations import se3, se3_inverse, skew

__all__ = [
    "ad",
    "ad_star",
    "adjoint",
    "coadjoint",
    "euler_poincare_wrench",
    "gravity_offset",
    "gravity_wrench",
    "se3",
    "se3_inverse",
    "skew",
    "spatial_inertia",
    "twist_hat",
]


def twist_hat(nu) -> np.ndarray:
    """4x4 matrix of a twist ``[v; w]`` in se(3); ``expm(twist_hat(nu))`` is in SE(3)."""
    out = np.zeros((4, 4))
    out[:3, :3] = skew(nu[3:])
    out[:3, 3] = nu[:3]
    return out


def adjoint(t: np.ndarray) -> np.ndarray:
    """Adjoint ``Ad_T`` (6, 6): twist in frame b -> the same twist in frame a (``T = T_ab``).

    ``v_a = R v_b + p x (R w_b)``, ``w_a = R w_b``.
    """
    r, p = t[:3, :3], t[:3, 3]
    out = np.zeros((6, 6))
    out[:3, :3] = r
    out[:3, 3:] = skew(p) @ r
    out[3:, 3:] = r
    return out


def coadjoint(t: np.ndarray) -> np.ndarray:
    """Coadjoint (6, 6): wrench in frame b -> the same wrench in frame a (``T = T_ab``).

    ``f_a = R f_b``, ``m_a = p x (R f_b) + R m_b``; equals ``adjoint(T)^-T`` and the paper's
    ``Ad*_{G_b^a}`` (eq. 13).
    """
    r, p = t[:3, :3], t[:3, 3]
    out = np.zeros((6, 6))
    out[:3, :3] = r
    out[3:, :3] = skew(p) @ r
    out[3:, 3:] = r
    return out


def ad(nu) -> np.ndarray:
    """Lie bracket matrix ``ad_nu`` (6, 6) with ``ad_nu x = [nu, x]`` (eqs. 9c, 10d-f)."""
    nu = np.asarray(nu, float)
    out = np.zeros((6, 6))
    w = skew(nu[3:])
    out[:3, :3] = w
    out[:3, 3:] = skew(nu[:3])
    out[3:, 3:] = w
    return out


def ad_star(nu) -> np.ndarray:
    """Dual Lie bracket on se*(3): ``ad_star(nu) = -ad(nu).T``, shape (6, 6).

    ``<ad_star(nu) F, x> = -<F, ad(nu) x>``; the derivative of ``coadjoint(exp(t nu))`` at 0.
    """
    nu = np.asarray(nu, float)
    out = np.zeros((6, 6))
    w = skew(nu[3:])
    out[:3, :3] = w
    out[3:, :3] = skew(nu[:3])
    out[3:, 3:] = w
    return out


def spatial_inertia(inertia: Inertia) -> np.ndarray:
    """Spatial inertia ``M`` (6, 6) about the body origin, twist order [v; w].

    ``M = [[m I, -m [c]], [m [c], I_c - m [c][c]]]`` with the centre of mass ``c`` and the
    rotational inertia ``I_c`` about it [kg, kg m, kg m^2]. Symmetric positive definite.
    """
    m = inertia.mass
    c = skew(inertia.com)
    out = np.zeros((6, 6))
    out[:3, :3] = m * np.eye(3)
    out[:3, 3:] = -m * c
    out[3:, :3] = m * c
    out[3:, 3:] = inertia.inertia - m * c @ c
    return out


def euler_poincare_wrench(m: np.ndarray, nu, nu_dot) -> np.ndarray:
    """Wrench on a rigid body from its motion, eq. (11): ``F = M nu_dot + ad_star(nu) M nu``.

    Args:
        m: Spatial inertia in the body frame, shape (6, 6).
        nu: Body twist in the body frame [m/s, rad/s], shape (6,).
        nu_dot: Its time derivative [m/s^2, rad/s^2], shape (6,); add the gravity offset
            (`gravity_offset` carried to this body) to include the weight.

    Returns:
        The wrench that must act on the body, in its frame [N, N m], shape (6,).
    """
    return m @ nu_dot + ad_star(nu) @ (m @ nu)


def gravity_offset(rotation_world_to_fb, gravity: float) -> np.ndarray:
    """Base acceleration offset that accounts for gravity, shape (6,).

    Args:
        rotation_world_to_fb: Rotation world <- fb (the base orientation), shape (3, 3).
        gravity: [m/s^2], along world -z.

    Returns:
        ``[R^T (0, 0, g); 0]``: the upward acceleration of the inertial frame, in fb.
    """
    return np.concatenate([np.asarray(rotation_world_to_fb).T @ np.array([0.0, 0.0, gravity]),
                           np.zeros(3)])


def gravity_wrench(m: np.ndarray, rotation_world_to_body, gravity: float) -> np.ndarray:
    """Weight of a body as a wrench in its own frame [N, N m], shape (6,).

    Equals ``-M @ [R^T (0, 0, g); 0]``: the alternative, per-body way of adding gravity.
    """
    return -m @ gravity_offset(rotation_world_to_body, gravity)
