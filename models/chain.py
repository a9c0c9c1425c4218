"""Kinematics of the cylinder-actuated four-bar chain (paper Sec. II-A, eqs. 2-8).

The chain lives in a plane with normal ``n`` (the common axis of its three revolute joints).
Plane coordinates are 2-D vectors ``(a, b)`` measured from the driven joint ``O``:

* ``O``: the driven revolute joint between the base link and the driven link,
* ``C``: the cylinder's base pivot, fixed in the base link,
* ``E``: the rod eye, fixed in the driven link (given at driven angle 0),
* the cylinder barrel turns about ``C``; the piston slides along it by the stroke ``x``.

The pin-to-pin cylinder length is ``L_x = L_c0 + x + L_c``. With ``L_a = |C|`` and
``L_b = |E|``, the triangle (O, C, E) has exterior angles ``q`` (at O), ``q1`` (at C) and
``q2`` (at E): the negated interior angles, each in ``(-pi, 0)``, so ``q + q1 + q2 = -pi``
(eqs. 2-4). Eq. (2) as printed uses ``L_x`` where the law of cosines needs ``L_x**2``; we use
the square (paper erratum).

Joint angles follow eq. (5): ``theta = psi + sigma * q`` for the driven joint and
``theta_b = psi_b - sigma * q1`` for the barrel, with constant offsets ``psi`` and one sign
``sigma = +-1`` fixed by the triangle's orientation about ``n``. The paper takes ``sigma = +1``
by choosing its axis directions; keeping ``sigma`` lets any axis convention be used. The
rod-eye angle (piston relative to the driven link) is ``theta_b - theta``.
The derivatives are ``k1 = d theta / dx``, ``k2 = d theta_b / dx`` and
``k3 = d(theta_b - theta)/dx = sigma dq2/dx`` (eqs. 6-8), and their time derivatives
``k_dot = (dk/dx) * x_dot``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from models.errors import JointOutOfRangeError, ModelError, StrokeOutOfRangeError

_SINGULAR_MARGIN = 1e-6  # [m] keep away from the collinear (singular) triangles


@dataclass(frozen=True)
class ChainState:
    """Configuration of one closed chain at a given stroke.

    Attributes:
        stroke: Cylinder stroke x [m].
        length: Pin-to-pin length L_x [m].
        q: Exterior angle at the driven joint [rad], eq. (2).
        q1: Exterior angle at the cylinder base pivot [rad], eq. (3).
        q2: Exterior angle at the rod eye [rad], eq. (4).
        theta: Driven joint angle [rad], eq. (5).
        theta_barrel: Barrel joint angle [rad], eq. (5).
        k: (k1, k2, k3) [rad/m], eqs. (6)-(8).
        dk_dx: Derivatives of (k1, k2, k3) with respect to x [rad/m^2].
    """

    stroke: float
    length: float
    q: float
    q1: float
    q2: float
    theta: float
    theta_barrel: float
    k: tuple[float, float, float]
    dk_dx: tuple[float, float, float]


@dataclass(frozen=True)
class CylinderChain:
    """One cylinder-actuated four-bar chain, generic for every cylinder of the machine.

    Args:
        name: Chain name, used in error messages.
        base_pivot: C, the cylinder base pivot in plane coordinates of the base link [m].
        rod_eye: E, the rod eye in plane coordinates of the driven link at angle 0 [m].
        dead_length: L_c0, pivot to piston face at zero stroke [m].
        rod_length: L_c, piston face to rod eye [m].
        stroke_max: Usable stroke [m]; the chain admits ``[0, stroke_max]`` intersected with
            the strokes the triangle can close at.
    """

    name: str
    base_pivot: tuple[float, float]
    rod_eye: tuple[float, float]
    dead_length: float
    rod_length: float
    stroke_max: float
    _consts: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        c = np.asarray(self.base_pivot, float)
        e = np.asarray(self.rod_eye, float)
        la, lb = float(np.linalg.norm(c)), float(np.linalg.norm(e))
        if la <= 0 or lb <= 0:
            raise ModelError(f"chain '{self.name}': pivots must not coincide with the joint")
        lx0 = self.dead_length + self.rod_length
        lo = max(0.0, abs(la - lb) + _SINGULAR_MARGIN - lx0)
        hi = min(self.stroke_max, la + lb - _SINGULAR_MARGIN - lx0)
        if not hi > lo:
            raise ModelError(f"chain '{self.name}': no stroke closes the triangle")
        # Orientation of the triangle O -> C -> E about the plane normal fixes sigma.
        phi_c = math.atan2(c[1], c[0])
        phi_e = math.atan2(e[1], e[0])
        cross = c[0] * e[1] - c[1] * e[0]
        orient = 1.0 if cross >= 0 else -1.0  # +1: E lies counter-clockwise of C
        consts = dict(la=la, lb=lb, lx0=lx0, lo=lo, hi=hi, phi_c=phi_c, phi_e=phi_e,
                      orient=orient, psi=phi_c - phi_e, psi_b=phi_c + math.pi)
        object.__setattr__(self, "_consts", consts)
        # Offsets psi of eq. (5), shifted by whole turns so that angles at mid-stroke lie
        # in (-pi, pi]: the angle stays continuous over the whole stroke range.
        s_mid = self.state(0.5 * (lo + hi), check=False)
        consts["psi"] -= s_mid.theta - math.remainder(s_mid.theta, 2 * math.pi)
        consts["psi_b"] -= s_mid.theta_barrel - math.remainder(s_mid.theta_barrel, 2 * math.pi)

    # ------------------------------------------------------------------ ranges
    @property
    def stroke_range(self) -> tuple[float, float]:
        """Valid stroke interval [m]: the cylinder's and the triangle's, intersected."""
        return self._consts["lo"], self._consts["hi"]

    @property
    def side_lengths(self) -> tuple[float, float]:
        """(L_a, L_b): joint-to-base-pivot and joint-to-rod-eye distances [m]."""
        return self._consts["la"], self._consts["lb"]

    @property
    def angle_range(self) -> tuple[float, float]:
        """Driven joint angle interval [rad] reached over the valid stroke range."""
        lo, hi = self.stroke_range
        a, b = self.joint_angle(lo), self.joint_angle(hi)
        return (min(a, b), max(a, b))

    def check_stroke(self, x: float) -> None:
        """Raise `StrokeOutOfRangeError` if ``x`` is outside the valid stroke range."""
        lo, hi = self.stroke_range
        if not (math.isfinite(x) and lo - 1e-12 <= x <= hi + 1e-12):
            raise StrokeOutOfRangeError(self.name, float(x), lo, hi)

    # ------------------------------------------------------------------ eqs. (2)-(8)
    def _cosines(self, lx: float):
        """Cosines of q, q1, q2 and their first and second derivatives in x."""
        k = self._consts
        la, lb = k["la"], k["lb"]
        # Law of cosines; eq. (2) with L_x squared (erratum).
        c = (la * la + lb * lb - lx * lx) / (2 * la * lb)
        c1 = (la * la + lx * lx - lb * lb) / (2 * la * lx)
        c2 = (lb * lb + lx * lx - la * la) / (2 * lb * lx)
        d = (-lx / (la * lb),
             -(la * la - lb * lb) / (2 * la * lx * lx) + 1 / (2 * la),
             -(lb * lb - la * la) / (2 * lb * lx * lx) + 1 / (2 * lb))
        dd = (-1 / (la * lb),
              (la * la - lb * lb) / (la * lx ** 3),
              (lb * lb - la * la) / (lb * lx ** 3))
        return (c, c1, c2), d, dd

    def _angles(self, lx: float, n: int) -> tuple[list, list, list]:
        """(q's, dq/dx's, d2q/dx2's) of the first ``n`` exterior angles q, q1, q2 at ``lx``."""
        cs, dcs, ddcs = self._cosines(lx)
        qs, dqs, ddqs = [], [], []
        for c, dc, ddc in zip(cs[:n], dcs[:n], ddcs[:n]):
            q = -math.acos(min(max(c, -1.0), 1.0))  # eqs. (2)-(4): q = -interior angle
            s = math.sin(q)
            dq = -dc / s
            qs.append(q)
            dqs.append(dq)
            ddqs.append(-(ddc + math.cos(q) * dq * dq) / s)
        return qs, dqs, ddqs

    def state(self, x: float, check: bool = True) -> ChainState:
        """Chain configuration and k-coefficients at stroke ``x`` [m]."""
        if check:
            self.check_stroke(x)
        k = self._consts
        lx = k["lx0"] + x
        qs, dqs, ddqs = self._angles(lx, 3)
        q, q1, q2 = qs
        sigma = self.sigma
        # Eq. (5): theta = psi + sigma q, barrel = psi_b - sigma q1, and the rod-eye angle
        # (piston relative to the driven link) = barrel - theta, whose rate is sigma * q2_dot.
        theta = k["psi"] + sigma * q
        theta_b = k["psi_b"] - sigma * q1
        kk = (sigma * dqs[0], -sigma * dqs[1], sigma * dqs[2])
        dk = (sigma * ddqs[0], -sigma * ddqs[1], sigma * ddqs[2])
        return ChainState(stroke=float(x), length=lx, q=q, q1=q1, q2=q2, theta=theta,
                          theta_barrel=theta_b, k=kk, dk_dx=dk)

    def float_state(self, x: float, check: bool = True) -> ChainState:
        """`state` at ``x`` computed on a Python float (a hot path; ``x`` a float or numpy's).

        The same IEEE operations as on numpy's scalar, several times faster. Where the
        triangle is flat a float divides by zero where numpy's scalar gives inf (strokes far
        out of range, with ``check=False``): that case runs on numpy's scalar.
        """
        try:
            return self.state(float(x), check)
        except ZeroDivisionError:
            return self.state(np.float64(x), check)

    def driven_terms(self, x: float) -> tuple[float, float, float, float, float, float]:
        """``(theta, theta_barrel, k1, k2, dk1/dx, dk2/dx)`` at stroke ``x``, unchecked.

        `float_state`'s numbers (the same operations) without the rod eye's and the
        `ChainState`: what a tree's configuration and Jacobian need of the chain (a hot
        path: `estimators.efforts`).
        """
        try:
            return self._driven_terms(float(x))
        except ZeroDivisionError:
            return self._driven_terms(np.float64(x))

    def _driven_terms(self, x: float) -> tuple[float, float, float, float, float, float]:
        k = self._consts
        (q, q1), (dq, dq1), (ddq, ddq1) = self._angles(k["lx0"] + x, 2)
        sigma = self.sigma
        return (k["psi"] + sigma * q, k["psi_b"] - sigma * q1, sigma * dq, -sigma * dq1,
                sigma * ddq, -sigma * ddq1)

    def driven_rates(self, x: float) -> tuple[float, float]:
        """``(k1, k2)`` of `driven_terms` at stroke ``x``, unchecked, without the rest.

        The simulator's damping asks for these alone at every pose update
        (`models.mujoco.servos.DampingSchedule`): `_cosines`' first two cosines and
        derivatives and `_angles`' first derivatives, the same expressions, hence the same
        numbers (and the same division by zero, which runs on numpy's scalar).
        """
        try:
            return self._driven_rates(float(x))
        except ZeroDivisionError:
            return self._driven_rates(np.float64(x))

    def _driven_rates(self, x: float) -> tuple[float, float]:
        k = self._consts
        la, lb = k["la"], k["lb"]
        lx = k["lx0"] + x
        c = (la * la + lb * lb - lx * lx) / (2 * la * lb)
        c1 = (la * la + lx * lx - lb * lb) / (2 * la * lx)
        d = -lx / (la * lb)
        d1 = -(la * la - lb * lb) / (2 * la * lx * lx) + 1 / (2 * la)
        dq = -d / math.sin(-math.acos(min(max(c, -1.0), 1.0)))
        dq1 = -d1 / math.sin(-math.acos(min(max(c1, -1.0), 1.0)))
        sigma = self.sigma
        return sigma * dq, -sigma * dq1

    def angles(self, x: float, check: bool = True) -> tuple[float, float]:
        """(theta, theta_barrel) at stroke ``x`` [rad]: `state`'s two angles alone.

        The same operations as `state`, without the rates (a hot path: the tree's joint
        positions, `models.coordinates.TreeCoordinates.joint_positions`).
        """
        if check:
            self.check_stroke(x)
        k = self._consts
        la, lb = k["la"], k["lb"]
        lx = k["lx0"] + x
        c = (la * la + lb * lb - lx * lx) / (2 * la * lb)
        c1 = (la * la + lx * lx - lb * lb) / (2 * la * lx)
        q = -math.acos(min(max(c, -1.0), 1.0))
        q1 = -math.acos(min(max(c1, -1.0), 1.0))
        sigma = self.sigma
        return k["psi"] + sigma * q, k["psi_b"] - sigma * q1

    @property
    def sigma(self) -> float:
        """Sign of eq. (5) for the driven joint: +1 or -1, from the triangle's orientation."""
        return -self._consts["orient"]

    def driven_rate_coefficients(self, x: float) -> tuple[float, float]:
        """(k1, dk1/dx) at stroke ``x`` without the rest of `state` (a hot path) [rad/m]."""
        k = self._consts
        la, lb = k["la"], k["lb"]
        lx = k["lx0"] + x
        c = (la * la + lb * lb - lx * lx) / (2 * la * lb)
        q = -math.acos(min(max(c, -1.0), 1.0))
        s = math.sin(q)
        dq = lx / (la * lb * s)
        ddq = -(-1 / (la * lb) + math.cos(q) * dq * dq) / s
        sigma = self.sigma
        return sigma * dq, sigma * ddq

    def joint_angle(self, x: float) -> float:
        """Driven joint angle theta(x) [rad], eq. (5)."""
        return self.state(x, check=False).theta

    def stroke_from_angle(self, theta: float) -> float:
        """Inverse map: the stroke that puts the driven joint at ``theta`` [rad]."""
        k = self._consts
        lo_t, hi_t = self.angle_range
        if not (math.isfinite(theta) and lo_t - 1e-12 <= theta <= hi_t + 1e-12):
            raise JointOutOfRangeError(self.name, float(theta), lo_t, hi_t)
        gamma = -self.sigma * (theta - k["psi"])
        la, lb = k["la"], k["lb"]
        lx = math.sqrt(max(la * la + lb * lb - 2 * la * lb * math.cos(gamma), 0.0))
        x = lx - k["lx0"]
        lo, hi = self.stroke_range
        return float(min(max(x, lo), hi))

    def rates(self, x: float, xd: float, xdd: float) -> dict[str, float]:
        """Joint rates of the chain from cylinder rates, eqs. (6)-(8).

        Returns:
            Dictionary with ``theta, theta_d, theta_dd`` (driven joint),
            ``barrel, barrel_d, barrel_dd`` and ``q2_d, q2_dd`` [rad, rad/s, rad/s^2].
        """
        s = self.state(x)
        k1, k2, k3 = s.k
        kd1, kd2, kd3 = (d * xd for d in s.dk_dx)
        return dict(
            theta=s.theta, theta_d=k1 * xd, theta_dd=kd1 * xd + k1 * xdd,
            barrel=s.theta_barrel, barrel_d=k2 * xd, barrel_dd=kd2 * xd + k2 * xdd,
            q2_d=k3 * xd, q2_dd=kd3 * xd + k3 * xdd,
        )

    def rod_eye_from_driven(self, theta: float) -> np.ndarray:
        """Rod eye position in base plane coordinates for driven angle ``theta`` [m]."""
        c, s = math.cos(theta), math.sin(theta)
        e = self.rod_eye
        return np.array([c * e[0] - s * e[1], s * e[0] + c * e[1]])

    def rod_eye_from_barrel(self, theta_b: float, x: float) -> np.ndarray:
        """Rod eye position in base plane coordinates along the barrel [m]."""
        lx = self._consts["lx0"] + x
        return np.asarray(self.base_pivot) + lx * np.array([math.cos(theta_b),
                                                           math.sin(theta_b)])
