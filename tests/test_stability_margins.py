"""Force-angle measure and ZMP margin on hand-solved cases; lift-off prediction AUC."""

import math

import numpy as np
import pytest

from scenarios.stability_margins import force_angle_and_zmp
from scenarios.sweep import lift_off_prediction

# A 2 m x 2 m support square on z = 0, wheels FL (+x, +y), RL, FR, RR; 1000 N weight.
POINTS = np.array([[1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0.0]])


def _one(forces, com, in_contact=(1, 1, 1, 1)):
    m = force_angle_and_zmp(np.zeros((1, 3)), np.eye(3)[None], POINTS[None],
                            np.asarray(forces, float)[None], np.array([in_contact], bool),
                            np.asarray(com, float)[None])
    return m["beta_Nm"][0], m["theta_rad"][0], m["zmp_margin_m"][0]


def test_centred_static_machine():
    beta, theta, zmp = _one(np.tile([0, 0, 250.0], (4, 1)), [0, 0, 1.0])
    assert theta == pytest.approx(math.pi / 4)
    assert beta == pytest.approx(math.pi / 4 * math.sqrt(2) * 1000.0)
    assert zmp == pytest.approx(1.0)


def test_centre_of_mass_near_an_edge_and_a_lateral_push():
    f = np.zeros((4, 3))
    f[[0, 2], 2], f[[1, 3], 2] = 475.0, 25.0
    beta, theta, zmp = _one(f, [0.9, 0, 1.0])
    assert theta == pytest.approx(math.atan(0.1)) and zmp == pytest.approx(0.1)
    f = np.tile([-125.0, 0, 250.0], (4, 1))  # f_r = (500, 0, -1000): pushed towards +x
    assert _one(f, [0, 0, 1.0])[1] == pytest.approx(math.pi / 4 - math.atan(0.5))


def test_past_the_edge_is_negative_and_two_wheels_are_zero():
    f = np.tile([0, 0, 250.0], (4, 1))
    assert _one(f, [1.2, 0, 1.0])[1] < 0
    assert _one(f, [0, 0, 1.0], (1, 0, 1, 0)) == (0.0, 0.0, 0.0)


def test_lift_off_auc():
    rows = [{"metrics": {"min_normal_force_N": {"FL": f}, "min_zmp_margin_m": z,
                         "min_force_angle_measure_Nm": b}}
            for f, z, b in ((0.0, 0.5, 10.0), (0.0, 0.1, 30.0), (900.0, 0.3, 20.0),
                            (2000.0, 0.4, 5.0))]
    p = lift_off_prediction(rows)
    assert p["runs_with_lift_off"] == 2 and p["min_normal_force_auc"] == 1.0
    assert p["zmp_margin_auc"] == pytest.approx(0.5)
