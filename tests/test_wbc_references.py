"""Ruckig references: within the description's limits, at the goal, typed errors."""

import numpy as np
import pytest

from wbc import (
    CRANE_AXES,
    SUSPENSION_AXES,
    AxisLimits,
    RuckigReference,
    TrajectoryError,
    WbcInputError,
)
from wbc.axes import axis_index


@pytest.fixture(scope="module")
def limits(machine):
    return AxisLimits.from_machine(machine)


def test_axis_limits_come_from_the_description(machine, limits):
    lift = machine.chains["lift"]
    lo, hi = lift.chain.stroke_range
    i = limits.names.index("lift")
    assert limits.position_lower[i] == pytest.approx(lo + 0.01 * (hi - lo))
    assert limits.position_upper[i] == pytest.approx(hi - 0.01 * (hi - lo))
    assert limits.velocity_lower[i] == pytest.approx(lift.cylinder.velocity_range[0])
    assert limits.velocity_upper[i] == pytest.approx(lift.cylinder.velocity_range[1])
    assert limits.acceleration[i] == lift.cylinder.max_acceleration
    k = limits.names.index("rotator")
    d = machine.direct_drives["rotator"]
    assert limits.velocity_upper[k] == d.velocity_limit
    assert limits.acceleration[k] == d.acceleration_limit
    assert limits.names[:2] == machine.suspension_coordinates


def _dense_samples(ref, t_end, dt=1e-3):
    t = np.arange(0.0, t_end, dt)
    p, v, a = ref.sample_many(t)
    return t, p, v, a


@pytest.mark.parametrize("axes", [CRANE_AXES, SUSPENSION_AXES])
def test_reference_respects_limits_and_reaches_goal(limits, axes):
    rng = np.random.default_rng(3)
    ref = RuckigReference(limits, axes, jerk_time=0.25, velocity_fraction=0.8,
                          acceleration_fraction=0.8)
    lo, hi = limits.position_lower[axes], limits.position_upper[axes]
    for _ in range(5):
        start = rng.uniform(lo, hi)
        goal = rng.uniform(lo, hi)
        v0 = 0.5 * ref.min_velocity * rng.uniform(0, 1, axes.size)  # moving backwards
        ref.plan(2.0, start, v0, np.zeros(axes.size), goal)
        t, p, v, a = _dense_samples(ref, 2.0 + ref.duration + 0.5)
        tol = 1e-9
        assert np.all(v <= ref.max_velocity + tol) and np.all(v >= ref.min_velocity - tol)
        assert np.all(np.abs(a) <= ref.max_acceleration + tol)
        jerk = np.diff(a, axis=0) / np.diff(t)[:, None]
        assert np.all(np.abs(jerk) <= ref.max_jerk * (1 + 1e-6) + 1e-6)
        # The reference's own limits are inside the machine's.
        assert np.all(ref.max_velocity <= limits.velocity_upper[axes])
        assert np.all(ref.min_velocity >= limits.velocity_lower[axes])
        # Before t0 the reference sits at the start; at the end at rest at the goal.
        np.testing.assert_allclose(p[0], np.clip(start, lo, hi), atol=1e-12)
        pe, ve, ae = ref.sample(2.0 + ref.duration + 1.0)
        np.testing.assert_allclose(pe, goal, atol=1e-9)
        np.testing.assert_allclose(ve, 0.0, atol=1e-9)
        np.testing.assert_allclose(ae, 0.0, atol=1e-9)
        assert np.all(p >= lo - 1e-12) and np.all(p <= hi + 1e-12)


def test_reference_is_time_synchronized(limits):
    ref = RuckigReference(limits, CRANE_AXES)
    start = 0.5 * (limits.position_lower + limits.position_upper)[CRANE_AXES]
    goal = start.copy()
    goal[0] += 0.1
    goal[3] += 0.3
    ref.plan(0.0, start, np.zeros(7), np.zeros(7), goal)
    # Every moving axis arrives at the same time (straight line in joint space).
    t, p, _, _ = _dense_samples(ref, ref.duration)
    frac = (p[:, [0, 3]] - start[[0, 3]]) / (goal - start)[[0, 3]]
    assert np.max(np.abs(frac[:, 0] - frac[:, 1])) < 0.2


def test_hold_and_errors(limits):
    ref = RuckigReference(limits, SUSPENSION_AXES)
    with pytest.raises(TrajectoryError):
        ref.sample(0.0)
    ref.hold([0.1, 0.12])
    p, v, a = ref.sample(5.0)
    np.testing.assert_allclose(p, [0.1, 0.12])
    assert not v.any() and not a.any()
    with pytest.raises(WbcInputError, match="outside .* for axis 'bogie_L'"):
        ref.plan(0.0, [0.1, 0.1], [0, 0], [0, 0], [0.9, 0.1])
    with pytest.raises(WbcInputError):
        ref.plan(0.0, [0.1, 0.1], [0, 0], [0, 0], [0.1, np.nan])
    with pytest.raises(WbcInputError):
        ref.plan(0.0, [0.1, 0.1], [0, 0], [0, 0], [0.1, 0.1, 0.1])
    with pytest.raises(ValueError):  # the typed errors are ValueErrors too
        ref.check_goal([1.0, 1.0])


def test_ruckig_boundary_case_is_planned(limits):
    """ruckig 0.19 raises on this exact boundary case; the reference retries off it."""
    ref = RuckigReference(limits, SUSPENSION_AXES[:1] + 3)  # the lift axis
    a, j = ref.max_acceleration[0], ref.max_jerk[0]
    d = a**3 / j**2 * 2  # a reaches its limit exactly, no constant-acceleration phase
    start = 0.3392170339050292
    ref.plan(0.0, [start], [0.0], [0.0], [start + d])
    assert ref.sample(10.0)[0][0] == pytest.approx(start + d, abs=1e-9)


def _crane_reference(limits, axis: int, step: float):
    """A crane reference, the start mid-range and the goal ``step`` along one axis."""
    ref = RuckigReference(limits, CRANE_AXES)
    start = 0.5 * (limits.position_lower + limits.position_upper)[CRANE_AXES]
    goal = start.copy()
    goal[axis] += step
    return ref, start, goal


def test_sample_many_equals_one_sample_at_a_time(limits):
    ref, start, goal = _crane_reference(limits, 1, 0.2)
    ref.plan(1.0, start, np.zeros(7), np.zeros(7), goal)
    times = np.array([0.0, 1.0, 1.3, 2.0, 1.0 + ref.duration + 1.0])  # before, in, after
    many = ref.sample_many(times)
    for k, t in enumerate(times):
        for got, want in zip((m[k] for m in many), ref.sample(t)):
            np.testing.assert_array_equal(got, want)
        one = ref.sample_many([t])  # the single-time path, shapes (1, 7)
        for got, want in zip(one, (m[k:k + 1] for m in many)):
            assert got.shape == (1, 7)
            np.testing.assert_array_equal(got, want)
    ref.hold(start)
    np.testing.assert_array_equal(ref.sample_many([0.0, 2.0])[0], [start, start])


def test_contiguous_axes_index_as_a_slice(limits):
    """`index` addresses the same entries as `axes` (a slice when they are contiguous)."""
    x = np.arange(9.0)
    for axes in (CRANE_AXES, SUSPENSION_AXES, [0, 3, 4]):
        ref = RuckigReference(limits, axes)
        np.testing.assert_array_equal(x[ref.index], x[np.asarray(axes)])
    assert isinstance(RuckigReference(limits, CRANE_AXES).index, slice)
    assert not isinstance(RuckigReference(limits, [0, 3, 4]).index, slice)


def test_axis_index_is_a_slice_only_where_the_axes_are_contiguous():
    x = np.arange(10.0, 19.0)
    for axes in (np.array([2, 3, 4]), np.array([0]), np.array([4, 2, 3]), np.array([0, 2])):
        index = axis_index(axes)
        assert isinstance(index, slice) == (np.diff(axes) == 1).all()
        np.testing.assert_array_equal(x[index], x[axes])


def _telescope_reference(limits, planned: bool):
    """A crane reference planned 0.4 m out along the telescope from 1 s on, or held, and
    times to sample it at: before, at and after its start and past its end."""
    ref, start, goal = _crane_reference(limits, 3, 0.4)
    if planned:
        ref.plan(1.0, start, np.full(7, 0.01), np.zeros(7), goal)
    else:
        ref.hold(start)
    return ref, (0.0, 1.0, 1.37, 2.9, 1.0 + ref.duration + 1.0)


@pytest.mark.parametrize("planned", [True, False])
def test_position_and_sample_into_equal_sample(limits, planned):
    """The per-tick paths read the same bits as `sample`, scaled as the governor does."""
    ref, times = _telescope_reference(limits, planned)
    for t in times:
        p, v, a = ref.sample(t)
        np.testing.assert_array_equal(ref.position(t), p)
        for rate in (1.0, 0.37, 0.0):
            out = np.full((3, 9), np.nan)
            ref.sample_into(t, rate, out[0, 2:], out[1, 2:], out[2, 2:])  # views
            np.testing.assert_array_equal(out[:, 2:], [p, rate * v, rate**2 * a])
            assert np.isnan(out[:, :2]).all()


def test_kept_position_follows_the_trajectory(limits):
    """`position` at the time `sample_into` wrote is `sample`'s, also across a new plan."""
    ref, start, goal = _crane_reference(limits, 1, 0.2)
    ref.plan(1.0, start, np.zeros(7), np.zeros(7), goal)
    buf = np.empty((3, 7))
    for t in (0.5, 1.0, 1.42, 1.42, 9.0):
        ref.sample_into(t, 1.0, *buf)
        got = ref.position(t)
        np.testing.assert_array_equal(got, ref.sample(t)[0])
        got[:] = 0.0  # a copy: the kept position is not the caller's
        np.testing.assert_array_equal(ref.position(t), ref.sample(t)[0])
    ref.plan(1.42, ref.position(1.42), np.zeros(7), np.zeros(7), start)  # from there back
    np.testing.assert_array_equal(ref.position(9.0), ref.sample(9.0)[0])
    np.testing.assert_allclose(ref.position(9.0), start, atol=1e-9)
    ref.sample_into(9.0, 1.0, *buf)
    ref.hold(goal)
    np.testing.assert_array_equal(ref.position(9.0), np.clip(goal, ref.position_lower,
                                                             ref.position_upper))


@pytest.mark.parametrize("planned", [True, False])
def test_raw_sample_clipped_and_scaled_is_sample_into(limits, planned):
    """`sample_raw` is what `sample_into` clips and scales; `kept` is what it keeps."""
    ref, times = _telescope_reference(limits, planned)
    for t in times:
        tr, pva = ref.sample_raw(t)
        assert (tr is None) == (not planned) and len(pva) == 21
        p, v, a = np.array(pva).reshape(3, 7)
        for rate in (1.0, 0.37):
            out = np.empty((3, 7))
            ref.sample_into(t, rate, *out)
            np.testing.assert_array_equal(out, [np.clip(p, ref.position_lower,
                                                        ref.position_upper),
                                                v * rate, a * rate**2])
        if planned:
            assert ref.kept(t) is ref._kept_position[2]  # what sample_into kept
            kept = ref.keep_position(tr, np.zeros(7))
            assert ref.kept(t) is kept and ref.kept(t + 3.0) is None  # another time
        else:
            assert ref.kept(t) is ref._hold


@pytest.mark.parametrize("compiled", [True, False])
def test_node_samples_keep_the_first_nodes_position(limits, compiled):
    """`sample_columns_into` keeps its first time's position: `position` there is kept (no
    new sample) and `sample`'s bits, before and after the start, past the end, at rates
    below one; a held reference keeps nothing and gives its hold."""
    ref, start, goal = _crane_reference(limits, 1, 0.2)
    ref.compiled = compiled
    ref.plan(1.0, start, np.zeros(7), np.zeros(7), goal)
    offsets = np.array([0.0, 0.01, 0.11, 0.31, 1.21])
    nodes = [np.full((5, 9), np.nan) for _ in range(3)]
    for tau, rate in ((0.5, 1.0), (1.0, 1.0), (1.42, 0.37), (1.42, 0.0), (9.0, 1.0)):
        ref.sample_columns_into(tau + rate * offsets, rate, *nodes)
        kept = ref.kept(tau)
        assert kept is not None
        np.testing.assert_array_equal(kept, ref.sample(tau)[0])
        np.testing.assert_array_equal(ref.position(tau), nodes[0][0, ref.index])
    ref.hold(goal)
    ref.sample_columns_into(9.0 + offsets, 1.0, *nodes)
    assert ref.kept(9.0) is ref._hold
    np.testing.assert_array_equal(ref.position(9.0), ref.sample(9.0)[0])
