"""Closed-chain kinematics (eqs. 2-8) against finite differences and plain geometry."""

import math

import numpy as np
import pytest

from models import CylinderChain, JointOutOfRangeError, StrokeOutOfRangeError

H = 1e-6


def _chains(machine):
    return [b.chain for b in machine.chains.values()]


def test_rod_eye_closes_from_both_sides(machine):
    for chain in _chains(machine):
        for x in np.linspace(*chain.stroke_range, 7):
            s = chain.state(x)
            np.testing.assert_allclose(chain.rod_eye_from_driven(s.theta),
                                       chain.rod_eye_from_barrel(s.theta_barrel, x), atol=1e-12)


def test_law_of_cosines_and_angle_sum(machine):
    # Eq. (2) with L_x squared: the pin-to-pin length from the triangle equals L_c0 + x + L_c.
    for chain in _chains(machine):
        la, lb = chain.side_lengths
        for x in np.linspace(*chain.stroke_range, 5):
            s = chain.state(x)
            assert math.isclose(la * la + lb * lb - 2 * la * lb * math.cos(s.q),
                                s.length ** 2, rel_tol=1e-12)
            assert math.isclose(s.q + s.q1 + s.q2, -math.pi, abs_tol=1e-12)
            assert -math.pi < s.q < 0 and -math.pi < s.q1 < 0 and -math.pi < s.q2 < 0


def test_k_against_finite_differences(machine):
    for chain in _chains(machine):
        lo, hi = chain.stroke_range
        for x in np.linspace(lo + 0.01, hi - 0.01, 6):
            s, sp, sm = chain.state(x), chain.state(x + H), chain.state(x - H)
            fd = ((sp.theta - sm.theta) / (2 * H),
                  (sp.theta_barrel - sm.theta_barrel) / (2 * H),
                  ((sp.theta_barrel - sp.theta) - (sm.theta_barrel - sm.theta)) / (2 * H))
            np.testing.assert_allclose(s.k, fd, rtol=1e-6, atol=1e-7)
            fd_dk = [(a - b) / (2 * H) for a, b in zip(sp.k, sm.k)]
            np.testing.assert_allclose(s.dk_dx, fd_dk, rtol=1e-5, atol=1e-5)


def test_rates_match_time_finite_differences(machine):
    # theta_dd = k_dot x_dot + k x_dd (eq. 6) against a twice-differentiated trajectory.
    chain = machine.chains["lift"].chain
    x = lambda t: 0.3 + 0.1 * math.sin(2 * t)  # noqa: E731
    t, dt = 0.4, 1e-4
    r = chain.rates(x(t), 0.2 * math.cos(2 * t), -0.4 * math.sin(2 * t))
    th = [chain.joint_angle(x(t + k * dt)) for k in (-1, 0, 1)]
    assert math.isclose(r["theta_d"], (th[2] - th[0]) / (2 * dt), rel_tol=1e-6)
    assert math.isclose(r["theta_dd"], (th[2] - 2 * th[1] + th[0]) / dt ** 2, rel_tol=1e-4)


def test_inverse_map_round_trip(machine):
    for chain in _chains(machine):
        for x in np.linspace(*chain.stroke_range, 9):
            assert math.isclose(chain.stroke_from_angle(chain.joint_angle(x)), x, abs_tol=1e-9)


def test_published_lift_and_tilt_angles(machine):
    # XS031 figures (machine-facts s2.5): lift x1 = 0, 0.3, 0.5 -> -9.24, 38.0, 82.8 deg;
    # tilt x2 = 0, 0.5 -> -146.1, -32.4 deg (the tilt map is CAD-exact: within 0.1 deg).
    lift, tilt = machine.chains["lift"].chain, machine.chains["tilt"].chain
    for x, deg in ((0.0, -9.24), (0.3, 38.0), (0.5, 82.8)):
        assert abs(math.degrees(lift.joint_angle(x)) - deg) < 0.05
    for x, deg in ((0.0, -146.1), (0.5, -32.4)):
        assert abs(math.degrees(tilt.joint_angle(x)) - deg) < 0.1


def test_lift_stroke_cut_by_geometry(machine):
    # Flag F3: L1 + L11 - 0.83 = 0.5532 m < 0.59 m stroke.
    lo, hi = machine.chains["lift"].chain.stroke_range
    assert lo == 0.0 and 0.552 < hi < 0.5533


def test_out_of_range_raises_typed_error(machine):
    chain = machine.chains["lift"].chain
    with pytest.raises(StrokeOutOfRangeError, match=r"outside \[0, 0.5532.*'lift'"):
        chain.state(0.93)
    with pytest.raises(StrokeOutOfRangeError):
        chain.state(float("nan"))
    with pytest.raises(JointOutOfRangeError):
        chain.stroke_from_angle(math.radians(170))


def test_mirrored_chain_flips_sigma():
    a = CylinderChain("a", (0.55, 0.15), (0.0, -0.35), 0.1, 0.52, 0.22)
    b = CylinderChain("b", (0.55, -0.15), (0.0, 0.35), 0.1, 0.52, 0.22)
    assert a.sigma == -b.sigma
    for x in (0.05, 0.15):
        assert math.isclose(a.joint_angle(x), -b.joint_angle(x), abs_tol=1e-12)


def test_driven_rate_coefficients_match_state(machine):
    for chain in _chains(machine):
        for x in np.linspace(*chain.stroke_range, 5)[1:-1]:
            s = chain.state(x)
            np.testing.assert_allclose(chain.driven_rate_coefficients(x),
                                       (s.k[0], s.dk_dx[0]), rtol=1e-12)
