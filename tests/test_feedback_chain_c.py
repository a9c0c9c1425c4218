"""The MPC's load-split chain in C (`wbc.force_models.chain_c`): numpy's bits, tick by tick.

The chain's inputs are recorded on a closed-loop run (pick-in-motion's first seconds:
standing, then driving), then replayed into two controllers of the run's machine and
configuration, one with the chain and one on numpy's steps (`MpcController.
_feedback_steps`): the feedback, the leveling offset, the warp drift, the speed cap, the
side reserve and every part's state must have the same bits after every tick. The same
ticks again with lifted wheels, odd loads and speeds, no measured setpoints, time standing
or going back, resets, and thresholds that make the governor's cap bind.
"""

import dataclasses
import math
import tempfile

import numpy as np
import pytest

from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop
from wbc.controllers.mpc import MpcController
from wbc.controllers.registry import make_controller
from wbc.force_models import chain_c
from wbc.force_models.feedback import ForceFeedback

pytestmark = pytest.mark.skipif(chain_c._library() is None or chain_c.numpy_blas() is None,
                                reason="no C compiler or not numpy's OpenBLAS")


@pytest.fixture(scope="module")
def recorded():
    """(machine, config, ticks): the chain's inputs at every tick of a 2.5 s closed loop."""
    ticks, kept = [], {}
    original = MpcController._chained_feedback

    def record(self, measured, state, q):
        kept["ctrl"] = self
        ticks.append((measured, state, q.copy(), self.force_constraint.thresholds.copy(),
                      self._speed_scale,
                      None if self.servo.setpoint is None else self.servo.setpoint.copy()))
        return original(self, measured, state, q)

    MpcController._chained_feedback = record
    try:
        run_closed_loop(DEFAULT_SCENARIO, tempfile.mkdtemp(), "mpc-full", duration=2.5,
                        progress=False)
    finally:
        MpcController._chained_feedback = original
    ctrl = kept["ctrl"]
    return ctrl.machine, ctrl.config, ticks


def _pair(machine, config):
    fast = make_controller("mpc-full", machine, config)
    slow = make_controller("mpc-full", machine, config)
    slow._chain = None
    assert fast._chain is not None
    return fast, slow


def _bits(*values) -> bytes:
    out = []
    for v in values:
        if v is None:
            out.append(b"None")
        elif isinstance(v, tuple):
            out.append(b"(" + _bits(*v) + b")")
        else:
            out.append(np.asarray(v, float).tobytes())
    return b"|".join(out)


def _state_bits(ctrl) -> bytes:
    g, d, s = ctrl.governor, ctrl.warp_drift, ctrl.side_swing
    return _bits(g._time, g.mean, g._square, g.per_speed, g.scale_lag, g._speed_square,
                 d.rate, d._last, s._time, s.speed, s.mean, s._square, s.sigma,
                 ctrl.speed_limit.cap, ctrl.side_reserve.reserve,
                 ctrl.last_feedback.forces, ctrl.last_feedback.in_contact)


def _tick(ctrl, tick, run):
    measured, state, q, thresholds, scale, setpoint = tick
    ctrl.force_constraint.thresholds = thresholds
    ctrl._speed_scale = scale
    if setpoint is None:
        ctrl.servo.setpoint = None
    else:
        ctrl.servo.setpoint = ctrl.servo._setpoint
        ctrl.servo.setpoint[:] = setpoint
    with np.errstate(all="ignore"):
        out = run(measured, state, q)
    assert out is not None
    fb, offset, drift = out
    return _bits(fb.forces, fb.model_forces, fb.in_contact, fb.time, offset, drift)


def _replay(fast, slow, ticks) -> list[float]:
    """Both controllers through ``ticks``; the speed caps."""
    caps = []
    for k, tick in enumerate(ticks):
        got = _tick(fast, tick, fast._chained_feedback)
        want = _tick(slow, tick, slow._feedback_steps)
        assert got == want, k
        assert _state_bits(fast) == _state_bits(slow), k
        caps.append(fast.speed_limit.cap)
    return caps


def test_closed_loop_ticks_are_numpys_bits(recorded):
    machine, config, ticks = recorded
    assert len(ticks) > 200
    _replay(*_pair(machine, config), ticks)


def test_with_the_side_swing_measured(recorded):
    """``side_reserve_z > 0``: the swing's measure stays numpy's, after the call."""
    machine, config, ticks = recorded
    config = dataclasses.replace(config, force=dataclasses.replace(config.force,
                                                                   side_reserve_z=2.0))
    _replay(*_pair(machine, config), ticks)


def test_caps_below_one_are_numpys_bits(recorded):
    """Thresholds near the slow loads while driving: the governor's cap binds, any wheel."""
    machine, config, ticks = recorded
    rng = np.random.default_rng(8)
    fast, slow = _pair(machine, config)
    caps = []
    for m, state, q, thr, scale, setpoint in ticks:
        mean = fast.governor.mean
        if mean is not None:
            thr = mean - rng.uniform(-50.0, 300.0, 4)
        caps += _replay(fast, slow, [(m, state, q, thr, scale, setpoint)])
    assert sum(0.0 < c < 1.0 for c in caps) > 20


ODD = [0.0, -0.0, np.nan, np.inf, -np.inf, 1e-300, -5e3]


def _odd(ticks, rng):
    """The recorded ticks with odd contacts, loads, speeds, setpoints, times and scales."""
    out = []
    t_shift = 0.0
    for k, (m, state, q, thr, scale, setpoint) in enumerate(ticks):
        forces, contact, time = m.forces.copy(), m.in_contact.copy(), m.time
        if k % 7 == 0:
            contact[rng.integers(4)] = False
        if k % 11 == 0:
            forces[rng.integers(4)] = rng.choice(ODD)
        if k % 13 == 0:
            t_shift -= rng.choice([0.0, 0.01, 0.03])  # time standing or going back
        if k % 9 == 0:
            thr = thr.copy()
            thr[rng.integers(4)] = rng.choice(ODD)
        if k % 17 == 0:
            scale = float(rng.choice([0.0, 0.04, 0.5, 1.0]))
        if k % 19 == 0:
            setpoint = None
        fields = {}
        if k % 23 == 0:
            fields["servo_setpoint"] = None
        if k % 29 == 0:
            twist = state.base_twist.copy()
            twist[:2] = rng.choice([1e200, 1e-3, 2.0, 0.0, -0.0], 2)  # 1e200: hypot inf
            fields["base_twist"] = twist
        if fields:
            state = dataclasses.replace(state, **fields)
        m = ForceFeedback.of(forces, m.model_forces, contact, time + t_shift)
        out.append((m, state, q, thr, scale, setpoint))
    return out


def test_odd_ticks_are_numpys_bits(recorded):
    machine, config, ticks = recorded
    rng = np.random.default_rng(5)
    fast, slow = _pair(machine, config)
    odd = _odd(ticks, rng)
    half = len(odd) // 2
    _replay(fast, slow, odd[:half])
    fast.reset(), slow.reset()
    _replay(fast, slow, odd[half:])


def test_the_chain_compensates_on_closed_loop_ticks(recorded):
    """It runs the whole chain there: compensated splits, a drift, the machine driving."""
    machine, config, ticks = recorded
    fast, _ = _pair(machine, config)
    compensated = 0
    for tick in ticks:
        _tick(fast, tick, fast._chained_feedback)
        compensated += fast.last_feedback is not tick[0]
    assert compensated > len(ticks) // 2
    assert fast.warp_drift.rate != 0.0 and math.isfinite(fast.warp_drift.rate)
    assert fast.side_swing.driving


def test_without_the_chain_the_numpy_steps_run(machine):
    ctrl = make_controller("mpc-full", machine)
    off = MpcController(machine, ctrl.config, force_model=ctrl.force_model,
                        feedback=ctrl.feedback, compiled=False)
    assert off._chain is None and off.governor is not None


@pytest.mark.parametrize("off", [{"governor_z": 0.0}, {"drift_horizon": 0.0},
                                 {"side_reserve": 0.0},
                                 {"governor_z": 0.0, "drift_horizon": 0.0,
                                  "side_reserve": 0.0}])
def test_without_some_parts_numpys_bits(recorded, off):
    """The chain with the governor, the drift or the side reserve off (its flags)."""
    machine, config, ticks = recorded
    config = dataclasses.replace(config, force=dataclasses.replace(config.force, **off))
    fast, slow = _pair(machine, config)
    for k, tick in enumerate(_odd(ticks, np.random.default_rng(6))):
        assert _tick(fast, tick, fast._chained_feedback) == _tick(slow, tick,
                                                                 slow._feedback_steps), k
        parts = [(p, getattr(fast, p)) for p in ("governor", "warp_drift", "side_swing")]
        assert all((x is None) == (getattr(slow, p) is None) for p, x in parts)
        assert _bits(fast.speed_limit.cap, fast.side_reserve and fast.side_reserve.reserve,
                     fast.warp_drift and fast.warp_drift.rate) == _bits(
            slow.speed_limit.cap, slow.side_reserve and slow.side_reserve.reserve,
            slow.warp_drift and slow.warp_drift.rate), k
