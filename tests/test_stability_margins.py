"""Force-angle measure and ZMP margin on hand-solved cases; lift-off prediction AUC."""

import math

import numpy as np
import pytest

from scenarios.stability_margins import PERIMETER, force_angle_and_zmp
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


def _reference(points: np.ndarray, forces: np.ndarray, in_contact: np.ndarray,
             com: np.ndarray) -> tuple[float, float, float]:
    """One sample, edge by edge: the implementation before the batched one (the oracle)."""
    ring = [k for k in PERIMETER if in_contact[k]]
    if len(ring) < 3:
        return 0.0, 0.0, 0.0
    f_r = -forces[ring].sum(axis=0)
    norm_f = float(np.linalg.norm(f_r))
    if norm_f == 0.0:
        return 0.0, 0.0, 0.0
    down = f_r / norm_f
    p = points[ring]
    # Orient the ring counter-clockwise seen against f_r (from "above").
    centre = p.mean(axis=0)
    area = sum(np.cross(p[i] - centre, p[(i + 1) % len(p)] - centre) @ -down
               for i in range(len(p)))
    if area < 0:
        p = p[::-1]
    fz = np.maximum(-(forces[ring] @ down), 0.0)  # pressure along f_r
    cop = (fz @ points[ring]) / fz.sum() if fz.sum() > 0 else centre
    beta, theta_min, zmp = np.inf, np.inf, np.inf
    for i in range(len(p)):
        a = p[(i + 1) % len(p)] - p[i]
        a /= np.linalg.norm(a)
        proj = np.eye(3) - np.outer(a, a)
        rel = com - p[i]
        lv = proj @ rel
        fi = proj @ f_r
        ln, fn = np.linalg.norm(lv), np.linalg.norm(fi)
        if ln == 0.0 or fn == 0.0:
            continue
        # Inward normal of the edge in the ground plane (counter-clockwise ring).
        inward = np.cross(-down, a)
        # Signed angle from -l (centre of mass towards the axis) to f_i, positive towards
        # the inside of the polygon: f_i through the edge is theta = 0.
        u = -lv / ln
        w = inward - (inward @ u) * u
        w /= np.linalg.norm(w)
        theta = float(np.arctan2(fi @ w, fi @ u))
        beta = min(beta, theta * ln * norm_f)
        theta_min = min(theta_min, theta)
        zmp = min(zmp, float((cop - p[i]) @ inward))
    return float(beta), float(theta_min), float(zmp)


def test_batched_margins_match_the_sample_by_sample_reference():
    """Random poses, forces, centres of mass and contact patterns (2-4 wheels)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    n = 400
    rot = Rotation.random(n, random_state=6).as_matrix()
    pos = rng.normal(size=(n, 3))
    pts = POINTS[None] * [1.2, 0.9, 1.0] + rng.normal(scale=0.1, size=(n, 4, 3))
    frc = rng.normal(scale=200.0, size=(n, 4, 3)) + [0.0, 0.0, 2500.0]
    frc[rng.random(n) < 0.05] *= -1.0  # the ground pulling: rings seen from below
    contact = rng.random((n, 4)) < 0.8
    com = rng.normal(scale=0.7, size=(n, 3)) + [0.0, 0.0, 1.0]
    com_world = np.einsum("nij,nj->ni", rot, com) + pos
    m = force_angle_and_zmp(pos, rot, pts, frc, contact, com_world)
    for i in range(n):
        p = rot[i] @ pts[i].T + pos[i][:, None]
        f = rot[i] @ frc[i].T
        want = _reference(p.T, f.T, contact[i], com_world[i])
        got = (m["beta_Nm"][i], m["theta_rad"][i], m["zmp_margin_m"][i])
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert 0.1 < (m["theta_rad"] == 0).mean() < 0.5  # the zeros of < 3 wheels are there


def test_lift_off_auc():
    rows = [{"metrics": {"min_normal_force_N": {"FL": f}, "min_zmp_margin_m": z,
                         "min_force_angle_measure_Nm": b}}
            for f, z, b in ((0.0, 0.5, 10.0), (0.0, 0.1, 30.0), (900.0, 0.3, 20.0),
                            (2000.0, 0.4, 5.0))]
    p = lift_off_prediction(rows)
    assert p["runs_with_lift_off"] == 2 and p["min_normal_force_auc"] == 1.0
    assert p["zmp_margin_auc"] == pytest.approx(0.5)
