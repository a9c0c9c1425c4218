"""The observer's first part of a tick in one C call (`_tick.TickPass`) against the filters'
own calls (each compiled) and the observer's Python: the same state, bit for bit."""

import dataclasses

import numpy as np
import pytest

from estimators.errors import EstimatorError
from estimators.observer import Observer
from estimators.observer.filters_c import compiled_filters
from estimators.payload import PayloadEstimator
from models import build_reference_machine
from models import terrain as T
from models.sensing import Samples
from models.sensor_suites import sensor_suite
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator

pytestmark = pytest.mark.skipif(compiled_filters() is None, reason="no C compiler")

_FIELDS = ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd",
           "suspension_force")


def _spoiled(r, k, rng):
    """Tick ``k``'s readings, now and then with a stream empty or holding a NaN, or fewer
    accelerometer than gyroscope samples."""
    names = ("angular_rate", "specific_force", "positions", "pressures", "wheel_speeds",
             "drive_torques")
    if k % 5 == 1:
        s = r.specific_force
        r = dataclasses.replace(r, specific_force=Samples(s.time[:1], s.value[:1]))
    if k < 3 or k % 7:
        return r
    name = names[(k // 14) % len(names)]  # each stream empty, then with a NaN
    s = getattr(r, name)
    if k % 14 == 0:  # an empty stream
        return dataclasses.replace(r, **{name: Samples(s.time[:0], s.value[:0])})
    value = s.value.copy()
    value[rng.integers(value.shape[0]), rng.integers(value.shape[1])] = np.nan
    return dataclasses.replace(r, **{name: Samples(s.time, value)})


def test_tick_pass_is_the_filters_calls():
    """A drive with the crane slewing, the first tick's levelling, empty streams and NaNs
    (each raises, or holds, at the same step), the axes' ranges narrowed about the motion
    (q clipped on both sides): every state field the same bits, the pressures' forces
    beyond the first bound rows."""
    machine = build_reference_machine()
    spec = sensor_suite("realistic", 4)
    sim = Simulator(machine, T.rough(3, max_slope_deg=8.0))
    sim.reset(None, (2.0, 0.0, 0.0))
    sensors = SensorSimulator(sim, spec)
    closure = PayloadEstimator(machine, fourth="cylinder-force", strokes="clip")
    fast, calls, python = (Observer(machine, spec, closure, compiled=c)
                           for c in (True, True, False))
    calls._tick = calls._tail = None
    assert fast._tick is not None and python._tick is None
    rng = np.random.default_rng(2)
    held, clipped = 0, set()
    for k in range(300):
        sim.set_command(cylinder_rates={"slew": 0.1 * np.sin(0.05 * k)},
                        wheel_speeds=(0.8, 1.2))
        sim.step(5 if k != 150 else 40)  # one long tick: more samples than the buffers
        r = _spoiled(sensors.readings(sim.time), k, rng)
        out = []
        for obs in (fast, calls):
            try:
                out.append(obs.update(r))
            except EstimatorError as exc:
                out.append(str(exc))
        if k == 20:  # ranges of +-1 mm, +-1 mrad about the axes' positions now
            q = out[0].state.q[:9]
            lo, hi = q - 1e-3, q + 1e-3
            fast._tick._consts[2][:9], fast._tick._consts[3][:9] = lo, hi  # bound: in place
            for obs in (calls, python):
                obs._q_lo, obs._q_hi = lo.copy(), hi.copy()
        if isinstance(out[0], str):
            assert out[0] == out[1]
            continue
        e_fast, e_calls = out
        held += e_fast.stale
        for name in _FIELDS:
            a, b = getattr(e_fast.state, name), getattr(e_calls.state, name)
            assert a.tobytes() == b.tobytes(), (k, name)
        assert e_fast.forces_four.tobytes() == e_calls.forces_four.tobytes()
        assert e_fast.payload_mass == e_calls.payload_mass
        if k > 20:
            clipped |= ({"lo"} if np.any(e_fast.state.q[:9] == lo) else set()) | (
                {"hi"} if np.any(e_fast.state.q[:9] == hi) else set())
        e_py = python.update(r)  # the Python filters: the C's to round-off
        np.testing.assert_allclose(e_fast.state.q, e_py.state.q, rtol=1e-9, atol=1e-9)
    assert held > 5 and fast.base._levelled and fast._tick._rows > 16
    assert clipped == {"lo", "hi"}
