"""The MPC's compiled constraint rows against their numpy paths on closed-loop ticks.

A short closed loop (the default scenario, mpc-full: standing, then driving with the side
reserve on) runs with each compiled constraint's `compute` watched: at every tick a twin on
the numpy path (``compiled=False``, its own caches) computes the rows of the same context,
and ``G``, ``h`` and the blocks must have the same bits. The compiled paths must have run
(not fallen back to numpy).
"""

from __future__ import annotations

import copy

import pytest

from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop
from wbc.constraints import SideReserveConstraint
from wbc.constraints.side_reserve_c import CompiledSideReserve, side_reserve_library

pytestmark = pytest.mark.skipif(side_reserve_library() is None, reason="no C compiler")

WATCHED = (SideReserveConstraint,)


CACHES = ("_cache",)


def _numpy_twin(con, twin=None):
    """``con`` on its numpy path: its settings now (the reserve, the bounds), caches its own."""
    if twin is None:
        twin = copy.copy(con)
        twin.__dict__.update(dict.fromkeys(CACHES), compiled=False)
    twin.__dict__.update((k, v) for k, v in con.__dict__.items()
                         if k not in CACHES and k != "compiled")
    return twin


def _bits(rows) -> tuple:
    return None if rows is None else (rows.G.shape, rows.G.tobytes(), rows.h.tobytes(),
                                      rows.diagonal)


@pytest.fixture(scope="module")
def ticks():
    """Per watched class: (ticks, ticks with rows, ticks whose bits differ, compiled calls)."""
    out = {cls: [0, 0, 0] for cls in WATCHED}
    calls = []
    originals = {cls: cls.compute for cls in WATCHED}
    twins = {}
    made = CompiledSideReserve.rows

    def rows_spy(self, *args):
        result = made(self, *args)
        calls.append(result is not None)
        return result

    def watch(cls):
        def compute(self, ctx):
            got = originals[cls](self, ctx)
            twin = twins[id(self)] = _numpy_twin(self, twins.get(id(self)))
            want = originals[cls](twin, ctx)
            count = out[cls]
            count[0] += 1
            count[1] += got is not None
            count[2] += _bits(got) != _bits(want)
            return got
        return compute

    for cls in WATCHED:
        cls.compute = watch(cls)
    CompiledSideReserve.rows = rows_spy
    try:
        run_closed_loop(DEFAULT_SCENARIO, None, "mpc-full", duration=3.0, progress=False)
    finally:
        for cls in WATCHED:
            cls.compute = originals[cls]
        CompiledSideReserve.rows = made
    out["side calls"] = calls
    return out


def test_side_reserve_rows_are_numpys_on_real_ticks(ticks):
    n, active, differ = ticks[SideReserveConstraint]
    assert n > 250 and active > 100  # the reserve on while driving
    assert differ == 0
    calls = ticks["side calls"]
    assert len(calls) == active and all(calls)  # every tick with rows in one C call

