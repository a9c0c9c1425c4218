"""The MPC context's servo state and brake trajectory in one compiled call
(`ServoState.observe_brake`, `wbc.controllers.servo_state_c.SERVO_BRAKE_C`): numpy's bits on
the closed loop's ticks and on odd ones; the plan's nodes made on first access; the glue
around the planner's context and solve that the loop runs every tick."""

import copy
import dataclasses

import numpy as np
import pytest

from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop
from testkit.plant import make_state, odd_servo_states
from wbc import load_estimator, make_controller
from wbc.axes import N_AXES
from wbc.context import ReferenceSample
from wbc.controllers.mpc import MpcController
from wbc.controllers.servo_state import ServoState
from wbc.controllers.servo_state_c import ServoPass
from wbc.errors import ConfigurationError
from wbc.layout import VariableLayout
from wbc.mpc.context import HorizonContext
from wbc.mpc.planner import MpcPlanner
from wbc.mpc.prediction import CondensedPrediction

DT = 0.01
PREDICTION = CondensedPrediction(VariableLayout(N_AXES, 12), [DT] + [0.1] * 11)
LO, HI = np.full(N_AXES, -0.5), np.full(N_AXES, 0.8)
ACCELERATION = np.linspace(0.3, 2.0, N_AXES)
ACCELERATION.setflags(write=False)
BRAKE = (PREDICTION.Lq, PREDICTION.Lv, PREDICTION.step_lengths, ACCELERATION)
# the axis limits' kind of arrays: read-only, owning their data
VELOCITY_LOWER = np.array(np.linspace(-0.4, -0.1, N_AXES))
VELOCITY_UPPER = np.array(np.linspace(0.1, 0.5, N_AXES))
VELOCITY_LOWER.setflags(write=False)
VELOCITY_UPPER.setflags(write=False)


def _braking(time_constant: float = 0.1) -> ServoState:
    return ServoState(DT, time_constant, LO, HI, times=PREDICTION.times, brake=BRAKE)


pytestmark = pytest.mark.skipif(_braking()._brake_of is None,
                                reason="no C compiler or not numpy's OpenBLAS")


def _pair(time_constant: float = 0.1):
    fast = _braking(time_constant)
    slow = ServoState(DT, time_constant, LO, HI, times=PREDICTION.times, compiled=False)
    assert fast._c.braking and slow._c is None
    return fast, slow


def _bits(*arrays) -> bytes:
    return b"".join(np.asarray(a, float).tobytes() for a in arrays)


def _state_bits(servo: ServoState) -> bytes:
    return _bits(servo.setpoint, servo.deflection, servo.rates)


def _want(slow: ServoState, state, prediction=PREDICTION, acceleration=ACCELERATION):
    """The numpy reference: `observe_free`, then the prediction's brake trajectory."""
    q, qd, qf, vf = slow.observe_free(state, prediction)
    return (q, qd, qf, vf, *prediction.brake_trajectory(q, qd, acceleration, (qf, vf)))


def _step(fast, slow, state, rates, qdd=None) -> None:
    """One tick on both: observe_brake (compared to the bit), then the commanded rates, or
    the rates `command` makes of the accelerations ``qdd`` (compared to the bit)."""
    got, want = fast.observe_brake(state, PREDICTION, ACCELERATION), _want(slow, state)
    assert [g.shape for g in got] == [w.shape for w in want]
    assert _bits(*got) == _bits(*want)
    assert _state_bits(fast) == _state_bits(slow)
    with np.errstate(all="ignore"):
        if qdd is None:
            fast.commanded(rates)
            slow.commanded(rates)
        else:
            got = fast.command(qdd, DT, VELOCITY_LOWER, VELOCITY_UPPER)
            assert _bits(got) == _bits(slow.command(qdd, DT, VELOCITY_LOWER, VELOCITY_UPPER))
    assert _state_bits(fast) == _state_bits(slow)


@pytest.fixture(scope="module")
def loop_ticks():
    """(state, commanded rates) of the MPC's ticks in 2 s of the default closed loop."""
    ticks = []
    observe_brake, commanded = ServoState.observe_brake, ServoState.commanded
    command = ServoState.command
    passes, commands = [], []

    def record_observe(self, state, prediction, acceleration):
        ticks.append([state, None])
        return observe_brake(self, state, prediction, acceleration)

    def record_commanded(self, rates):
        ticks[-1][1] = np.array(rates, float)
        return commanded(self, rates)

    def record_command(self, qdd, dt, lower, upper):  # the rates it commands
        ticks[-1][1] = np.array(command(self, qdd, dt, lower, upper), float)
        return ticks[-1][1].copy()

    def record_pass(self, *args, _f=ServoPass.observe_brake):
        passes.append(self)
        return _f(self, *args)

    def record_pass_command(self, *args, _f=ServoPass.command):
        commands.append(_f(self, *args))
        return commands[-1]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ServoState, "observe_brake", record_observe)
        mp.setattr(ServoState, "commanded", record_commanded)
        mp.setattr(ServoState, "command", record_command)
        mp.setattr(ServoPass, "observe_brake", record_pass)
        mp.setattr(ServoPass, "command", record_pass_command)
        run_closed_loop(DEFAULT_SCENARIO, None, "mpc-full", duration=2.0)
    assert len(ticks) > 150 and all(r is not None for _, r in ticks)
    # the loop's own ticks ran compiled (not the first observe), its commands every one
    assert len(passes) == len(ticks) - 1
    assert len(commands) == len(ticks) and all(r is not None for r in commands)
    return ticks


def test_closed_loop_ticks_are_the_numpy_paths_bits(loop_ticks):
    """The loop's states and commands, as they came and with setpoints to resync to."""
    for time_constant in (0.1, 0.0):
        fast, slow = _pair(time_constant)
        for k, (state, rates) in enumerate(loop_ticks):
            if k % 37 == 36:  # a wound-down servo: its setpoint far from the integrated one
                state = dataclasses.replace(state, servo_setpoint=state.servo_setpoint - 0.01)
            qdd = None if k % 3 == 0 else (rates - fast.rates) / DT  # about the loop's
            _step(fast, slow, state, rates, qdd)


def test_odd_ticks_are_the_numpy_paths_bits(machine):
    """No measured setpoint, time standing or going back, odd and huge rates (braked at
    the limit over several steps, or at rest at once), a reset."""
    rng = np.random.default_rng(7)
    fast, slow = _pair()
    for k, (reset, state) in enumerate(odd_servo_states(machine, rng, 2000, 500, DT)):
        if reset:
            fast.reset(), slow.reset()
        rates = rng.normal(0.0, rng.choice([0.0, 0.1, 3.0]), N_AXES)
        if k % 13 == 0:
            rates[rng.integers(N_AXES)] = rng.choice([np.nan, np.inf, -np.inf, 0.0, -0.0])
        qdd = None
        if k % 2:  # accelerations: some to the velocity limits exactly, through them, odd
            qdd = rng.normal(0.0, rng.choice([1.0, 30.0]), N_AXES)
            i = rng.integers(N_AXES)
            qdd[i] = rng.choice([(VELOCITY_UPPER[i] - fast.rates[i]) / DT, np.nan, np.inf,
                                 -np.inf, 0.0, -0.0])
        _step(fast, slow, state, rates, qdd)
        if qdd is not None and not np.isfinite(qdd).all():
            # a NaN in the state: the sign of a NaN made of two NaNs is the compiler's
            # (IEEE leaves it open), in the observe's sums as in numpy's; start anew
            fast.reset(), slow.reset()


def test_other_arrays_take_numpy(machine, monkeypatch):
    """Another prediction or other limits: `observe_free` and numpy's brake, their bits."""
    fast, slow = _pair()
    calls = []
    monkeypatch.setattr(ServoPass, "observe_brake",
                        lambda self, *a, _f=ServoPass.observe_brake: calls.append(self)
                        or _f(self, *a))
    state = make_state(machine)
    _step(fast, slow, state, np.full(N_AXES, 0.05))  # the first observe: numpy's anyway
    other = CondensedPrediction(VariableLayout(N_AXES, 5), 0.2)
    twice = ACCELERATION * 2.0
    for k in range(1, 4):
        later = dataclasses.replace(state, time=state.time + k * DT)
        prediction, limits = (other, ACCELERATION) if k == 1 else (PREDICTION, twice)
        if k == 3:
            prediction, limits = PREDICTION, np.array(ACCELERATION)  # equal, not the same
        got = fast.observe_brake(later, prediction, limits)
        assert _bits(*got) == _bits(*_want(slow, later, prediction, limits))
    assert calls == []
    later = dataclasses.replace(state, time=state.time + 5 * DT)
    assert _bits(*fast.observe_brake(later, PREDICTION, ACCELERATION)) == _bits(
        *_want(slow, later))
    assert calls == [fast._c]


def test_a_pass_without_the_shapes_has_no_brake():
    """Factors of another horizon, limits of other axes, a single step: no brake."""
    times = PREDICTION.times
    for brake in ((PREDICTION.Lq[:5, :5], PREDICTION.Lv, PREDICTION.step_lengths,
                   ACCELERATION),
                  (PREDICTION.Lq, PREDICTION.Lv, PREDICTION.step_lengths, ACCELERATION[:4])):
        assert not ServoPass.make(N_AXES, slice(0, 2), times, brake).braking
    one = CondensedPrediction(VariableLayout(N_AXES, 1), DT)
    assert not ServoPass.make(N_AXES, slice(0, 2), one.times,
                              (one.Lq, one.Lv, one.step_lengths, ACCELERATION)).braking


def test_a_deep_copy_brakes_on_buffers_of_its_own(machine):
    """The copy's pass: its own buffers and kept limits; both numpy's bits afterwards."""
    fast, slow = _pair()
    state = make_state(machine)
    _step(fast, slow, state, np.full(N_AXES, 0.05))
    twin, twin_slow = copy.deepcopy(fast), copy.deepcopy(slow)
    assert twin._c is not fast._c and twin._c.braking
    assert twin._c._brake[5] is not fast._c._brake[5]
    later = dataclasses.replace(state, time=state.time + DT)
    want = _want(slow, later)
    assert _bits(*fast.observe_brake(later, PREDICTION, ACCELERATION)) == _bits(*want)
    got = twin.observe_brake(later, PREDICTION, ACCELERATION)  # other `kept` arrays: numpy's
    assert _bits(*got) == _bits(*_want(twin_slow, later))


@pytest.fixture(scope="module")
def loop_plans():
    """(controller's context, plan, solution's inputs) of 60 ticks of the closed loop."""
    plans = []
    solve = MpcController._solve

    def record(self, state):
        out = solve(self, state)
        plan = self.last_plan
        plans.append((plan, np.array(plan.inputs), self.planner.prediction))
        return out

    contexts = []
    context = MpcPlanner.context

    def record_context(self, *args, **kwargs):
        contexts.append(context(self, *args, **kwargs))
        return contexts[-1]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(MpcController, "_solve", record)
        mp.setattr(MpcPlanner, "context", record_context)
        run_closed_loop(DEFAULT_SCENARIO, None, "mpc-full", duration=1.6)
    assert len(plans) == len(contexts) > 60
    return [(c, *p) for c, p in zip(contexts, plans)][-60:]


def test_plan_nodes_are_the_trajectory_of_the_solution(loop_plans):
    """The nodes made on first access: the prediction of the context's start under the
    solution's inputs, as the planner made them every tick before."""
    for ctx, plan, inputs, prediction in loop_plans:
        want = prediction.trajectory(ctx.q, ctx.qd, inputs,
                                     (ctx.free_positions, ctx.free_velocities))
        assert _bits(plan.positions, plan.velocities) == _bits(*want)
        assert plan.positions is plan.positions  # made once


def test_context_brake_is_the_planners_own(loop_plans):
    """The brake the servo's pass gave the planner: the planner's own of the same start."""
    for ctx, *_ in loop_plans:
        want = ctx.prediction.brake_trajectory(ctx.q, ctx.qd, ctx.limits.acceleration,
                                               (ctx.free_positions, ctx.free_velocities))
        assert _bits(ctx.brake_inputs, ctx.brake_positions, ctx.brake_velocities) == _bits(
            *want)


def test_nominal_inputs_are_the_shifted_rows(loop_plans):
    """`nominal_inputs`: the previous plan's rows at the shifted steps (numpy's indexing)."""
    for ctx, *_ in loop_plans[1:]:
        assert ctx.nominal_inputs.flags.owndata
    ctx, plan, inputs, prediction = loop_plans[-1]
    mp = MpcPlanner.__new__(MpcPlanner)
    mp.layout, mp.prediction, mp._shift = ctx.layout, prediction, None
    mp._plan, mp._plan_time = inputs, 1.0
    starts = prediction.start_times
    for elapsed in (0.0, DT, 0.05, 0.1, 0.35, 5.0):
        idx = np.clip(np.searchsorted(starts, starts + elapsed + 1e-9, side="right") - 1, 0,
                      len(starts) - 1)
        assert mp.nominal_inputs(1.0 + elapsed).tobytes() == inputs[idx].tobytes()


@pytest.mark.parametrize("bad", [[1.0, 2.0, np.nan, 0.0], [1.0, np.inf, 0.0, 0.0],
                                 [0.0, 0.0, -1e-300, 0.0], [1.0, 2.0, 3.0],
                                 [[1.0, 2.0, 3.0, 4.0]]])
def test_force_margin_refuses_what_check_margins_refuses(mpc_controller, bad):
    with pytest.raises(ConfigurationError, match="force margin must be 4 finite forces"):
        mpc_controller.set_force_margin(bad)


def test_force_margin_sets_the_thresholds(mpc_controller):
    c = mpc_controller
    for m in ([0.0, -0.0, 1.5, 2e3], np.array([3.0, 0.0, 0.25, 1e-300])):
        c.set_force_margin(m)
        want = c.force_thresholds + c.config.force.margin + np.asarray(m, float)
        assert c.force_constraint.thresholds.tobytes() == want.tobytes()
        assert c.force_margin.tobytes() == np.asarray(m, float).tobytes()


@pytest.fixture
def mpc_controller(machine):
    return make_controller("mpc-full", machine, force_model=load_estimator(machine, "full"))


def test_command_at_the_range_ends_and_other_limits(machine):
    """Setpoints driven into the range's ends (and the range's own zero), then limits the
    pass does not take (writable, or views): numpy's rates and state, to the bit."""
    fast = ServoState(DT, 0.1, np.zeros(N_AXES), HI, times=PREDICTION.times, brake=BRAKE)
    slow = ServoState(DT, 0.1, np.zeros(N_AXES), HI, times=PREDICTION.times, compiled=False)
    state = make_state(machine)
    for k in range(60):
        later = dataclasses.replace(state, time=state.time + k * DT)
        fast.observe_brake(later, PREDICTION, ACCELERATION)
        slow.observe_free(later, PREDICTION)
        qdd = np.full(N_AXES, (-1.0) ** (k // 20) * 50.0)
        qdd[0] = -0.0
        got = fast.command(qdd, DT, VELOCITY_LOWER, VELOCITY_UPPER)
        assert _bits(got) == _bits(slow.command(qdd, DT, VELOCITY_LOWER, VELOCITY_UPPER))
        assert _state_bits(fast) == _state_bits(slow)
    assert fast._c._limits[2] is not None  # the pass took the constant limits
    for lower, upper in ((np.array(VELOCITY_LOWER), VELOCITY_UPPER),
                         (VELOCITY_LOWER, np.concatenate([VELOCITY_UPPER] * 2)[:N_AXES])):
        qdd = np.linspace(-3.0, 3.0, N_AXES)
        assert fast._c.command(qdd, DT, lower, upper, DT) is None
        got = fast.command(qdd, DT, lower, upper)
        assert _bits(got) == _bits(slow.command(qdd, DT, lower, upper))
        assert _state_bits(fast) == _state_bits(slow)


def test_reference_sample_of_is_the_constructor():
    fields = [np.arange(3.0) + k for k in range(3)]
    fast, slow = ReferenceSample.of(*fields), ReferenceSample(*fields)
    assert list(vars(fast)) == list(vars(slow)) == ["position", "velocity", "acceleration"]
    assert all(vars(fast)[n] is vars(slow)[n] for n in vars(slow))
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.position = fields[1]


def test_assembled_context_is_the_constructor(loop_plans):
    """`HorizonContext.assemble`: the dataclass's fields in its order, as its ``__init__``
    sets them, the optional ones defaulted."""
    ctx = loop_plans[-1][0]
    names = [f.name for f in dataclasses.fields(HorizonContext)]
    values = {n: vars(ctx)[n] for n in names}
    slow = HorizonContext(**values)
    assert list(vars(ctx))[:len(names)] == list(vars(slow)) == names
    assert all(vars(ctx)[n] is vars(slow)[n] for n in names)
    required = [n for n in names if n not in ("feedback", "warp", "leveling_offset",
                                              "warp_drift")]
    bare = HorizonContext.assemble(*(values[n] for n in required))
    assert list(vars(bare)) == names and bare.feedback is None and bare.leveling_offset == 0.0


def test_node_samples_refuse_arrays_they_cannot_write(machine):
    """Read-only or strided node arrays: None, nothing written (numpy's path takes them)."""
    from wbc import CRANE_AXES, AxisLimits, RuckigReference

    limits = AxisLimits.from_machine(machine)
    ref = RuckigReference(limits, CRANE_AXES)
    lo, hi = limits.position_lower[CRANE_AXES], limits.position_upper[CRANE_AXES]
    ref.plan(0.0, lo + 0.1 * (hi - lo), np.zeros(7), np.zeros(7), lo + 0.6 * (hi - lo))
    offsets = np.linspace(0.0, 1.2, 13)
    good = [np.zeros((13, 9)) for _ in range(3)]
    frozen = np.zeros((13, 9))
    frozen.setflags(write=False)
    strided = np.zeros((13, 18))[:, ::2]
    first = ref.index.start
    for bad in (frozen, strided):
        arrays = [good[0], bad, good[2]]
        assert ref._compiled.sample_nodes(0.2, 1.0, offsets, 0.0, first, *arrays) is None
        assert not good[0].any() and not good[2].any()
    assert ref._compiled.sample_nodes(0.2, 1.0, offsets, 0.0, first, *good) is not None
    assert good[0].any()
    want = [np.zeros((13, 9)) for _ in range(3)]
    ref.sample_columns_into(0.2 + 1.0 * offsets, 1.0, *want)
    assert _bits(*good) == _bits(*want)


def test_finite_nonnegative_is_numpys_answer():
    from models.numeric import finite_nonnegative

    rng = np.random.default_rng(3)
    odd = [np.nan, -np.nan, np.inf, -np.inf, 0.0, -0.0, -5e-324, 5e-324, 1.7e308, -1.0]
    for _ in range(3000):
        x = rng.normal(100.0, 300.0, 4)
        x[rng.random(4) < 0.3] = rng.choice(odd)
        want = bool(np.isfinite(x).all() and not (x < 0).any())
        assert finite_nonnegative(x.tolist()) is want


def test_structure_key_is_made_once_and_kept(loop_plans):
    ctx = loop_plans[-1][0]
    fresh = HorizonContext.assemble(*(vars(ctx)[f.name] for f in dataclasses.fields(ctx)
                                      if f.name not in ("feedback", "warp", "leveling_offset",
                                                        "warp_drift")))
    assert "structure_key" not in vars(fresh)
    key = fresh.structure_key
    assert key == (ctx.prediction.structure_key, ctx.dt) and fresh.structure_key is key
    assert vars(fresh)["structure_key"] is key
    with pytest.raises(dataclasses.FrozenInstanceError):
        fresh.structure_key = key
