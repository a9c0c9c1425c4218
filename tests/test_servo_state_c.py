"""The servo state's observe and free response in C (`wbc.controllers.servo_state_c`):
numpy's bits, on the closed loop's ticks and on odd ones."""

import copy
import dataclasses
import types

import numpy as np
import pytest

from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop
from testkit.plant import make_state, odd_servo_states
from wbc.axes import N_AXES
from wbc.controllers.servo_state import ServoState
from wbc.controllers.servo_state_c import ServoPass
from wbc.layout import VariableLayout
from wbc.mpc.prediction import CondensedPrediction

DT = 0.01
PREDICTION = CondensedPrediction(VariableLayout(N_AXES, 12), [DT] + [0.1] * 11)
LO, HI = np.full(N_AXES, -0.5), np.full(N_AXES, 0.8)

pytestmark = pytest.mark.skipif(
    ServoState(DT, 0.1, LO, HI, times=PREDICTION.times)._c is None, reason="no C compiler")


def _pair(time_constant: float = 0.1):
    fast = ServoState(DT, time_constant, LO, HI, times=PREDICTION.times)
    slow = ServoState(DT, time_constant, LO, HI, times=PREDICTION.times, compiled=False)
    assert fast._c is not None and slow._c is None
    return fast, slow


def _bits(*arrays) -> bytes:
    return b"".join(np.asarray(a, float).tobytes() for a in arrays)


def _state_bits(servo: ServoState) -> bytes:
    return _bits(servo.setpoint, servo.deflection, servo.rates)


def _step(fast, slow, state, rates) -> None:
    """One tick on both: observe_free (compared to the bit), then the commanded rates."""
    got, want = fast.observe_free(state, PREDICTION), slow.observe_free(state, PREDICTION)
    assert [g.shape for g in got] == [w.shape for w in want]
    assert _bits(*got) == _bits(*want)
    assert _state_bits(fast) == _state_bits(slow)
    with np.errstate(all="ignore"):
        fast.commanded(rates)
        slow.commanded(rates)
    assert _state_bits(fast) == _state_bits(slow)


@pytest.fixture(scope="module")
def loop_ticks():
    """(state, commanded rates) of the MPC's ticks in 2 s of the default closed loop."""
    ticks = []
    observe_brake, commanded = ServoState.observe_brake, ServoState.commanded
    command = ServoState.command

    def record_observe(self, state, prediction, acceleration):
        ticks.append([state, None])
        return observe_brake(self, state, prediction, acceleration)

    def record_commanded(self, rates):
        ticks[-1][1] = np.array(rates, float)
        return commanded(self, rates)

    def record_command(self, qdd, dt, lower, upper):  # the rates it commands
        ticks[-1][1] = np.array(command(self, qdd, dt, lower, upper), float)
        return ticks[-1][1].copy()

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ServoState, "observe_brake", record_observe)
        mp.setattr(ServoState, "commanded", record_commanded)
        mp.setattr(ServoState, "command", record_command)
        run_closed_loop(DEFAULT_SCENARIO, None, "mpc-full", duration=2.0)
    assert len(ticks) > 150 and all(r is not None for _, r in ticks)
    return ticks


def test_closed_loop_ticks_are_the_numpy_paths_bits(loop_ticks):
    """The loop's states and commands, as they came and with setpoints to resync to."""
    for time_constant in (0.1, 0.0):
        fast, slow = _pair(time_constant)
        for k, (state, rates) in enumerate(loop_ticks):
            if k % 37 == 36:  # a wound-down servo: its setpoint far from the integrated one
                state = dataclasses.replace(state, servo_setpoint=state.servo_setpoint - 0.01)
            _step(fast, slow, state, rates)


def test_odd_ticks_are_the_numpy_paths_bits(machine):
    """No measured setpoint, near ones, time standing or going back, odd rates, a reset."""
    rng = np.random.default_rng(5)
    fast, slow = _pair()
    for k, (reset, state) in enumerate(odd_servo_states(machine, rng, 3000, 700, DT)):
        if reset:
            fast.reset(), slow.reset()
        rates = rng.normal(0.0, 0.1, N_AXES)
        if k % 13 == 0:
            rates[rng.integers(N_AXES)] = rng.choice([np.nan, np.inf, -np.inf, 0.0, -0.0])
        _step(fast, slow, state, rates)


def test_another_prediction_takes_numpy(machine):
    """``observe_free`` of a prediction with other times: numpy's, its free response."""
    fast, slow = _pair()
    other = CondensedPrediction(VariableLayout(N_AXES, 5), 0.2)
    state = make_state(machine)
    for _ in range(3):
        got, want = fast.observe_free(state, other), slow.observe_free(state, other)
        assert _bits(*got) == _bits(*want) and got[2].shape == (5, N_AXES)
        state = dataclasses.replace(state, time=state.time + DT)


def test_a_deep_copy_runs_on_buffers_of_its_own(machine, monkeypatch):
    """The copy's C pass on its own buffers (at its copy of the times), the original's
    unchanged by it: both numpy's bits."""
    fast, slow = _pair()
    state = make_state(machine)
    _step(fast, slow, state, np.full(N_AXES, 0.05))
    twin = copy.deepcopy(fast)
    assert twin._c is not fast._c and twin.setpoint is twin._c.setpoint
    assert twin.rates is twin._c.rates and twin.deflection is twin._c.deflection
    # a prediction with the copy's times array (a controller's prediction is not copied)
    twin_prediction = types.SimpleNamespace(times=twin._times,
                                            free_response=PREDICTION.free_response)
    calls = []
    monkeypatch.setattr(ServoPass, "observe",
                        lambda self, *a, _f=ServoPass.observe: calls.append(self) or _f(self, *a))
    later = dataclasses.replace(state, time=state.time + DT)
    want = slow.observe_free(later, PREDICTION)
    assert _bits(*twin.observe_free(later, twin_prediction)) == _bits(*want)
    assert _bits(*fast.observe_free(later, PREDICTION)) == _bits(*want)
    assert calls == [twin._c, fast._c]
