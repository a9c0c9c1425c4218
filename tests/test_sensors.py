"""The simulated sensors: error statistics against their specs, the IMU against an independent
differentiation of MuJoCo's motion, chamber pressures, rates and latency."""

import dataclasses

import numpy as np
import pytest

from models import build_reference_machine
from models import terrain as T
from models.errors import ModelError
from models.sensing import cylinder_force
from models.sensor_suites import IDEAL, REALISTIC, sensor_suite
from scenarios.errors import SimulatorError
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator

MACHINE = build_reference_machine()


@pytest.fixture(scope="module")
def sim():
    return Simulator(MACHINE, T.flat())


def _rest_run(sim, spec, seconds=4.0):
    sim.reset()
    sensors = SensorSimulator(sim, spec)
    try:
        sim.step(int(round(seconds / sim.timestep)))
        return sensors.readings(sim.time), sim.measure()[0]
    finally:
        sensors.close()


def test_noise_of_each_stream_matches_its_spec(sim):
    r, state = _rest_run(sim, sensor_suite("realistic", 1), seconds=8.0)
    for samples, spec in ((r.specific_force, REALISTIC.imu.accelerometer),
                          (r.angular_rate, REALISTIC.imu.gyroscope),
                          (r.pressures, REALISTIC.pressure)):
        std = samples.value.std(axis=0)
        # 4000 samples: the sample std is within 5 % of the truth (the machine is at rest;
        # the bias walk adds < 1 %).
        np.testing.assert_allclose(std, spec.sample_std, rtol=0.06)
    # Stroke sensors: noise 2.5 um on a 1 um grid.
    np.testing.assert_allclose(r.positions.value[:, :6].std(axis=0),
                               REALISTIC.stroke.sample_std, rtol=0.1)
    steps = np.diff(np.unique(r.positions.value[:, 3]))
    np.testing.assert_allclose(steps, REALISTIC.stroke.resolution, rtol=1e-6)
    del state


def test_turn_on_biases_have_their_spec_spread(sim):
    """Across seeds, the constant offsets scatter as the specs' bias figures say."""
    offsets = []
    for seed in range(8):
        r, _ = _rest_run(sim, sensor_suite("realistic", seed), seconds=1.0)
        force = sim.actuator_forces()[:5]  # at rest: the same at every sample
        p_true = SensorSimulator.chamber_pressures(_Areas(), force)
        offsets.append(r.pressures.value.mean(axis=0) - p_true)
    spread = np.std(np.concatenate(offsets))  # 80 offsets
    assert spread == pytest.approx(REALISTIC.pressure.bias, rel=0.35)


class _Areas:
    """Stand-in ``self`` for `SensorSimulator.chamber_pressures` (it reads the areas only)."""

    from models.sensing import cylinder_areas as _ca
    _areas = _ca(MACHINE)


def test_chamber_pressures_are_the_two_branch_formula_to_the_bit():
    """The in-place split gives the bits of ``np.where`` over both branches, any shape."""
    from scenarios.sensors import BACK_PRESSURE

    rng = np.random.default_rng(3)
    forces = rng.normal(0.0, 5e4, (7, 5))
    forces[0, :2] = 0.0, -0.0
    a_a, a_b = _Areas._areas[:, 0], _Areas._areas[:, 1]
    p_a = np.where(forces >= 0, (forces + BACK_PRESSURE * a_b) / a_a, BACK_PRESSURE)
    p_b = np.where(forces >= 0, BACK_PRESSURE, (BACK_PRESSURE * a_a - forces) / a_b)
    expected = np.stack([p_a, p_b], axis=-1).reshape(7, 10)
    got = SensorSimulator.chamber_pressures(_Areas(), forces)
    assert got.tobytes() == expected.tobytes()
    assert SensorSimulator.chamber_pressures(_Areas(), forces[3]).tobytes() == \
        expected[3].tobytes()


def test_recorded_truths_are_the_numpy_formulas_to_the_bit(sim):
    """The listener's Python-float arithmetic gives the bits of the formulas on numpy's
    scalars: the IMU's specific force (module docstring), gyro, wheel speeds and torques."""
    sim.reset()
    sensors = SensorSimulator(sim, sensor_suite("realistic", 4))
    ix, p, g = sim.index, np.asarray(REALISTIC.imu.position, float), MACHINE.gravity
    expected = {"acc": [], "gyro": [], "wheels": [], "drive": []}

    def reference(s, qpos, qvel, t):
        d = s.data
        rot, v6, a6 = d.xmat[ix.base_body], qvel[ix.base_dof], d.qacc[ix.base_dof]
        w, al, p0, p1, p2 = v6[3:6], a6[3:6], p[0], p[1], p[2]
        c = (w[1] * p2 - w[2] * p1, w[2] * p0 - w[0] * p2, w[0] * p1 - w[1] * p0)
        a = (a6[0], a6[1], a6[2] + g)
        expected["acc"].append([
            rot[i] * a[0] + rot[i + 3] * a[1] + rot[i + 6] * a[2] + al[(i + 1) % 3]
            * p[(i + 2) % 3] - al[(i + 2) % 3] * p[(i + 1) % 3] + w[(i + 1) % 3]
            * c[(i + 2) % 3] - w[(i + 2) % 3] * c[(i + 1) % 3] for i in range(3)])
        expected["gyro"].append(v6[3:6].copy())
        wd, tau = qvel[ix.independent_dof[9:13]], d.actuator_force[ix.wheel_actuators]
        expected["wheels"].append([0.5 * (wd[0] + wd[1]), 0.5 * (wd[2] + wd[3])])
        expected["drive"].append([tau[0] + tau[1], tau[2] + tau[3]])

    sim.add_step_listener(reference)
    try:
        sim.set_command(cylinder_rates={"slew": 0.2, "lift": 0.05}, wheel_speeds=(1.0, 0.5))
        sim.step(20)
    finally:
        sim.remove_step_listener(reference)
        sensors.close()
    for name, every in (("acc", 1), ("gyro", 1), ("wheels", 5), ("drive", 1)):
        stream = getattr(sensors, "_" + name)
        got = stream.truths[1:stream.count]  # after the primed reading
        want = np.array(expected[name][::every])[:got.shape[0]]
        assert got.shape[0] >= 4 and got.tobytes() == want.tobytes(), name


def test_delivered_readings_are_read_only(sim):
    r, _ = _rest_run(sim, sensor_suite("realistic", 2), seconds=0.1)
    for samples in (r.specific_force, r.angular_rate, r.positions, r.pressures,
                    r.wheel_speeds, r.drive_torques):
        assert len(samples) > 0
        assert not samples.time.flags.writeable and not samples.value.flags.writeable


def test_imu_at_rest_reads_gravity_in_its_own_frame(sim):
    r, state = _rest_run(sim, sensor_suite("ideal"), seconds=1.0)
    f = r.specific_force.value.mean(axis=0)
    np.testing.assert_allclose(f, state.base_rotation.T @ [0, 0, MACHINE.gravity], atol=2e-3)
    assert np.linalg.norm(f) == pytest.approx(MACHINE.gravity, rel=2e-4)


def test_imu_specific_force_is_the_mounting_points_acceleration_less_gravity(sim):
    """Against the point velocity differentiated over each step (MuJoCo's own motion)."""
    sim.reset()
    sensors = SensorSimulator(sim, IDEAL)
    ix = sim.index
    p = np.asarray(IDEAL.imu.position)
    vel, rot = [], []
    try:
        sim.set_command(cylinder_rates={"slew": 0.15, "lift": 0.08}, wheel_speeds=(2.0, -1.0))
        for _ in range(300):
            sim.step(1)
            qpos, qvel, _ = sim.measured_instant
            r_wb = sim.data.xmat[ix.base_body].reshape(3, 3).copy()
            w_body = qvel[ix.base_dof][3:6]
            vel.append(qvel[ix.base_dof][:3] + r_wb @ np.cross(w_body, p))
            rot.append(r_wb)
        readings = sensors.readings(sim.time + 1.0)
    finally:
        sensors.close()
    f = readings.specific_force.value[-300:]
    h = sim.timestep
    g = np.array([0.0, 0.0, MACHINE.gravity])
    errors = []
    for k in range(100, 299):
        a_world = (vel[k + 1] - vel[k]) / h  # semi-implicit Euler: v' = v + h a
        expected = rot[k].T @ (a_world + g)
        errors.append(f[k] - expected)
    err = np.abs(np.array(errors)).max()
    assert err < 0.02 * np.abs(f).max(), err


def test_pressures_give_back_the_servo_force(sim):
    r, _ = _rest_run(sim, IDEAL, seconds=0.2)
    np.testing.assert_allclose(cylinder_force(MACHINE, r.pressures.value[-1]),
                               sim.actuator_forces()[:5], rtol=1e-9, atol=1e-6)
    assert np.all(r.pressures.value >= 0.0)


def test_rates_latency_and_delivery_once(sim):
    sim.reset()
    sensors = SensorSimulator(sim, REALISTIC)
    try:
        sim.step(5)
        first = sensors.readings(sim.time)
        sim.step(5)
        second = sensors.readings(sim.time)
    finally:
        sensors.close()
    lat = REALISTIC.pressure.latency
    assert first.pressures.time.max() <= first.time - lat + 1e-9
    assert second.pressures.time.min() > first.pressures.time.max()  # each reading once
    np.testing.assert_allclose(np.diff(second.pressures.time), 1.0 / REALISTIC.pressure.rate)
    assert len(second.wheel_speeds) in (0, 1, 2)


def test_seeds_reproduce_and_differ(sim):
    a, _ = _rest_run(sim, sensor_suite("realistic", 4), seconds=0.2)
    b, _ = _rest_run(sim, sensor_suite("realistic", 4), seconds=0.2)
    c, _ = _rest_run(sim, sensor_suite("realistic", 5), seconds=0.2)
    np.testing.assert_array_equal(a.pressures.value, b.pressures.value)
    assert not np.array_equal(a.pressures.value, c.pressures.value)


def test_bad_suites_are_typed_errors(sim):
    with pytest.raises(SimulatorError, match="SensorSpec with sensors"):
        SensorSimulator(sim, sensor_suite("oracle"))
    with pytest.raises(ModelError, match="unknown sensor suite"):
        sensor_suite("perfect")
    with pytest.raises(ModelError, match="rate"):
        dataclasses.replace(REALISTIC.stroke, rate=0.0)
    for bad in (0.0, -1.0, float("nan"), "10 g", True):
        with pytest.raises(ModelError, match="full_scale"):
            dataclasses.replace(REALISTIC.imu.accelerometer, full_scale=bad)


def test_pressure_force_is_the_mechanism_force_plus_the_seal_friction(sim):
    """While the lift cylinder slides, the pressures' force exceeds the force the mechanism
    needs (rigid-body dynamics, `estimators.efforts`) by the seal friction, sign of the
    motion; MuJoCo's friction rows on the piston carry exactly that."""
    from estimators.efforts import ActuatorEfforts

    lift = MACHINE.coordinates.independent_names.index("lift")
    friction = MACHINE.chains["lift"].cylinder.seal_friction
    assert friction > 0
    efforts = ActuatorEfforts(MACHINE)
    for rate in (0.05, -0.05):
        sim.reset()
        sensors = SensorSimulator(sim, IDEAL)
        try:
            sim.set_command(cylinder_rates={"lift": rate})
            sim.step(250)  # steady sliding
            excess = []
            for _ in range(20):
                sim.step(5)
                state = sim.measure()[0]
                r = sensors.readings(sim.time)
                pressure_force = cylinder_force(MACHINE, r.pressures.value[-1])[lift]
                excess.append(pressure_force - efforts.efforts(state)[lift])
        finally:
            sensors.close()
        assert np.mean(excess) == pytest.approx(np.sign(rate) * friction, abs=0.1 * friction)


def test_trusted_readings_check_the_time_and_equal_the_checked_ones():
    """`SensorReadings.trusted` skips the per-field checks, not the tick's: a NaN tick is
    refused as by the constructor; valid fields give the constructor's object."""
    from models.errors import StateError
    from models.sensing import Samples, SensorReadings

    def samples(k):
        return Samples.trusted(np.arange(2.0), np.ones((2, k)))

    fields = dict(specific_force=samples(3), angular_rate=samples(3), positions=samples(9),
                  pressures=samples(10), wheel_speeds=samples(2), drive_torques=samples(2),
                  link_specific_force=None)
    setpoint = np.zeros(9)
    setpoint.flags.writeable = False
    for bad in (float("nan"), float("inf")):
        with pytest.raises(StateError, match="'time' must be a finite number"):
            SensorReadings.trusted(bad, servo_setpoint=setpoint, **fields)
    trusted = SensorReadings.trusted(1.0, servo_setpoint=setpoint, **fields)
    checked = SensorReadings(time=1.0, servo_setpoint=setpoint, **fields)
    for f in dataclasses.fields(SensorReadings):
        a, b = getattr(trusted, f.name), getattr(checked, f.name)
        assert a is b or np.array_equal(a, b), f.name
