"""Ruckig trajectories sampled in C (`wbc.references.sample_c`) against Ruckig's own.

Oracle: the binding's ``Trajectory.at_time`` and `RuckigReference`'s arithmetic on its
samples (numpy's clip and products), bit for bit, on random trajectories of one to seven
axes: starts above the velocity limits (Ruckig's brake phases), times before the start,
inside and past the end, clock rates below one, positions clipped.
"""

from __future__ import annotations

import numpy as np
import pytest
import ruckig

from models.numeric import clip
from wbc.references.sample_c import compiled_trajectory

pytestmark = pytest.mark.skipif(compiled_trajectory(np.zeros(1), np.ones(1)) is None,
                                reason="no C compiler")


def _random_trajectory(rng, n):
    otg, inp, traj = ruckig.Ruckig(n), ruckig.InputParameter(n), ruckig.Trajectory(n)
    v_max, a_max = rng.uniform(0.05, 1.0, n), rng.uniform(0.1, 2.0, n)
    inp.max_velocity = v_max.tolist()
    inp.min_velocity = (-rng.uniform(0.05, 1.0, n)).tolist()
    inp.max_acceleration = a_max.tolist()
    inp.min_acceleration = (-a_max).tolist()
    inp.max_jerk = (a_max / rng.choice([0.25, 0.37, 0.5])).tolist()
    inp.current_position = rng.uniform(-1, 1, n).tolist()
    inp.current_velocity = (rng.uniform(-1.5, 1.5, n) * v_max * (rng.random(n) < 0.6)).tolist()
    inp.current_acceleration = (rng.uniform(-1, 1, n) * a_max
                                * (rng.random(n) < 0.4)).tolist()
    inp.target_position = rng.uniform(-1, 1, n).tolist()
    try:
        result = otg.calculate(inp, traj)
    except (ruckig.RuckigError, ValueError):
        return None
    return traj if result in (ruckig.Result.Working, ruckig.Result.Finished) else None


def _reference(traj, times, t0, rate, lower, upper):
    flat = []
    for t in np.maximum(times - t0, 0.0).tolist():
        p, v, a = traj.at_time(t)[:3]
        flat += p + v + a
    pva = np.array(flat, float).reshape(len(times), 3, -1)
    return clip(pva[:, 0], lower, upper), pva[:, 1] * rate, pva[:, 2] * rate**2


def test_samples_are_ruckigs_bit_for_bit():
    rng = np.random.default_rng(0)
    checked = braking = 0
    while checked < 400:
        n = int(rng.integers(1, 8))
        traj = _random_trajectory(rng, n)
        if traj is None:
            continue
        braking += any(p.brake.duration > 0 for p in traj.profiles[0])
        lower, upper = np.full(n, -0.9), np.full(n, 0.9)
        c = compiled_trajectory(lower, upper)
        assert c.load(traj)
        t0 = float(rng.uniform(0, 3))
        times = t0 + np.concatenate([[0.0, -0.01, -0.0], rng.uniform(0, 1.2 * traj.duration, 20),
                                     [traj.duration, 2 * traj.duration]])
        rate = float(rng.choice([1.0, 0.5, 0.731, 0.0]))
        # the MPC's layout: the axes' columns of (times, 9) node arrays
        nodes = [np.full((times.size, 9), np.nan) for _ in range(3)]
        first = int(rng.integers(0, 10 - n))
        views = [a[:, first:first + n] for a in nodes]
        assert c.sample_into(times, t0, rate, *views)
        for got, want in zip(views, _reference(traj, times, t0, rate, lower, upper)):
            assert np.array_equal(got, want)
        for a in nodes:  # nothing outside the views written
            assert np.isnan(np.delete(a, np.s_[first:first + n], axis=1)).all()
        checked += 1
    assert braking > 50  # the brake phases were exercised


def test_a_changed_phase_is_caught():
    """The oracle has power: one phase's jerk off in the C's copy changes samples."""
    rng = np.random.default_rng(1)
    traj = None
    while traj is None:
        traj = _random_trajectory(rng, 3)
    lower, upper = np.full(3, -10.0), np.full(3, 10.0)
    c = compiled_trajectory(lower, upper)
    c.load(traj)
    times = np.linspace(0, traj.duration, 50)
    out = [np.empty((50, 3)) for _ in range(3)]
    c.profiles[1, 7 + 2] *= 1 + 1e-12  # axis 1, phase 2's jerk
    c.sample_into(times, 0.0, 1.0, *out)
    want = _reference(traj, times, 0.0, 1.0, lower, upper)
    assert not all(np.array_equal(a, b) for a, b in zip(out, want))


def test_arrays_it_cannot_take_are_refused():
    rng = np.random.default_rng(2)
    traj = None
    while traj is None:
        traj = _random_trajectory(rng, 2)
    c = compiled_trajectory(np.full(2, -1.0), np.full(2, 1.0))
    c.load(traj)
    times = np.linspace(0, 1, 5)
    good = [np.empty((5, 2)) for _ in range(3)]
    assert not c.sample_into(times, 0.0, 1.0, np.empty((5, 4))[:, ::2], *good[1:])
    assert not c.sample_into(times, 0.0, 1.0, np.empty((5, 3)), *good[1:])
    assert not c.sample_into(times[::2].copy(), 0.0, 1.0, *good)
    assert not c.load(ruckig.Trajectory(3))  # another number of axes


@pytest.mark.parametrize("axes", ["crane", "suspension"])
def test_reference_node_samples_are_the_bindings(machine, axes):
    """`RuckigReference.sample_many_into` and `sample_columns_into` in C and through the
    binding: the same bits into the MPC's node arrays (and nothing in the other axes'
    columns), from starts inside and above the limits, at clock rates <= 1."""
    from wbc import CRANE_AXES, SUSPENSION_AXES, AxisLimits, RuckigReference

    limits = AxisLimits.from_machine(machine)
    index = CRANE_AXES if axes == "crane" else SUSPENSION_AXES
    rng = np.random.default_rng(3)
    lo, hi = limits.position_lower[index], limits.position_upper[index]
    for _ in range(40):
        refs = [RuckigReference(limits, index, jerk_time=0.5) for _ in range(2)]
        refs[1].compiled = False
        start = rng.uniform(lo, hi)
        velocity = rng.uniform(-1.2, 1.2, len(index)) * limits.velocity_upper[index]
        goal = rng.uniform(lo, hi)
        t0 = float(rng.uniform(0, 5))
        for ref in refs:
            ref.plan(t0, start, velocity, np.zeros(len(index)), goal)
        assert refs[0]._compiled_loaded
        times = t0 + float(rng.uniform(-0.5, refs[0].duration)) + np.linspace(0, 1.0, 13)
        rate = float(rng.choice([1.0, 0.6, 0.0]))
        out = [[np.full((13, 9), np.nan) for _ in range(3)] for _ in range(3)]
        refs[0].sample_many_into(times, rate, *(a[:, refs[0].index] for a in out[0]))
        refs[0].sample_columns_into(times, rate, *out[1])  # the controller's call
        refs[1].sample_many_into(times, rate, *(a[:, refs[1].index] for a in out[2]))
        for a, b, c in zip(*out):
            assert np.array_equal(a, c, equal_nan=True)
            assert np.array_equal(b, c, equal_nan=True)  # the other columns left NaN


@pytest.mark.parametrize("axes", ["crane", "suspension"])
def test_node_samples_from_offsets_are_the_columns(machine, axes):
    """`RuckigReference.sample_nodes_into` (the times made in C) against
    `sample_columns_into` of numpy's ``tau + rate * offsets`` on the binding: the same
    bits, the same kept position; planned, held, odd clocks and offsets."""
    from wbc import CRANE_AXES, SUSPENSION_AXES, AxisLimits, RuckigReference

    limits = AxisLimits.from_machine(machine)
    index = CRANE_AXES if axes == "crane" else SUSPENSION_AXES
    rng = np.random.default_rng(4)
    lo, hi = limits.position_lower[index], limits.position_upper[index]
    steps = np.array([0.01, 0.03, 0.06] + [0.1] * 10)
    kept = np.concatenate([[0.0], np.cumsum(steps)])
    kept.setflags(write=False)  # the planner's node times: read-only, kept
    for trial in range(60):
        refs = [RuckigReference(limits, index, jerk_time=0.5) for _ in range(2)]
        refs[1].compiled = False
        t0 = float(rng.uniform(0, 5))
        if trial % 5 == 0:
            held = rng.uniform(lo, hi)
            for ref in refs:
                ref.hold(held)
        else:
            start, goal = rng.uniform(lo, hi), rng.uniform(lo, hi)
            velocity = rng.uniform(-1.2, 1.2, len(index)) * limits.velocity_upper[index]
            for ref in refs:
                ref.plan(t0, start, velocity, np.zeros(len(index)), goal)
        offsets = kept if trial % 3 else rng.uniform(-1.0, 3.0, int(rng.integers(0, 20)))
        tau = t0 + float(rng.choice([-0.3, 0.0, -0.0, 0.37, 1e-9, 40.0]))
        rate = float(rng.choice([1.0, 0.6, 0.0, 0.123456789]))
        out = [[np.full((offsets.size, 9), np.nan) for _ in range(3)] for _ in range(2)]
        refs[0].sample_nodes_into(tau, rate, offsets, *out[0])
        assert refs[0]._compiled._offsets_of is (offsets if refs[0]._planned else None)
        refs[1].sample_columns_into(tau + rate * offsets, rate, *out[1])
        for a, b in zip(*out):
            assert a.tobytes() == b.tobytes(), trial
        if refs[0]._planned and offsets.size:
            t = tau + rate * float(offsets[0])
            assert refs[0].kept(t) is not None
            assert refs[0].kept(t).tobytes() == refs[1].kept(t).tobytes()


def test_node_samples_refuse_arrays_they_cannot_take():
    rng = np.random.default_rng(5)
    traj = None
    while traj is None:
        traj = _random_trajectory(rng, 2)
    c = compiled_trajectory(np.full(2, -1.0), np.full(2, 1.0))
    c.load(traj)
    offsets = np.linspace(0, 1, 5)
    good = [np.empty((5, 4)) for _ in range(3)]
    assert c.sample_nodes(0.0, 1.0, offsets, 0.0, 0, *good) == 0.0
    assert c.sample_nodes(0.0, 1.0, offsets, 0.0, 3, *good) is None  # columns 3, 4 of 4
    assert c.sample_nodes(0.0, 1.0, offsets[:4], 0.0, 0, *good) is None
    assert c.sample_nodes(0.0, 1.0, offsets, 0.0, 0, np.empty((5, 8))[:, ::2],
                          *good[1:]) is None
    assert c.sample_nodes(0.0, 1.0, offsets.reshape(5, 1), 0.0, 0, *good) is None
