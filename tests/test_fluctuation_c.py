"""The speed governor's tick in C (`wbc.force_models.fluctuation_c`): numpy's bits."""

import numpy as np
import pytest

from wbc.force_models.fluctuation import SpeedGovernor

ODD = [0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, -1.0, 5e3, 1e-300]


def _pair():
    fast = SpeedGovernor(2.0, high_pass=0.2, window=1.0, drive_time_constant=0.5)
    slow = SpeedGovernor(2.0, high_pass=0.2, window=1.0, drive_time_constant=0.5)
    slow._c, slow._state = None, np.zeros(2)  # the numpy path
    slow.reset()
    return fast, slow


def _bits(gov) -> bytes:
    parts = [gov.mean, gov._square, gov.per_speed, np.array([gov.scale_lag,
                                                             gov._speed_square])]
    return b"".join(np.asarray(p, float).tobytes() for p in parts if p is not None)


pytestmark = pytest.mark.skipif(SpeedGovernor(1.0)._c is None, reason="no C compiler")


def test_update_and_cap_are_the_numpy_paths_bits():
    """Driving, standing, lifted wheels, odd loads and speeds, time going back."""
    rng = np.random.default_rng(3)
    fast, slow = _pair()
    t = 0.0
    for k in range(6000):
        if k % 1500 == 1499:
            fast.reset(), slow.reset()
        t += float(rng.choice([0.01, 0.01, 0.01, 0.0, -0.02, 0.5]))
        f = rng.normal(6e3, 2e3, 4)
        if k % 11 == 0:
            f[rng.integers(4)] = rng.choice(ODD)
        contact = rng.random(4) < 0.97
        speed = float(rng.choice([0.5, 0.3, 0.1, 0.0, np.nan]) if k % 13 == 0
                      else rng.uniform(0.0, 0.8))
        scale = float(rng.uniform(0.0, 1.0))
        with np.errstate(all="ignore"):
            fast.update(f, contact, t, speed, scale)
            slow.update(f, contact, t, speed, scale)
        assert fast._c is not None and fast.mean is fast._c.mean or fast.mean is None
        assert _bits(fast) == _bits(slow), k
        th = rng.choice(ODD, 4) if k % 17 == 0 else rng.normal(3e3, 1e3, 4)
        cap_speed = float(rng.choice([0.3, 0.0, np.nan, 1e-3, 0.6]))
        with np.errstate(all="ignore"):
            got, want = (g.cap(th, cap_speed, contact) for g in (fast, slow))
        assert np.array(got).tobytes() == np.array(want).tobytes(), (k, got, want)


def test_cap_on_odd_states_is_the_numpy_paths_bits():
    """Signed zeros, infinities and NaN in the kept mean, the per-speed and the lag."""
    rng = np.random.default_rng(0)
    fast, slow = _pair()
    fast.mean = fast._c.mean
    for trial in range(20000):
        mean = rng.choice(ODD, 4) if trial % 2 else rng.normal(5e3, 3e3, 4)
        fast._c.mean[:] = mean
        slow.mean = mean.copy()
        per_speed = (rng.choice(ODD, 4) if trial % 3 == 0 else np.abs(rng.normal(1e3, 1e3, 4)))
        fast.per_speed, slow.per_speed = per_speed.copy(), per_speed.copy()
        fast.scale_lag = slow.scale_lag = float(rng.choice([0.0, 0.5, 1.0, np.nan, -np.inf]))
        th = mean.copy() if trial % 7 == 0 else (
            rng.choice(ODD, 4) if trial % 5 == 0 else rng.normal(3e3, 1e3, 4))
        contact = rng.random(4) < 0.8
        speed = float(rng.choice([0.3, 0.0, np.nan, 1e-3, np.inf, -0.2]))
        with np.errstate(all="ignore"):
            got, want = (g.cap(th, speed, contact) for g in (fast, slow))
        assert np.array(got).tobytes() == np.array(want).tobytes(), (trial, got, want)


def test_a_deep_copy_runs_on_buffers_of_its_own():
    import copy

    fast, slow = _pair()
    rng = np.random.default_rng(8)
    for k in range(300):
        f, speed = rng.normal(6e3, 2e3, 4), float(rng.uniform(0.2, 0.6))
        for g in (fast, slow):
            g.update(f, np.ones(4, bool), 0.01 * k, speed, 0.8)
    twin = copy.deepcopy(fast)
    assert twin.mean is twin._c.mean and twin._square is twin._c.square
    assert twin._state is twin._c.state and twin._c.mean is not fast._c.mean
    assert _bits(twin) == _bits(fast)
    for k in range(300, 400):
        f = rng.normal(6e3, 2e3, 4)
        for g in (twin, slow):
            g.update(f, np.ones(4, bool), 0.01 * k, 0.4, 0.8)
    assert _bits(twin) == _bits(slow) != _bits(fast)
