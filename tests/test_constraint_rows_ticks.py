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

from models.numpy_blas import numpy_blas
from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop
from wbc.constraints import (
    HorizonEffortLimit,
    HorizonPositionLimit,
    HorizonVelocityLimit,
    SideReserveConstraint,
)
from wbc.constraints.limits_c import CompiledEffortRows, CompiledHorizonBounds, _library
from wbc.constraints.side_reserve_c import CompiledSideReserve, side_reserve_library

pytestmark = pytest.mark.skipif(side_reserve_library() is None or _library() is None
                                or numpy_blas() is None,
                                reason="no C compiler or not numpy's OpenBLAS")

WATCHED = (SideReserveConstraint, HorizonEffortLimit, HorizonPositionLimit,
           HorizonVelocityLimit)
# The compiled calls (the method, and whether its result says it ran)
SPIED = {"side": (CompiledSideReserve, "rows"), "effort": (CompiledEffortRows, "rows_of_pair"),
         "limits": (CompiledHorizonBounds, "h")}


CACHES = ("_cache", "_structure_cache", "_last", "_key", "_G", "_c")


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
    """Per watched class: [ticks, ticks with rows, ticks whose bits differ]; per spied
    compiled method: whether each call made its rows."""
    out = {cls: [0, 0, 0] for cls in WATCHED}
    originals = {cls: cls.compute for cls in WATCHED}
    made = {name: getattr(*where) for name, where in SPIED.items()}
    twins = {}

    def spy(name):
        def call(self, *args):
            result = made[name](self, *args)
            if not twins.get("twin"):  # the compiled constraint's call, not the twin's
                out[name].append(result is not None)
            return result
        return call

    def watch(cls):
        def compute(self, ctx):
            got = originals[cls](self, ctx)
            twin = twins[id(self)] = _numpy_twin(self, twins.get(id(self)))
            twins["twin"] = True
            try:
                want = originals[cls](twin, ctx)
            finally:
                twins["twin"] = False
            count = out[cls]
            count[0] += 1
            count[1] += got is not None
            count[2] += _bits(got) != _bits(want)
            return got
        return compute

    for cls in WATCHED:
        cls.compute = watch(cls)
    for name, (cls, method) in SPIED.items():
        out[name] = []
        setattr(cls, method, spy(name))
    try:
        run_closed_loop(DEFAULT_SCENARIO, None, "mpc-full", duration=3.0, progress=False)
    finally:
        for cls in WATCHED:
            cls.compute = originals[cls]
        for name, (cls, method) in SPIED.items():
            setattr(cls, method, made[name])
    return out


def test_side_reserve_rows_are_numpys_on_real_ticks(ticks):
    n, active, differ = ticks[SideReserveConstraint]
    assert n > 250 and active > 100  # the reserve on while driving
    assert differ == 0
    calls = ticks["side"]
    assert len(calls) == active and all(calls)  # every tick with rows in one C call


def test_effort_rows_are_numpys_on_real_ticks(ticks):
    n, active, differ = ticks[HorizonEffortLimit]
    assert n == active > 250 and differ == 0
    assert len(ticks["effort"]) == n and all(ticks["effort"])  # the pair's call each tick


@pytest.mark.parametrize("limit", [HorizonPositionLimit, HorizonVelocityLimit])
def test_horizon_bounds_are_numpys_on_real_ticks(ticks, limit):
    n, active, differ = ticks[limit]
    assert n == active > 250 and differ == 0
    assert len(ticks["limits"]) == 2 * n  # both limits' h compiled, every tick

