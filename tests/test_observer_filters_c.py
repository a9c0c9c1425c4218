"""The observer's chassis and joint filters in C (`filters_c`) against their Python code."""

import numpy as np
import pytest

from estimators.observer.base_filter import BaseFilter
from estimators.observer.filters_c import compiled_filters
from estimators.observer.joint_filter import JointFilter
from models.rotations import rpy_rotation

pytestmark = pytest.mark.skipif(compiled_filters() is None, reason="no C compiler")


def _imu_ticks(seed: int, n: int = 300):
    """IMU samples of a machine rolling and turning on bumps: 4 a tick, the odd empty tick."""
    rng = np.random.default_rng(seed)
    g = np.array([0.0, 0.0, 9.81])
    for k in range(n):
        t = 0.01 * k
        rot = rpy_rotation(0.3 * t, 0.15 * np.sin(2.0 * t), 0.1 * np.cos(3.0 * t))
        count = 0 if k % 97 == 50 else 4
        rates = (np.array([0.2 * np.cos(3 * t), 0.3 * np.cos(2 * t), 0.3])
                 + 0.01 * rng.standard_normal((count, 3)))
        forces = rot.T @ g + 0.5 * rng.standard_normal((count, 3)) + [0.3 * np.sin(t), 0, 0]
        wheels = None if k % 13 == 0 else np.array([1.5 + np.sin(t), 1.2 - np.sin(t)])
        if k == 120:
            wheels = np.array([np.nan, 1.0])  # a bad wheel reading: the odometry holds
        yield t, rates.reshape(count, 3), forces.reshape(count, 3), wheels


@pytest.mark.parametrize("seed", [0, 1])
def test_base_filter_in_c_is_the_python_filter(seed):
    args = (np.array([0.8, -0.3, 1.1]), 9.81, 0.55)
    fc, fp = BaseFilter(*args), BaseFilter(*args, compiled=False)
    assert fc._c is not None and fp._c is None
    for t, rates, forces, wheels in _imu_ticks(seed):
        fc.update(t, rates, forces, wheels)
        fp.update(t, rates, forces, wheels)
        for name in ("rotation", "rate", "angular_acceleration", "specific_force", "velocity",
                     "twist", "acceleration"):
            np.testing.assert_allclose(getattr(fc, name), getattr(fp, name), rtol=1e-12,
                                       atol=1e-12, err_msg=f"{name} at t={t:.2f}")
    # The attitude moved off level and the odometry ran: the comparison saw real motion.
    assert abs(fp.rotation[2, 0]) > 0.02 and fp.velocity[0] > 0.5


def test_joint_filter_in_c_is_the_numpy_filter():
    rng = np.random.default_rng(5)
    noise = np.r_[np.full(6, 3e-6), np.full(3, 1e-4)]
    fc, fp = JointFilter(9, 0.002, noise), JointFilter(9, 0.002, noise, compiled=False)
    assert fc._c is not None and fp._c is None
    x_keep = None
    for k in range(200):
        t = 0.002 * (5 * k + np.arange(5))
        z = (0.02 * np.sin(np.outer(t, np.linspace(0.5, 3.0, 9)))
             + noise * rng.standard_normal((5, 9)))
        xc, xp = fc.update(z[: k % 6]), fp.update(z[: k % 6])  # 0..5 samples a tick
        np.testing.assert_allclose(xc, xp, rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(fc.predict(0.004), fp.predict(0.004), rtol=1e-11,
                                   atol=1e-13)
        dt = 0.0005 * (k % 7)
        # C's prediction is numpy's arithmetic on the same state: the same bits.
        np.testing.assert_array_equal(fc.predict_rows(dt), fc.predict(dt).T)
        np.testing.assert_array_equal(fp.predict_rows(dt), fp.predict(dt).T)
        if k == 100:
            x_keep, x_copy = xc, xc.copy()
    np.testing.assert_array_equal(x_keep, x_copy)  # a returned array is not written later
    assert np.abs(fp.x[:, 2]).max() > 0.01  # accelerations were estimated


def test_base_step_tests_the_rotation_as_check_rotation():
    """The step's flag (`BaseFilter.rotation_valid`) is `check_rotation`'s verdict on
    proper rotations, ones drifted about the tolerance, reflections, large entries; False
    (the caller checks then) with a NaN or inf."""
    from models.state import ROTATION_TOLERANCE, StateError, check_rotation

    f = BaseFilter(np.array([0.8, -0.3, 1.1]), 9.81, 0.55)
    rng = np.random.default_rng(4)
    verdicts = set()
    for k in range(600):
        r = rpy_rotation(*rng.uniform(-3.0, 3.0, 3))
        kind = k % 6
        if kind == 1:  # drift of about the tolerance
            r = r + rng.uniform(0.2, 2.0) * ROTATION_TOLERANCE * rng.standard_normal((3, 3))
        elif kind == 2:
            r = r * np.array([1.0, 1.0, -1.0])  # det -1
        elif kind == 3:
            r = r * (1.0 + rng.uniform(0.0, 3.0) * ROTATION_TOLERANCE)
        elif kind == 4:
            r[rng.integers(3), rng.integers(3)] = rng.choice([np.nan, np.inf, 1.5])
        f._state[:9] = r.reshape(-1)
        f._in[:] = (0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 9.8, 0.0, 0.0, 0.0)  # dt 0: R unchanged
        assert f._c() == 0
        np.testing.assert_array_equal(f.rotation, r)
        try:
            with np.errstate(invalid="ignore"):  # its det of a NaN matrix
                check_rotation("r", r)
            valid = bool(np.isfinite(r).all())
        except StateError:
            valid = False
        assert f.rotation_valid == valid, (k, r)
        verdicts.add((kind, valid))
    assert {(1, True), (1, False), (3, True), (3, False), (2, False)} <= verdicts
