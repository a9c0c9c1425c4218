"""The reference governor's error (`Controller._governor_error`): numpy's max of abs, bits."""

import numpy as np
import pytest

from testkit.plant import make_state
from wbc.controllers.controller import Controller


class _Ref:
    """A reference that holds ``position`` (what `RuckigReference.kept` gives)."""

    def __init__(self, position, index):
        self.held, self.index = position, index

    def kept(self, t):
        return self.held

    def position(self, t):
        raise AssertionError("the kept position is read")


@pytest.mark.parametrize("index", [slice(2, 9), slice(0, 2), slice(4, 5)])
def test_governor_error_is_numpys_max_of_abs(machine, index):
    rng = np.random.default_rng(7)
    state = make_state(machine)
    q = state.q[index]
    odd = np.array([0.0, -0.0, np.nan, -np.nan, np.inf, -np.inf, 1e-300])
    for trial in range(3000):
        d = rng.normal(scale=10.0 ** rng.integers(-6, 2), size=q.size)
        if trial % 2:
            d[rng.integers(q.size, size=2)] = rng.choice(odd, 2)
        if trial % 5 == 0:
            d[:] = d[0]  # ties
        position = q + d
        if trial % 7 == 0:
            position = q.copy()  # zeros
        want = float(np.maximum.reduce(np.abs(position - q)))
        with np.errstate(invalid="ignore"):
            got = Controller._governor_error(None, _Ref(position, index), 0.0, state)
        assert type(got) is float
        assert np.array(got).tobytes() == np.array(want).tobytes(), (trial, got, want)
