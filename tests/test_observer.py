"""The observer on MuJoCo runs: payload after a pick, contact flags, attitude, bad readings."""

import dataclasses

import numpy as np
import pytest

from estimators.errors import EstimatorError
from estimators.observer import (
    CONTACT_LANDING_N,
    CONTACT_OFF_N,
    CONTACT_ON_N,
    CONTACT_TICKS,
    Observer,
)
from estimators.observer.contacts import ContactTracker
from estimators.observer.payload_rls import EVENT_TICKS, EXPECTED_PICK_TICKS
from estimators.payload import PayloadEstimator
from models import build_reference_machine
from models import terrain as T
from models.sensing import Samples
from models.sensor_suites import chassis_only, sensor_suite
from scenarios.closed_loop import _set_payload
from scenarios.closed_loop_scenarios import SCENARIOS
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator

PICK_POSE = SCENARIOS["pick-in-motion"].start_pose  # crane out on the downhill side


def _observer(machine, suite="realistic", seed=2, prior=None):
    """An observer with the closure it runs in the loop; ``suite``: a name or a `SensorSpec`."""
    spec = sensor_suite(suite, seed) if isinstance(suite, str) else suite
    closure = PayloadEstimator(machine, fourth="cylinder-force", strokes="clip")
    return Observer(machine, spec, closure, initial_payload=prior)


def _pick_run(seed, mass, slope, grapple_tick=None, pick=True, chassis=False):
    """5 s standing at the pick pose: the grapple command at ``grapple_tick`` (None: none),
    a sudden pick (10 kg -> mass) at 2 s, held still 0.2 s (the seals stick), then lifted.
    Returns the events (tick, kind), the estimates at ticks 199 and 399, and the last one."""
    machine = build_reference_machine(payload_mass=10.0)
    sim = Simulator(machine, T.side_slope(slope))
    sim.reset(PICK_POSE.q(machine), (8.0, 0.0, 0.0))
    spec = sensor_suite("realistic", seed)
    spec = chassis_only(spec) if chassis else spec
    sensors = SensorSimulator(sim, spec)
    obs = _observer(machine, spec, prior=10.0)
    events, at = [], {}
    for k in range(500):
        if k == grapple_tick:
            obs.expect_pick(sim.time)
        if k == 200 and pick:
            _set_payload(sim, mass)
        if k == 220:
            sim.set_command(cylinder_rates={"lift": 0.02, "tilt": 0.02})
        sim.step(5)
        e = obs.update(sensors.readings(sim.time))
        if e.payload_event:
            events.append((k, e.payload_event))
        if k in (199, 399):
            at[k] = e.payload_mass
    return events, at, e


PICKS = pytest.mark.parametrize("seed,mass,slope", [(2, 240.0, -5.0), (17, 300.0, -8.0)],
                                ids=["240kg", "300kg-held-out"])


@PICKS
def test_payload_within_5_percent_2_s_after_a_pick(seed, mass, slope):
    """A sudden pick from an empty grapple, held still 0.2 s (the seals stick), then lifted.

    Seed 2 is the one the regression filter and the event test were tuned on; seed 17 with
    300 kg on a steeper slope was not.
    """
    events, at, e = _pick_run(seed, mass, slope)
    assert at[199] == pytest.approx(10.0, abs=0.05 * mass)
    assert at[399] == pytest.approx(mass, rel=0.05)  # within 2 s
    assert e.payload_mass == pytest.approx(mass, rel=0.05)  # 3 s after the pick
    assert [kind for _, kind in events] == ["pick"]  # one event, no false release
    assert 200 <= events[0][0] <= 230
    assert 0.0 < e.payload_std < 0.05 * mass


@PICKS
def test_the_grapple_command_lets_a_pick_be_seen_sooner(seed, mass, slope):
    """After the operator's grapple command (1 s before the pick) a growing mass is an event
    after EXPECTED_PICK_TICKS instead of EVENT_TICKS; the lift after it raises no release.
    (The chassis-only sensor set: with the link accelerometers the estimate follows the pick
    within a tick either way, `tests/test_link_accelerometers.py`.)"""
    before, _, _ = _pick_run(seed, mass, slope, chassis=True)
    events, at, e = _pick_run(seed, mass, slope, grapple_tick=100, chassis=True)
    assert [kind for _, kind in events] == ["pick"]
    assert events[0][0] <= before[0][0] - (EVENT_TICKS - EXPECTED_PICK_TICKS)
    assert at[399] == pytest.approx(mass, rel=0.05)
    assert e.payload_mass == pytest.approx(mass, rel=0.05)


def test_a_grapple_command_without_a_pick_raises_no_event():
    """An empty grab: the grapple command, no load, then the lift (the expectation lapses)."""
    events, _, e = _pick_run(2, 0.0, -5.0, grapple_tick=100, pick=False)
    assert events == []
    assert e.payload_mass == pytest.approx(10.0, abs=15.0)


def test_contact_flags_right_where_the_force_is_clear():
    """A wheel lifts (crane out at full reach on a side slope): every sample with a true
    force above 1 kN is flagged in contact, every sample at zero force out of contact."""
    machine = build_reference_machine(payload_mass=150.0)
    sim = Simulator(machine, T.side_slope(-12.0))
    sim.reset(None, (8.0, 0.0, 0.0))
    sensors = SensorSimulator(sim, sensor_suite("realistic", 4))
    obs = _observer(machine, prior=150.0)
    wrong, zero_seen = 0, 0
    for k in range(700):  # the operator ramps the motion up over a second, after one at rest
        ramp = min(max((k - 100) / 100.0, 0.0), 1.0)
        sim.set_command(cylinder_rates={"slew": 0.12 * ramp, "telescope": 0.25 * ramp,
                                        "lift": -0.05 * ramp})
        sim.step(5)
        e = obs.update(sensors.readings(sim.time))
        truth = sim.measure()[1]
        f = truth.normal_force
        flags = e.state.contacts.in_contact
        wrong += int(np.sum(flags[f > 1000.0] == False))  # noqa: E712
        wrong += int(np.sum(flags[f <= 0.0] == True))  # noqa: E712
        zero_seen += int(np.sum(f <= 0.0))
    assert zero_seen > 0, "the scenario should lift a wheel"
    assert wrong == 0


@pytest.mark.parametrize("compiled", [True, False])
def test_a_lifted_wheel_comes_back_after_its_ticks_or_at_once_on_landing(compiled):
    """The flags' state machine: off below `CONTACT_OFF_N`; back after `CONTACT_TICKS`
    ticks above `CONTACT_ON_N`, or at once above `CONTACT_LANDING_N` (an impact); in C
    and in Python."""
    tracker = ContactTracker(0.6, 10.0, True, compiled)
    heavy, between = 1e4, 0.5 * (CONTACT_ON_N + CONTACT_LANDING_N)

    def tick(rl):
        flags, _, _ = tracker.update(np.array([heavy, rl, heavy, heavy]))
        assert flags.tolist() == tracker.in_contact
        return tracker.in_contact[1]

    assert tick(heavy)
    assert not tick(0.5 * CONTACT_OFF_N)  # lifts at once
    assert [tick(between) for _ in range(CONTACT_TICKS)] == [False] * (CONTACT_TICKS - 1) + [True]
    assert tick(CONTACT_OFF_N)  # hysteresis: stays down to the off level
    assert not tick(0.0)
    assert not tick(0.99 * CONTACT_LANDING_N)  # a bounce in the air's range is not a landing
    assert not tick(0.0)  # ... and the count starts again
    assert tick(1.01 * CONTACT_LANDING_N)  # an impact: back at once


def test_attitude_at_rest_and_stale_on_nan():
    machine = build_reference_machine()
    sim = Simulator(machine, T.side_slope(-10.0))
    sim.reset(None, (8.0, 0.0, 0.4))
    sensors = SensorSimulator(sim, sensor_suite("realistic", 1))
    obs = _observer(machine)
    for _ in range(200):
        sim.step(5)
        e = obs.update(sensors.readings(sim.time))
    up_true = sim.measure()[0].base_rotation[2]
    assert np.degrees(np.arccos(up_true @ e.state.base_rotation[2])) < 0.1
    sim.step(5)
    r = sensors.readings(sim.time)
    bad = dataclasses.replace(r, pressures=Samples(r.pressures.time,
                                                   np.full(r.pressures.value.shape, np.nan)))
    held = obs.update(bad)
    assert held.stale and np.all(np.isfinite(held.state.suspension_force))
    with pytest.raises(EstimatorError, match="SensorReadings"):
        obs.update("readings")
    with pytest.raises(EstimatorError, match="oracle"):
        _observer(machine, suite="oracle")


def test_attitude_while_turning_and_swinging():
    """Ideal sensors, a skid-steer turn with the crane slewing on flat ground: within 0.3 deg.

    The filter pulls the estimate towards gravity as the IMU sees it less the motion the
    odometry knows (w x v, v_dot). Pulling towards the specific force low-passed in the
    chassis frame was 1.1 deg off on average on the flat run (the turns' centripetal
    acceleration and a lag of the rotating chassis).
    """
    machine = build_reference_machine()
    sim = Simulator(machine, T.flat())
    sensors = SensorSimulator(sim, sensor_suite("ideal", 1))
    obs = _observer(machine, suite="ideal")
    worst = 0.0
    for k in range(800):
        t = 0.01 * k
        sim.set_command(cylinder_rates={"slew": 0.05 * np.sin(1.5 * t)},
                        wheel_speeds=(0.4, 1.8) if k >= 100 else (0.0, 0.0))
        sim.step(5)
        e = obs.update(sensors.readings(sim.time))
        if k >= 200:
            up_true = sim.measure()[0].base_rotation[2]
            worst = max(worst, np.degrees(np.arccos(min(up_true @ e.state.base_rotation[2],
                                                        1.0))))
    assert worst < 0.3


def test_crane_accelerations_from_the_pressures():
    """Slew, lift and tilt swing (sliding seals). Oracles: MuJoCo's exact slew acceleration
    (`Simulator.measure`) and its contact forces. The slew's acceleration from its pressures
    is more than twice as close as the encoders' alone; the lift's and tilt's are not closer
    (their reflected inertia is smaller against the transducers' noise), but the closure
    made consistent with the measured cylinder forces is: its four-wheel forces move closer
    to MuJoCo's. The chassis-only sensor set (with the link accelerometers the encoders'
    slew acceleration is already closer than the pressures', `docs/sensors.md`)."""
    acc, force = {}, {}
    for from_pressures in (False, True):
        machine = build_reference_machine(payload_mass=150.0)
        sim = Simulator(machine, T.side_slope(-3.0))
        sim.reset(PICK_POSE.q(machine), (8.0, 0.0, 0.0))
        spec = chassis_only(sensor_suite("realistic", 7))
        sensors = SensorSimulator(sim, spec)
        obs = _observer(machine, spec, prior=150.0)
        obs.crane_from_pressures = from_pressures
        da, df = [], []
        for k in range(300):
            t = 0.01 * k
            sim.set_command(cylinder_rates={"slew": 0.05 * np.sin(1.5 * t),
                                            "lift": 0.04 * np.sin(2.0 * t),
                                            "tilt": 0.04 * np.cos(2.5 * t)})
            sim.step(5)
            est = obs.update(sensors.readings(sim.time))
            if k >= 100:
                truth, contacts = sim.measure()
                da.append(est.state.qdd[2] - truth.qdd[2])
                df.append(np.abs(est.forces_four - contacts.fz_in_fb).mean())
        acc[from_pressures] = float(np.sqrt(np.mean(np.square(da))))
        force[from_pressures] = float(np.mean(df))
    assert acc[True] < 0.5 * acc[False], acc
    assert force[True] < 0.9 * force[False], force


def test_ground_normal_of_the_touching_wheels():
    """The plane through three or four wheel centres on a tilted plane gives its normal."""
    from estimators.observer._vec3 import ground_normal as _ground_normal
    from models.rotations import rpy_rotation

    tilt = rpy_rotation(0.3, 0.2, -0.15)  # a plane tilted in pitch and roll
    flat_centres = np.array([[1.2, 0.9, 0.6], [-1.4, 0.9, 0.6], [1.2, -0.9, 0.6],
                             [-1.4, -0.9, 0.6]])
    centres = flat_centres @ tilt.T
    normal = tilt[:, 2]
    for touching in ([1, 1, 1, 1], [1, 0, 1, 1], [0, 1, 1, 1]):
        n = _ground_normal(centres, np.array(touching, bool))
        assert n == pytest.approx(normal, abs=1e-12)
    assert _ground_normal(centres, np.array([1, 0, 0, 1], bool)) == pytest.approx([0, 0, 1])


def test_contact_points_against_mujoco_with_the_bogies_pitched():
    """Bogies pitched in opposition on rough ground: the chassis is not parallel to the
    ground, the plane of the touching wheels is. Oracle: MuJoCo's contact points."""
    machine = build_reference_machine(payload_mass=150.0)
    sim = Simulator(machine, T.rough(7, max_slope_deg=20.0))
    sim.reset(None, (2.0, 0.0, 0.0))
    sensors = SensorSimulator(sim, sensor_suite("ideal", 3))
    obs = _observer(machine, suite="ideal", prior=150.0)
    err_plane, err_chassis = [], []
    for k in range(400):
        phase = 2 * np.pi * 0.4 * k * 0.01
        sim.set_command(cylinder_rates={"bogie_L": 0.04 * np.cos(phase),
                                        "bogie_R": -0.04 * np.cos(phase)},
                        wheel_speeds=(0.4, 0.4))
        sim.step(5)
        e = obs.update(sensors.readings(sim.time))
        truth = sim.measure()[1]
        if k < 100:
            continue
        on = truth.in_contact & e.state.contacts.in_contact
        centres = truth.point_in_fb + machine.wheel_radius * truth.normal_in_fb
        below = centres - machine.wheel_radius * np.array([0.0, 0.0, 1.0])
        err_plane.extend(np.linalg.norm(e.state.contacts.point_in_fb - truth.point_in_fb,
                                        axis=1)[on])
        err_chassis.extend(np.linalg.norm(below - truth.point_in_fb, axis=1)[on])
    assert np.mean(err_plane) < 0.5 * np.mean(err_chassis)
    assert np.mean(err_plane) < 0.01  # measured 5 mm against 17 mm


def _glitched_drive(ticks, at, spoil, compiled=True, slew=0.0):
    """Driving on a 5 deg side slope (the slew at ``slew`` [rad/s]) with the realistic
    sensors, tick ``at``'s readings spoiled by ``spoil(readings, observer)``: that tick's
    estimate is stale, every other one is not, and nothing non-finite gets out. Returns the
    estimates."""
    machine = build_reference_machine()
    sim = Simulator(machine, T.side_slope(-5.0))
    sim.reset(None, (8.0, 0.0, 0.0))
    spec = sensor_suite("realistic", 3)
    sensors = SensorSimulator(sim, spec)
    obs = Observer(machine, spec, PayloadEstimator(machine, fourth="cylinder-force",
                                                   strokes="clip"), compiled=compiled)
    sim.set_command(cylinder_rates={"slew": slew}, wheel_speeds=(0.5, 0.5))
    estimates = []
    for k in range(ticks):
        sim.step(5)
        r = sensors.readings(sim.time)
        if k == at:
            r = spoil(r, obs)
        e = obs.update(r)
        assert e.stale == (k == at), k
        st = e.state
        for a in (st.base_rotation, st.base_twist, st.base_acceleration, st.q, st.qd, st.qdd,
                  st.contacts.force_in_fb, e.forces_four):
            assert np.all(np.isfinite(a)), k
        assert np.isfinite(e.payload_mass) and np.isfinite(e.payload_std)
        estimates.append(e)
    return estimates


@pytest.mark.parametrize("stream", ["specific_force", "angular_rate", "positions", "pressures",
                                    "wheel_speeds", "drive_torques"])
def test_a_nan_reading_is_held_for_its_tick_and_the_observer_recovers(stream):
    """A glitch on one stream (NaN on every sample of one tick): that tick is held and
    marked stale, the next good readings are used again, and nothing non-finite gets out."""
    def spoil(r, obs):
        s = getattr(r, stream)
        assert len(s), f"{stream} delivered nothing this tick"
        return dataclasses.replace(r, **{stream: Samples(s.time, np.full(s.value.shape,
                                                                         np.nan))})

    _glitched_drive(120, 60, spoil)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("stream, value", [("angular_rate", 1e155), ("angular_rate", 40.0),
                                           ("specific_force", 1e155),
                                           ("specific_force", -120.0)])
def test_an_imu_sample_beyond_full_scale_is_a_fault_held_for_its_tick(stream, value, compiled):
    """One gyroscope or accelerometer sample beyond the MTi-630's range (2000 deg/s, 10 g):
    a corrupted sample, refused before the chassis filter sees it; the observer goes on.
    Before the gate a 1e155 rad/s sample made the attitude NaN for good and every later
    tick raised `models.StateError` out of `Observer.update`."""
    from estimators.observer.base_filter import IMU_FAULT

    assert sensor_suite("realistic").imu.gyroscope.full_scale == pytest.approx(
        np.radians(2000.0))

    def spoil(r, obs):
        s = getattr(r, stream)
        v = s.value.copy()
        v[-1, 1] = value
        r = dataclasses.replace(r, **{stream: Samples(s.time, v)})
        with pytest.raises(EstimatorError, match="full scale"):
            obs._update(r)
        assert IMU_FAULT.startswith("an IMU sample")
        return r

    _glitched_drive(90, 60, spoil, compiled)


@pytest.mark.parametrize("compiled", [True, False])
def test_a_position_spike_is_a_fault_held_for_its_tick(compiled):
    """One stroke sample 50 m off (a wire break): refused before the joint filter sees it,
    so the payload estimate and the state carry on as before; without the gate it went
    through the filter's derivatives into the payload filter (mass NaN, every later tick
    stale in the compiled path)."""
    from estimators.observer import POSITION_FAULT

    def spoil(r, obs):
        s = r.positions
        value = s.value.copy()
        value[-1, 2] += 50.0
        r = dataclasses.replace(r, positions=Samples(s.time, value))
        with pytest.raises(EstimatorError, match="sensor fault"):
            obs._update(r)
        assert POSITION_FAULT.startswith("a position sample")
        return r

    masses = [e.payload_mass for e in _glitched_drive(80, 40, spoil, compiled, slew=0.1)]
    assert np.max(np.abs(np.diff(masses[35:50]))) < 20.0  # no jump through the spike


def test_payload_rls_takes_no_step_it_cannot_compute():
    """Non-finite regression sides, or a step that overflows, leave the mass and its
    variance as they were (no NaN gets in)."""
    from estimators.observer.payload_rls import PayloadRLS

    rls = PayloadRLS(150.0, 50.0, [2e3, 2e3], [100.0, 100.0])
    mass, p = rls.mass, rls.P
    rls.update(1.0, 0.01, [8e4, 6e4], [np.nan, 5e4], [90.0, 50.0])
    assert (rls.mass, rls.P) == (mass, p)
    rls.update(1.01, 0.01, [8e4, 6e4], [7e4, 5e4], [1e200, 1e200])
    assert (rls.mass, rls.P) == (mass, p)
    rls.update(1.02, 0.01, [8e4, 6e4], [7e4, 5e4], [90.0, 50.0])
    assert rls.mass != mass and np.isfinite(rls.mass) and rls.P > 0


def test_payload_rls_covariance_stays_positive_at_a_huge_regressor():
    """A machine lying on its side (a tip-over a run must still report) gives the crane's
    regression 1e10 N/kg: ``p - p k'y`` then rounds below zero, and the mass's std was the
    square root of a negative number (a sweep run lost to ``math domain error``). The values
    are those of that tick."""
    import math

    from estimators.observer.payload_rls import EVENT_TICKS, PayloadRLS

    rls = PayloadRLS(-739.8776772144694, 0.0, np.sqrt([59749291.33758166, 40449743.97425386]),
                     [243.55069144, 243.55069144], event_variance_scale=0.1)
    rls._run = EVENT_TICKS - 1  # this tick's innovation completes an event: P reset
    rls.update(8.028, 0.01, [-10223.250557087227, -83509.77061303661],
               [16586714951591.828, 46984154218.37842],
               [22420782063.968056, 64723457.24967057], [0.0, 0.0])
    assert rls.event is not None
    assert rls.P > 0 and math.isfinite(rls.std)
    y = np.array([22420782063.968056, 64723457.24967057])
    info = 1 / 300.0**2 + np.sum(y**2 / rls.R)  # the scalar RLS's exact posterior
    assert rls.P == pytest.approx(1 / info, rel=1e-12)


@pytest.mark.parametrize("command_at,ticks", [(None, EVENT_TICKS), (0.0, EXPECTED_PICK_TICKS),
                                              (-7.0, EVENT_TICKS)],
                         ids=["no-command", "expected", "lapsed"])
def test_payload_rls_expectation_shortens_only_a_growing_mass(command_at, ticks):
    """Synthetic regression: a step from 10 to 210 kg at t = 0.1 s is an event after
    ``ticks`` ticks (the grapple command's expectation lapses after EXPECTED_PICK_SECONDS);
    the step back (a release) always takes EVENT_TICKS."""
    from estimators.observer.payload_rls import EXPECTED_PICK_SECONDS, PayloadRLS

    assert EXPECTED_PICK_SECONDS < 7.0
    for m0, m1, kind, n in ((10.0, 210.0, "pick", ticks), (210.0, 10.0, "release", EVENT_TICKS)):
        rls = PayloadRLS(m0, 1.0, [100.0, 100.0], [0.0, 0.0])
        if command_at is not None:
            rls.expect_pick(command_at)
        y = [90.0, 60.0]
        events = []
        for k in range(30):
            t = 0.01 * k
            m = m1 if t >= 0.1 else m0
            rls.update(t, 0.01, [m * y[0], m * y[1]], [0.0, 0.0], y)
            if rls.event:
                events.append((k, rls.event))
        assert events[0] == (10 + n - 1, kind)
        assert rls.pick_expected == (command_at == 0.0 and kind == "release")
