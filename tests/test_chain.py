"""Closed-chain kinematics (eqs. 2-8) against finite differences and plain geometry."""

import math

import numpy as np
import pytest

from models import CylinderChain, JointOutOfRangeError, ModelError, StrokeOutOfRangeError
from models.reference_machine import LIFT_STROKE_END, build_reference_machine

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


@pytest.fixture(scope="module")
def published_lift():
    """The lift chain with the published 0.59 m stroke (no end stop: to the dead centre)."""
    return build_reference_machine(lift_stroke_end=0.59).chains["lift"].chain


def test_published_lift_and_tilt_angles(machine, published_lift):
    # XS031 figures (machine-facts s2.5): lift x1 = 0, 0.3, 0.5 -> -9.24, 38.0, 82.8 deg;
    # tilt x2 = 0, 0.5 -> -146.1, -32.4 deg (the tilt map is CAD-exact: within 0.1 deg).
    # The published stroke (0.59 m), not the machine's end stop at 0.49 m.
    lift = published_lift
    tilt = machine.chains["tilt"].chain
    for x, deg in ((0.0, -9.24), (0.3, 38.0), (0.5, 82.8)):
        assert abs(math.degrees(lift.joint_angle(x)) - deg) < 0.05
    for x, deg in ((0.0, -146.1), (0.5, -32.4)):
        assert abs(math.degrees(tilt.joint_angle(x)) - deg) < 0.1


def test_lift_stroke_ends_short_of_dead_centre(machine, published_lift):
    lift = machine.chains["lift"].chain
    assert lift.stroke_range == (0.0, LIFT_STROKE_END)
    # Flag F3: the published 0.59 m stroke is cut by the triangle at its dead centre,
    # L1 + L11 - 0.83 = 0.5532 m.
    published = published_lift
    assert 0.552 < published.stroke_range[1] < 0.5533

    def gain(x, h=1e-6):  # d theta / dx [rad/m]
        return (published.joint_angle(x + h) - published.joint_angle(x - h)) / (2 * h)

    # The stop keeps the linkage gain within about twice its smallest value; the dead
    # centre's is unbounded (ten times the smallest 0.4 mm short of it).
    smallest = min(gain(x) for x in np.linspace(0.01, LIFT_STROKE_END, 50))
    assert gain(LIFT_STROKE_END) < 2.1 * smallest
    assert gain(published.stroke_range[1] - 4e-4) > 10 * smallest


@pytest.mark.parametrize("end", [0.3, 0.6, float("nan"), True, "0.49"])
def test_lift_stroke_end_out_of_range_is_a_typed_error(end):
    with pytest.raises(ModelError, match=r"lift_stroke_end must be a number in \(0.3, 0.59\]"):
        build_reference_machine(lift_stroke_end=end)


def test_out_of_range_raises_typed_error(machine):
    chain = machine.chains["lift"].chain
    with pytest.raises(StrokeOutOfRangeError, match=r"outside \[0, 0.49\].*'lift'"):
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


def test_angles_are_the_state_angles(machine):
    # `angles` is `state`'s two angles alone (the tree's joint positions use it): the same
    # numbers to the bit over the whole range, ends included, and the same range check.
    for chain in _chains(machine):
        lo, hi = chain.stroke_range
        for x in [lo, hi, *np.linspace(lo, hi, 23)[1:-1]]:
            s = chain.state(x)
            assert chain.angles(float(x)) == (s.theta, s.theta_barrel)
        with pytest.raises(StrokeOutOfRangeError):
            chain.angles(hi + 1e-3)


def test_float_state_is_state(machine):
    # The hot paths' `float_state` gives `state`'s numbers to the bit, and far out of range
    # (check off), where a Python float divides by zero, numpy scalar's inf and nan as before.
    for chain in _chains(machine):
        lo, hi = chain.stroke_range
        for x in [*np.linspace(lo, hi, 9), hi + 10.0, lo - 10.0]:
            with np.errstate(all="ignore"):
                want = chain.state(np.float64(x), check=False)
                got = chain.float_state(x, check=False)
            np.testing.assert_array_equal([got.theta, got.theta_barrel, *got.k, *got.dk_dx],
                                          [want.theta, want.theta_barrel, *want.k, *want.dk_dx])
        with pytest.raises(StrokeOutOfRangeError):
            chain.float_state(hi + 1e-3)


def test_driven_terms_are_the_states_numbers_to_the_bit(machine):
    """`CylinderChain.driven_terms` (the effort model's hot path) against `float_state`."""
    for chain in _chains(machine):
        lo, hi = chain.stroke_range
        for x in np.r_[np.linspace(lo, hi, 9), lo - 1e-3, hi + 1e-3]:
            s = chain.float_state(x, check=False)
            expected = (s.theta, s.theta_barrel, s.k[0], s.k[1], s.dk_dx[0], s.dk_dx[1])
            assert chain.driven_terms(np.float64(x)) == expected
