"""The observer's tick after its filters in two C calls (`_tail.TailPass`) against the Python
steps it replaces (`Observer._from_links` and on, with the other compiled parts): every
output the same bits, and where the C hands back, the Python steps from there."""

import dataclasses

import numpy as np
import pytest

from estimators.errors import EstimatorError
from estimators.observer import Observer, _tail, tail_c
from estimators.observer.crane_pressures import SLIDING_SPEED
from estimators.payload import PayloadEstimator
from models import build_reference_machine
from models import terrain as T
from models.sensing import Samples
from models.sensor_suites import chassis_only, sensor_suite
from scenarios.closed_loop import _set_payload
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator

pytestmark = pytest.mark.skipif(tail_c.compiled_tail() is None or tail_c.numpy_blas() is None,
                                reason="no C compiler or not numpy's own OpenBLAS")


def _bits(x):
    """An output as comparable bytes (arrays with their shape and type, the rest as is)."""
    if isinstance(x, np.ndarray):
        return (x.dtype.str, x.shape, x.tobytes())
    if dataclasses.is_dataclass(x):
        return tuple((f.name, _bits(getattr(x, f.name))) for f in dataclasses.fields(x))
    return repr(x)


def _same(a, b, k):
    """Two ticks' results: the same estimate bit for bit, or the same error."""
    assert _bits(a) == _bits(b), k


def _spoiled(r, k, rng):
    """Tick ``k``'s readings, now and then with a stream empty or holding a NaN (the link
    accelerometers' too), or a wheel speed of 1e160 rad/s or an angular rate of 7e153 rad/s
    (finite: the kernels overflow)."""
    names = ("angular_rate", "specific_force", "positions", "pressures", "wheel_speeds",
             "drive_torques", "link_specific_force")
    if k in (150, 151, 275):
        s = r.wheel_speeds
        return dataclasses.replace(r, wheel_speeds=Samples(s.time, np.full_like(s.value,
                                                                                1e160)))
    if k == 327:  # the gyroscope (last: the attitude does not recover): the links' kernel too
        s = r.angular_rate
        return dataclasses.replace(r, angular_rate=Samples(s.time, np.full_like(s.value,
                                                                                7e153)))
    if k < 3 or k % 9:
        return r
    name = names[(k // 18) % len(names)]
    s = getattr(r, name)
    if s is None:
        return r
    if k % 18 == 0:  # an empty stream
        return dataclasses.replace(r, **{name: Samples(s.time[:0], s.value[:0])})
    value = s.value.copy()
    value[rng.integers(value.shape[0]), rng.integers(value.shape[1])] = np.nan
    return dataclasses.replace(r, **{name: Samples(s.time, value)})


def _tick(obs, r):
    try:
        return obs.update(r)
    except (EstimatorError, ValueError) as exc:  # ValueError: a state the models refuse
        return f"{type(exc).__name__}: {exc}"


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the overflowing ticks' numpy
@pytest.mark.parametrize("links", [True, False], ids=["link-accelerometers", "chassis-only"])
def test_tail_pass_is_the_python_steps(links, monkeypatch):
    """A drive over rough ground with the slew, lift and tilt moving out of phase (every
    set of sliding cylinders), a grapple command and a pick, spoiled and overflowing
    readings, a long tick (the sample buffers grow), a writable setpoint, and the
    estimator's ranges narrowed about the motion (the range check hands back): the same
    estimates, errors and kept state, and every hand-back code taken."""
    machine = build_reference_machine(payload_mass=10.0)
    spec = sensor_suite("realistic", 5)
    # No IMU range: the absurd gyroscope sample of tick 327 reaches the links' kernel (with
    # the MTi-630's range it is refused before the chassis filter, `IMU_FAULT`).
    imu = spec.imu
    spec = dataclasses.replace(spec, imu=dataclasses.replace(
        imu, gyroscope=dataclasses.replace(imu.gyroscope, full_scale=float("inf"))))
    spec = spec if links else chassis_only(spec)
    sim = Simulator(machine, T.rough(4, max_slope_deg=8.0))
    sim.reset(None, (2.0, 0.0, 0.0))
    sensors = SensorSimulator(sim, spec)
    fast, python = (Observer(machine, spec, PayloadEstimator(machine, fourth="cylinder-force",
                                                             strokes="clip"), initial_payload=10.0)
                    for _ in range(2))
    python._tail = None
    assert fast._tail is not None
    codes, patterns, events = set(), set(), 0
    handed_back = fast._tail._python

    def python_steps(code, *args):
        codes.add(code)
        return handed_back(code, *args)

    monkeypatch.setattr(fast._tail, "_python", python_steps)
    rng = np.random.default_rng(7)
    for k in range(330):
        if k == 60:
            for obs in (fast, python):
                obs.expect_pick(sim.time)
        if k == 120:
            _set_payload(sim, 260.0)
        moving = (k // 20) % 8  # the slew, lift and tilt on or off by turns, to and fro
        sign = 1.0 if (k // 160) % 2 else -1.0
        sim.set_command(cylinder_rates={"slew": 0.1 * sign * (moving & 1),
                                        "lift": 0.03 * sign * (moving >> 1 & 1),
                                        "tilt": 0.03 * sign * (moving >> 2 & 1)},
                        wheel_speeds=(0.8, 1.1))
        sim.step(5 if k != 200 else 45)  # one long tick: more samples than the buffers
        r = _spoiled(sensors.readings(sim.time), k, rng)
        if k == 240:  # a writable setpoint: the validating constructor, in Python
            object.__setattr__(r, "servo_setpoint", r.servo_setpoint.copy())
        if k == 300:  # ranges of +-1 mm, +-1 mrad about the positions: out at times
            q = fast._last.state.q
            for obs in (fast, python):
                est = obs.force_model._est
                est._bounds = tuple((i, q[i] - 1e-3, q[i] + 1e-3) for i, _, _ in est._bounds)
            lo, hi = fast._tail._bounds[1], fast._tail._bounds[2]  # bound in C: in place
            lo[:], hi[:] = zip(*((lo_i, hi_i) for _, lo_i, hi_i in fast.force_model._est._bounds))
        a, b = _tick(fast, r), _tick(python, r)
        _same(a, b, k)
        for name in ("std",):
            if links:
                assert _bits(getattr(fast.links, name)) == _bits(getattr(python.links, name)), k
        assert fast.contacts.in_contact == python.contacts.in_contact, k
        assert fast.contacts.drive == python.contacts.drive, k
        assert _bits(fast._regression) == _bits(python._regression), k
        assert _bits(fast._previous_four) == _bits(python._previous_four), k
        assert fast.force_model.n_clipped == python.force_model.n_clipped, k
        if isinstance(a, str) or a.stale:
            continue
        patterns.add(tuple((np.abs(a.state.qd[2:5]) > SLIDING_SPEED).tolist()))
        events += a.payload_event is not None
    assert len(patterns) == 8  # none, each alone, each pair, all three
    assert events >= 1 and fast._tick._rows > 16
    assert codes == ({1, 2, 3, 4} if links else {1, 3, 4})


def test_the_blas_routines_are_numpys():
    """`tail_c.numpy_blas`'s ``cblas_dgemv``, ``cblas_ddot`` and ``dgesv``, called as the
    tail's C calls them, give numpy's ``ndarray.dot``, ``@`` and ``linalg.solve`` bits on
    random blocks of the crane's sizes (a sum in another order would differ)."""
    import ctypes

    gemv_at, ddot_at, gesv_at = tail_c.numpy_blas()
    i64, dbl, ptr = ctypes.c_int64, ctypes.c_double, ctypes.c_void_p
    gemv = ctypes.CFUNCTYPE(None, ctypes.c_int, ctypes.c_int, i64, i64, dbl, ptr, i64, ptr,
                            i64, dbl, ptr, i64)(gemv_at)
    ddot = ctypes.CFUNCTYPE(dbl, i64, ptr, i64, ptr, i64)(ddot_at)
    gesv = ctypes.CFUNCTYPE(None, *[ptr] * 8)(gesv_at)
    rng = np.random.default_rng(0)
    for _ in range(300):
        a = rng.standard_normal((9, 9)) * 10.0 ** rng.uniform(-3, 3, (9, 9))
        x = rng.standard_normal(9) * 10.0 ** rng.uniform(-3, 3, 9)
        y = np.zeros(9)
        gemv(101, 111, 9, 9, 1.0, a.ctypes.data, 9, x.ctypes.data, 1, 0.0, y.ctypes.data, 1)
        assert y.tobytes() == a.dot(x).tobytes()
        for k in (1, 2, 3):
            block, u = a[:k, k:].copy(), x[k:].copy()
            if k == 1:
                got = np.array([ddot(9 - k, block.ctypes.data, 1, u.ctypes.data, 1)])
            else:
                got = np.zeros(k)
                gemv(102, 112, 9 - k, k, 1.0, block.ctypes.data, 9 - k, u.ctypes.data, 1,
                     0.0, got.ctypes.data, 1)
            assert got.tobytes() == (block @ u).tobytes()
            m = a[:k, :k] + np.diag(np.full(k, 1e3))
            col, rhs = np.asfortranarray(m).copy(order="F"), x[:k].copy()
            n, one, info, piv = i64(k), i64(1), i64(0), np.zeros(k, np.int64)
            gesv(ctypes.addressof(n), ctypes.addressof(one), col.ctypes.data,
                 ctypes.addressof(n), piv.ctypes.data, rhs.ctypes.data, ctypes.addressof(n),
                 ctypes.addressof(info))
            assert info.value == 0 and rhs.tobytes() == np.linalg.solve(m, x[:k]).tobytes()


def test_without_c_or_numpys_blas_the_python_steps_run(monkeypatch):
    """No `numpy_blas` (numpy built on another BLAS): no tail pass, the Python steps."""
    machine = build_reference_machine()
    monkeypatch.setattr(tail_c, "numpy_blas", lambda: None)
    obs = Observer(machine, sensor_suite("realistic", 1),
                   PayloadEstimator(machine, fourth="cylinder-force", strokes="clip"))
    assert obs._tail is None and isinstance(_tail.tail_pass(obs), type(None))
    assert Observer(machine, sensor_suite("realistic", 1),
                    PayloadEstimator(machine, fourth="cylinder-force"),
                    compiled=False)._tail is None
