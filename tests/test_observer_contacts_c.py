"""The observer's contact geometry, longitudinal forces and flags in C (`contacts_c`)
against their Python code: the same bits."""

import numpy as np
import pytest

from estimators.observer.contacts import CONTACT_LANDING_N, ContactTracker
from estimators.observer.contacts_c import compiled_contacts

pytestmark = pytest.mark.skipif(compiled_contacts() is None, reason="no C compiler")


def _same(a, b):
    """The same array, bit for bit (NaN's too)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), (a, b)


@pytest.mark.parametrize("sphere", [True, False])
def test_contact_tracker_in_c_is_the_python_tracker(sphere):
    """Random geometry and forces about a wheel's load (flags leaving and landing), drive
    torques from the second tick, the odd NaN: every output the same bits."""
    rng = np.random.default_rng(3 + sphere)
    tc, tp = (ContactTracker(0.62, 11.5, sphere, c) for c in (True, False))
    assert tc._c is not None and tp._c is None
    centres = np.array([[1.6, 1.0, -0.3], [-1.5, 1.0, -0.3], [1.6, -1.0, -0.3],
                        [-1.5, -1.0, -0.3]])
    previous = np.ones(4)
    seen = set()
    for k in range(400):
        lowest = centres + 0.05 * rng.standard_normal((4, 3))
        up = (np.array([0.0, 0.0, 1.0]) + 0.2 * rng.standard_normal(3)).tolist()
        if k == 7:
            lowest[2, 1] = np.nan
        if k > 0:
            torques = 800.0 * rng.standard_normal((int(rng.integers(1, 4)), 2))
            tc.set_drive(torques)
            tp.set_drive(torques)
        acc = (3.0 * rng.standard_normal(4)).tolist()
        tc.wheel_acceleration = tp.wheel_acceleration = acc
        out_c, out_p = tc.points(lowest, list(up), previous), tp.points(lowest, list(up),
                                                                          previous)
        for a, b in zip(out_c, out_p):
            _same(a, b)
        forces = rng.uniform(-500.0, 1.2 * CONTACT_LANDING_N, 4)
        if k == 11:
            forces[0] = np.nan
        if k % 50 == 3:
            forces[:2] = 0.0  # a side's zero sum: the even split
        flags_c, flags_p = tc.update(forces), tp.update(forces)
        for a, b in zip(flags_c, flags_p):
            _same(a, b)
        assert tc.in_contact == tp.in_contact
        seen.add(sum(tp.in_contact))
        previous = forces
    assert seen >= {2, 3, 4}  # the normal's three cases ran
