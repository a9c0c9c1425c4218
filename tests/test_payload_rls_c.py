"""The payload filter's update in C (`tail_c`'s ``rls_update``, run by the observer's
``tail_run``) against `payload_rls.PayloadRLS.update`: the same state, bit for bit, tick
after tick, through picks, releases, the grapple command's expectation, dead bands, ticks
without information, an overflowing step and a window that outgrows its ring."""

import ctypes
import math

import numpy as np
import pytest

from estimators.observer import tail_c
from estimators.observer.payload_rls import RLS_STATE, PayloadRLS, forgetting

pytestmark = pytest.mark.skipif(tail_c.compiled_tail() is None or tail_c.numpy_blas() is None,
                                reason="no C compiler or not numpy's own OpenBLAS")


def _table():
    """A pointer table with the one entry ``rls_update`` reads: numpy's ``dgesv``."""
    table = (ctypes.c_void_p * len(tail_c.POINTERS))()
    table[tail_c.POINTERS.index("fn_gesv")] = tail_c.numpy_blas()[2]
    return table


def _c_update(table, rls: PayloadRLS, t: float, dt: float, z: np.ndarray) -> None:
    """`PayloadRLS.update` by the C, as `_tail.TailPass` runs it (a full ring: Python)."""
    code = tail_c.compiled_tail().rls_update(
        ctypes.addressof(table), rls._state.ctypes.data, rls._ring.ctypes.data,
        rls._ring.shape[1], t, forgetting(dt), z.ctypes.data)
    if code == 5:
        zz = z.tolist()
        rls.update(t, dt, zz[0:2], zz[2:4], zz[4:6], zz[6:8])
    else:
        assert code == 0


def _ticks(rng):
    """(time, dt, z (8,), expect the pick now) of a drive: the payload picked and released,
    noise, bands on and off, NaN and insensitive ticks, a run of 1 ms ticks, an overflow."""
    t, m_true = 0.0, 40.0
    for k in range(900):
        dt = 0.001 if 300 <= k < 420 else (0.0 if k == 7 else 0.01)
        t += dt
        m_true = 40.0 if k < 200 else (640.0 if k < 600 else 60.0)
        y = np.array([210.0, -120.0]) * (1.0 + 0.3 * math.sin(0.01 * k))
        if 100 <= k < 115:
            y *= 0.01  # the cylinders do not see the payload
        f0 = np.array([3e4, -2e4]) + rng.normal(0.0, 50.0, 2)
        measured = f0 + y * m_true + rng.normal(0.0, 300.0, 2)
        band = np.array([0.0, 0.0]) if (k // 37) % 2 else np.array([900.0, 700.0])
        if k in (50, 51, 700):
            measured[k % 2] = np.nan
        if k == 800:
            y[:] = 1e200  # the step overflows: no update
        z = np.concatenate([measured, f0, y, band])
        yield t, dt, z, k == 190


def test_the_c_update_is_the_python_update():
    table = _table()
    rng = np.random.default_rng(3)
    python, fast = (PayloadRLS(10.0, 150.0, [2e3, 1.5e3], [300.0, 200.0],
                               event_variance_scale=0.1) for _ in range(2))
    events, grew = [], False
    for t, dt, z, expect in _ticks(rng):
        if expect:
            for rls in (python, fast):
                rls.expect_pick(t)
        zz = z.tolist()
        python.update(t, dt, zz[0:2], zz[2:4], zz[4:6], zz[6:8])
        _c_update(table, fast, t, dt, z)
        assert fast._state.tobytes() == python._state.tobytes(), (t, RLS_STATE)
        assert fast._ring.tobytes() == python._ring.tobytes(), t
        assert repr((fast.event, fast.event_time, fast.std)) == repr(
            (python.event, python.event_time, python.std))  # (std: NaN at the overflow)
        events += [python.event] if python.event else []
        grew |= python._ring.shape[1] > 64
    assert "pick" in events and "release" in events and grew
