"""The link accelerometers: readings against MuJoCo, the fusion, a pick with them."""


import numpy as np
import pytest

from estimators.efforts import ActuatorEfforts
from estimators.errors import EstimatorError
from estimators.observer.link_fusion import LinkFusion
from models import build_reference_machine
from models import terrain as T
from models.errors import ModelError
from models.sensing import ChannelSpec, LinkAccelerometer, Samples
from models.sensor_suites import chassis_only, sensor_suite
from scenarios.closed_loop_scenarios import SCENARIOS, scenario_terrain
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator
from tests.test_observer import PICK_POSE, _observer, _pick_run

IDEAL = sensor_suite("ideal", 0)


def _swinging(spec, ticks=300):
    """swing-out's start, the crane's four axes and both sides' wheels driven (sines)."""
    sc = SCENARIOS["swing-out"]
    machine = build_reference_machine(payload_mass=sc.payload_mass)
    sim = Simulator(machine, scenario_terrain(sc, 0))
    sim.reset(sc.start_pose.q(machine), sc.start)
    sensors = SensorSimulator(sim, spec)
    for k in range(ticks):
        t = 0.01 * k
        sim.set_command(cylinder_rates={"slew": 0.15 * np.sin(3 * t),
                                        "lift": 0.02 * np.cos(4 * t),
                                        "tilt": 0.02 * np.sin(5 * t),
                                        "telescope": 0.1 * np.sin(6 * t)},
                        wheel_speeds=(1.0, 0.5))
        sim.step(5)
        yield machine, sim, sensors.readings(sim.time)


def test_at_rest_each_reads_gravity_in_its_body_axes():
    machine = build_reference_machine()
    sim = Simulator(machine, T.flat())
    sim.reset(PICK_POSE.q(machine), (0.0, 0.0, 0.0))
    sensors = SensorSimulator(sim, IDEAL)
    sim.step(500)
    f = sensors.readings(sim.time).link_specific_force.value[-50:].mean(axis=0).reshape(-1, 3)
    for reading, acc in zip(f, IDEAL.link_accelerometers):
        rotation = sim.data.xmat[sim.model.body(acc.body).id].reshape(3, 3)
        np.testing.assert_allclose(reading, rotation.T @ [0.0, 0.0, machine.gravity],
                                   atol=2e-3)


def test_readings_equal_the_estimators_kinematics_at_mujocos_state():
    """MuJoCo's accelerometer reading (the oracle) against `point_specific_forces` at the
    simulator's exact state: the same point, frame and gravity, at the physics step's
    instant (the ideal suite has no latency)."""
    efforts = None
    worst = 0.0
    for k, (machine, sim, r) in enumerate(_swinging(IDEAL, 120)):
        if k % 20 != 19:
            continue
        efforts = efforts or ActuatorEfforts(machine)
        st, _ = sim.measure()
        a, b = efforts.point_specific_forces(
            st, [(acc.body, acc.position) for acc in IDEAL.link_accelerometers])
        assert np.abs(a[:, [0, 1, 6, 7, 8]]).max() == 0.0  # suspension and wrist unseen
        worst = max(worst, np.abs(a @ st.qdd[:9] + b - r.link_specific_force.value[-1]).max())
    assert worst < 5e-3  # [m/s^2], against readings of ~10


def test_an_unknown_body_or_a_bad_mount_is_refused():
    with pytest.raises(ModelError, match="position"):
        LinkAccelerometer("lift", (1.0, 0.0), ChannelSpec(rate=400.0))
    st = next(_swinging(IDEAL, 1))
    with pytest.raises(EstimatorError, match="no body 'boom'"):
        ActuatorEfforts(st[0]).point_specific_forces(st[1].measure()[0], [("boom", (0, 0, 0))])


@pytest.mark.parametrize("suite", ["ideal", "realistic"])
def test_fused_crane_accelerations_are_closer_to_mujocos(suite):
    """The lift, tilt and telescope accelerations, RMS against MuJoCo's, with the links'
    accelerometers fused and without (the same run, the same sensor errors). With the
    realistic chassis IMU the base's estimate (0.19 m/s^2 at the crane through the lever
    arm) limits what the fusion gains: lift and tilt 16-18 %, the telescope 3 %."""
    links = sensor_suite(suite, 3)
    rms = []
    for spec in (links, chassis_only(links)):
        obs, err = None, []
        for k, (machine, sim, r) in enumerate(_swinging(spec)):
            if obs is None:
                obs = _observer(machine, spec)
            e = obs.update(r)
            if k > 20:
                err.append(e.state.qdd[3:6] - sim.measure()[0].qdd[3:6])
        rms.append(np.sqrt(np.mean(np.square(err), axis=0)))
    assert np.all(rms[0][:2] < 0.9 * rms[1][:2]) and rms[0][2] < rms[1][2], rms


def test_a_pick_seen_without_the_links_too():
    """The sudden 240 kg pick of `tests/test_observer.py` (grapple command 1 s before) with
    the chassis-only sensor set: one event, within 5 % after 2 s (the RLS's own rules)."""
    events, at, e = _pick_run(2, 240.0, -5.0, grapple_tick=100, chassis=True)
    assert [kind for _, kind in events] == ["pick"]
    assert at[199] == pytest.approx(10.0, abs=12.0)
    assert at[399] == pytest.approx(240.0, rel=0.05)
    assert e.payload_mass == pytest.approx(240.0, rel=0.05)


def test_the_fusion_keeps_the_encoders_estimate_without_a_good_reading():
    """No reading this tick, or a NaN one: the encoders' accelerations come back unchanged."""
    machine, sim, r = next(_swinging(IDEAL, 1))
    st = sim.measure()[0]
    fusion = LinkFusion(ActuatorEfforts(machine), IDEAL.link_accelerometers, 0.1,
                        np.full(9, 0.1))
    nan = Samples(np.array([sim.time]), np.full((1, 6), np.nan))
    for readings in (None, Samples(np.zeros(0), np.zeros((0, 6))), nan):
        np.testing.assert_array_equal(fusion.accelerations(st, readings), st.qdd)
    moved = fusion.accelerations(st, r.link_specific_force)
    np.testing.assert_array_equal(np.delete(moved, [2, 3, 4, 5]),
                                  np.delete(st.qdd, [2, 3, 4, 5]))
