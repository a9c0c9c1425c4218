"""`wbc.solvers.screen_c`'s inline neighbours of a double against ``nextafter``.

The C screening widens its margin to the neighbouring doubles with ``next_down`` and
``next_up`` (``nextafter`` without the library call); oracle: numpy's ``nextafter`` on
zeros, subnormals, the largest doubles, infinities and random doubles of every exponent.
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest

from models.cbuild import compile_shared
from wbc.solvers.screen_c import SCREEN_C, screen_library

pytestmark = pytest.mark.skipif(screen_library() is None, reason="no C compiler")


def test_neighbours_are_nextafters():
    source = SCREEN_C + ("double down(double x) { return next_down(x); }\n"
                         "double up(double x) { return next_up(x); }\n")
    lib = ctypes.CDLL(str(compile_shared(source, "screen_neighbours")))
    for f in (lib.down, lib.up):
        f.argtypes, f.restype = [ctypes.c_double], ctypes.c_double
    rng = np.random.default_rng(0)
    big, tiny = np.finfo(float).max, np.finfo(float).tiny
    xs = [0.0, -0.0, np.inf, -np.inf, 5e-324, -5e-324, big, -big, tiny, -tiny, 1.0, -1.0]
    xs += list(rng.normal(size=5000) * 10.0 ** rng.integers(-320, 308, 5000))
    with np.errstate(over="ignore"):
        for x in xs:
            for f, to in ((lib.down, -np.inf), (lib.up, np.inf)):
                assert np.float64(f(x)).tobytes() == np.nextafter(x, to).tobytes(), x
    assert np.isnan(lib.down(np.nan)) and np.isnan(lib.up(np.nan))
