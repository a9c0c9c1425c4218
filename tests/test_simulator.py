"""Simulator: consistent measurements, ground-truth contacts, closed chains, commands."""

import copy
import math

import mujoco
import numpy as np
import pytest

from models import StateError, build_reference_machine
from models import terrain as T
from models.errors import PlacementError
from scenarios.base_motion import base_motion_from_free_joint
from scenarios.commands import ActuatorCommand
from scenarios.errors import CommandError, SimulatorError
from scenarios.noise import MeasurementNoise
from scenarios.physics_rate import NormalForceRecorder
from scenarios.simulator import Simulator

MACHINE = build_reference_machine()
COORDS = MACHINE.coordinates
NAMES = COORDS.independent_names
WEIGHT = MACHINE.total_mass * MACHINE.gravity


@pytest.fixture(scope="module")
def flat_sim():
    return Simulator(MACHINE, T.flat())


def _drive_to(sim: Simulator, name: str, target: float, settle_s: float = 0.5) -> None:
    """Move one servo to ``target`` with a proportional rate command, then hold it."""
    i = NAMES.index(name)
    rate = {n: 0.0 for n in NAMES[:6]}
    for _ in range(2000):
        error = target - sim.data.qpos[sim.index.independent_qpos[i]]
        if abs(error) < 2e-4:
            break
        rate[name] = float(np.clip(3.0 * error, -0.05, 0.05))
        sim.set_command(cylinder_rates=rate)
        sim.step(5)
    sim.set_command()
    sim.step(int(settle_s / sim.timestep))


def test_weight_is_carried_by_the_wheels_at_rest(flat_sim):
    flat_sim.reset()
    state, contacts = flat_sim.measure()
    assert contacts.in_contact.all()
    total_normal = contacts.normal_force.sum()
    assert abs(total_normal / WEIGHT - 1.0) < 0.005
    # The force is the ground's push on the wheels: up, through points under the wheels.
    assert (contacts.fz_in_fb > 0).all()
    # The front-heavy machine sits pitched by a few hundredths of a degree on its contacts.
    np.testing.assert_allclose(contacts.normal_in_fb, np.tile([0, 0, 1.0], (4, 1)), atol=3e-3)
    np.testing.assert_allclose(np.abs(contacts.point_in_fb[:, :2]),
                               np.tile([1.15, 0.875], (4, 1)), atol=5e-3)
    np.testing.assert_allclose(contacts.point_in_fb[:, 2], -0.45, atol=5e-3)
    assert np.abs(contacts.friction_in_fb).max() < 0.01 * WEIGHT
    payload = flat_sim.machine.payload
    assert flat_sim.model.body(payload).mass[0] == flat_sim.machine.body(payload).inertia.mass
    assert flat_sim.closure_violation() < 1e-5


def test_wheel_forces_are_mj_contact_force_on_the_wheel():
    """Per wheel, the sum of mj_contactForce over its contacts, signed as the ground's push."""
    sim = Simulator(MACHINE, T.rough(1))
    sim.set_command(cylinder_rates={"slew": 0.05}, wheel_speeds=(3.0, 2.5))
    sim.step(700)
    _, contacts = sim.measure()
    model, data, index = sim.model, sim.data, sim.index
    expected = np.zeros((4, 3))
    f6 = np.zeros(6)
    for i in range(data.ncon):
        mujoco.mj_contactForce(model, data, i, f6)  # acts on geom[1], contact frame
        g0, g1 = data.contact.geom[i]
        force = data.contact.frame[i].reshape(3, 3).T @ f6[:3]
        if g1 in index.wheel_geoms:
            expected[list(index.wheel_geoms).index(g1)] += force
        else:
            expected[list(index.wheel_geoms).index(g0)] -= force
    rotation = data.xmat[index.base_body].reshape(3, 3)
    np.testing.assert_allclose(contacts.force_in_fb, expected @ rotation, atol=1e-6)
    assert (expected[:, 2] >= 0).all() and expected[:, 2].sum() > 0.5 * WEIGHT


def test_airborne_wheels_report_no_force_and_their_lowest_point(flat_sim):
    flat_sim.reset()
    data = flat_sim.data
    data.qpos[flat_sim.index.base_qpos[2]] += 0.3
    mujoco.mj_forward(flat_sim.model, data)
    contacts = flat_sim.wheel_contacts()
    assert not contacts.in_contact.any()
    np.testing.assert_array_equal(contacts.force_in_fb, 0.0)
    rotation = data.xmat[flat_sim.index.base_body].reshape(3, 3)
    up_in_fb = rotation.T @ [0.0, 0.0, 1.0]
    centres = (data.xpos[flat_sim.index.wheel_bodies] - data.xpos[flat_sim.index.base_body]
               ) @ rotation
    np.testing.assert_allclose(contacts.point_in_fb,
                               centres - MACHINE.wheel_radius * up_in_fb, atol=1e-12)
    np.testing.assert_allclose(contacts.normal_in_fb, np.tile(up_in_fb, (4, 1)), atol=1e-12)
    flat_sim.reset()


def test_measure_belongs_to_one_instant(flat_sim):
    """After a step, MuJoCo's forward dynamics at the reported state give the reported
    accelerations and contact forces (they would not at data.qpos, one step later)."""
    flat_sim.reset()
    flat_sim.set_command(cylinder_rates={"lift": 0.03, "slew": 0.05}, wheel_speeds=(2.0, 1.0))
    flat_sim.step(50)
    state, contacts = flat_sim.measure()
    qpos, qvel, t = flat_sim.measured_instant
    assert t == pytest.approx(flat_sim.time - flat_sim.timestep)
    probe = copy.copy(flat_sim.data)
    probe.qpos[:], probe.qvel[:], probe.time = qpos, qvel, t
    mujoco.mj_forward(flat_sim.model, probe)
    ix = flat_sim.index
    tol = 1e-5 * np.abs(probe.qacc).max()  # the solver's accuracy (warm starts differ)
    chains = flat_sim.machine.chains
    direct = [i for i, n in enumerate(ix.independent_names) if n not in chains]
    np.testing.assert_allclose(probe.qacc[ix.independent_dof[direct]], state.qdd[direct],
                               atol=tol)
    for i, name in enumerate(ix.independent_names):
        if name in chains:  # stroke rates come through the driven joint (eq. 6)
            s = chains[name].chain.state(state.q[i])
            dof = ix.dof_adr[chains[name].driven_joint]
            assert s.k[0] * state.qd[i] == pytest.approx(qvel[dof], abs=1e-9)
            assert (s.dk_dx[0] * state.qd[i] ** 2 + s.k[0] * state.qdd[i]
                    == pytest.approx(probe.qacc[dof], abs=tol))
    np.testing.assert_allclose(probe.qacc[ix.base_dof], flat_sim.data.qacc[ix.base_dof],
                               atol=tol)
    later = copy.copy(flat_sim.data)  # the state one step later has other accelerations
    mujoco.mj_forward(flat_sim.model, later)
    assert np.abs(later.qacc - flat_sim.data.qacc).max() > 1e3 * tol
    forces = []
    f6 = np.zeros(6)
    for i in range(probe.ncon):
        mujoco.mj_contactForce(flat_sim.model, probe, i, f6)
        forces.append(f6[0])
    assert sum(forces) == pytest.approx(contacts.normal_force.sum(), rel=1e-5)
    np.testing.assert_allclose(state.q, qpos[ix.independent_qpos])
    np.testing.assert_allclose(state.base_position, qpos[:3])


def test_base_motion_conversion_matches_finite_differences():
    """The twist derivative is d/dt [R^T v_world; w_fb], checked by central differences."""
    rng = np.random.default_rng(2)
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody></mujoco>")
    h = 1e-5
    for _ in range(5):
        quat = rng.normal(size=4)
        qpos = np.r_[rng.normal(size=3), quat / np.linalg.norm(quat)]
        qvel, qacc = rng.normal(size=6), rng.normal(size=6)
        twists = []
        for sign in (1.0, -1.0):
            q = qpos.copy()
            mujoco.mj_integratePos(model, q, sign * qvel, h)
            twists.append(base_motion_from_free_joint(q, qvel + sign * h * qacc, qacc)[2])
        _, rotation, twist, accel = base_motion_from_free_joint(qpos, qvel, qacc)
        np.testing.assert_allclose(accel, (twists[0] - twists[1]) / (2 * h), atol=1e-6)
        np.testing.assert_allclose(twist[:3], rotation.T @ qvel[:3])


@pytest.mark.parametrize("name, strokes", [("bogie_L", (0.08, 0.17)), ("slew", (0.15, 0.42)),
                                           ("lift", (0.25, 0.33)), ("tilt", (0.12, 0.32))])
def test_mujoco_closed_chain_matches_chain_kinematics(flat_sim, name, strokes):
    """Driven to a stroke and settled, MuJoCo's chain sits where eqs. (2)-(5) put it."""
    flat_sim.reset()
    binding = MACHINE.chains[name]
    adr = flat_sim.index.qpos_adr
    for target in strokes:
        _drive_to(flat_sim, name, target)
        x = flat_sim.data.qpos[adr[binding.piston]]
        assert x == pytest.approx(target, abs=2e-3)
        expected = binding.chain.state(x)
        assert flat_sim.data.qpos[adr[binding.driven_joint]] == pytest.approx(expected.theta,
                                                                              abs=1e-4)
        assert flat_sim.data.qpos[adr[binding.barrel]] == pytest.approx(expected.theta_barrel,
                                                                        abs=1e-4)


@pytest.mark.parametrize("name, rate", [("bogie_R", 0.02), ("slew", -0.03), ("lift", -0.02),
                                        ("tilt", 0.03)])
def test_joint_rates_follow_k1_k2_during_slow_motion(flat_sim, name, rate):
    """theta_dot = k1 x_dot and barrel_dot = k2 x_dot (eqs. 6-7) from MuJoCo's velocities."""
    flat_sim.reset()
    binding = MACHINE.chains[name]
    i = NAMES.index(name)
    dof = flat_sim.index.dof_adr
    flat_sim.set_command(cylinder_rates={name: rate})
    flat_sim.step(150)
    for _ in range(50):
        flat_sim.step(2)
        state, _ = flat_sim.measure()
        _, qvel, _ = flat_sim.measured_instant
        k1, k2, _ = binding.chain.state(state.q[i]).k
        x_dot = state.qd[i]
        assert abs(x_dot) > 0.3 * abs(rate)
        assert qvel[dof[binding.driven_joint]] / x_dot == pytest.approx(k1, abs=2e-3)
        assert qvel[dof[binding.barrel]] / x_dot == pytest.approx(k2, abs=2e-3)


def test_stroke_rates_are_the_numpy_formula_to_the_bit(flat_sim):
    """`measure`'s stroke rates through the driven joints (eq. 6) in Python floats give the
    bits of the same formula on numpy's scalars."""
    flat_sim.reset()
    flat_sim.set_command(cylinder_rates={"lift": 0.05, "tilt": -0.04, "bogie_L": 0.02})
    flat_sim.step(60)
    state, _ = flat_sim.measure()
    qpos, qvel, _ = flat_sim.measured_instant
    q, qacc = qpos[flat_sim.index.independent_qpos], flat_sim.data.qacc
    for i in COORDS.chain_indices:
        b = COORDS.binding(i)
        dof = flat_sim.index.dof_adr[b.driven_joint]
        k1, dk1 = b.chain.driven_rate_coefficients(q[i])
        qd = qvel[dof] / k1
        assert state.qd[i].tobytes() == np.float64(qd).tobytes()
        assert state.qdd[i].tobytes() == np.float64((qacc[dof] - dk1 * qd * qd) / k1).tobytes()


def _rough_drive_closure(sim: Simulator, seconds: float) -> float:
    """Worst loop gap [m] driving over rough ground with every cylinder moving."""
    worst = 0.0
    while sim.time < seconds:
        t = sim.time
        sim.set_command(cylinder_rates={"bogie_L": 0.02 * math.sin(t), "bogie_R": -0.02,
                                        "slew": 0.05 * math.sin(0.5 * t),
                                        "lift": 0.02 * math.sin(0.8 * t),
                                        "tilt": 0.03 * math.cos(0.8 * t),
                                        "telescope": 0.05 * math.sin(0.7 * t)},
                        wrist_rates=(0.2, -0.1, 0.3), wheel_speeds=(4.0, 3.5))
        sim.step(5)
        worst = max(worst, sim.closure_violation())
    return worst


def test_chains_stay_closed_driving_over_rough_terrain_with_moving_cylinders():
    sim = Simulator(MACHINE, T.rough(0))
    worst = _rough_drive_closure(sim, 4.0)
    assert sim.measure()[0].base_position[0] > 3.0  # it did drive
    assert worst < 1e-4  # the project's bar: closed to 0.1 mm (the brief's test: 1 mm)


def test_slewing_with_the_crane_upright_keeps_the_wheel_forces_smooth():
    """The slew's free inertia is 15x smaller with the crane upright than at home.

    With the damping designed at home applied there, the explicit slew damper diverged at half
    the step rate and the wheels' forces jumped between 0 and 38 kN from step to step (a
    random scenario folding the crane up after a release); `DampingSchedule` caps it. Run at 87
    deg of lift, on the machine without the lift's end stop: at the stop (79.6 deg) the
    forces stay smooth even without the schedule, so the test could not fail there; at 87
    deg without it the smallest force is 155 N.
    """
    machine = build_reference_machine(payload_mass=10.0, lift_stroke_end=0.59)
    sim = Simulator(machine, T.flat())
    q = machine.coordinates.home()
    q[3] = machine.chains["lift"].chain.stroke_from_angle(math.radians(87.0))
    q[4] = machine.chains["tilt"].chain.stroke_from_angle(math.radians(-18.0))
    q[5] = 0.0
    sim.reset(q)
    recorder = NormalForceRecorder(sim)
    slew = np.zeros(6)
    slew[2] = 0.05  # [m/s] of the slew cylinder, 0.2 s
    sim.set_command(cylinder_rates=slew)
    sim.step(100)
    sim.set_command()
    sim.step(400)
    force = recorder.normal_force
    assert force.min() > 5e3
    assert np.abs(np.diff(force, axis=0)).max() < 5e3


def test_mujoco_default_constraint_settings_let_the_chains_open():
    """The measured pitfall the model's solref/solimp avoid (documented, kept honest)."""
    sim = Simulator(MACHINE, T.rough(0))
    sim.model.eq_solref[:] = (0.02, 1.0)
    sim.model.eq_solimp[:] = (0.9, 0.95, 0.001, 0.5, 2.0)
    sim.reset(reuse_settled=False)
    assert _rough_drive_closure(sim, 4.0) > 1e-4


def test_reset_restores_the_same_settled_state(flat_sim):
    flat_sim.reset()
    first, _ = flat_sim.measure()
    flat_sim.set_command(cylinder_rates={"lift": 0.02}, wheel_speeds=(2.0, 2.0))
    flat_sim.step(300)
    flat_sim.reset()
    again, _ = flat_sim.measure()
    assert again.time == 0.0 and flat_sim.time == 0.0
    np.testing.assert_array_equal(again.q, first.q)
    np.testing.assert_array_equal(again.base_position, first.base_position)
    np.testing.assert_array_equal(flat_sim.command.servo_rates, np.zeros(9))


def test_wheel_commands_drive_each_side(flat_sim):
    flat_sim.reset()
    flat_sim.set_command(wheel_speeds=(3.0, 3.0))
    ix = flat_sim.index
    np.testing.assert_array_equal(flat_sim.data.ctrl[ix.wheel_actuators], [3.0] * 4)
    flat_sim.step(1000)
    state, contacts = flat_sim.measure()
    assert state.base_twist[0] == pytest.approx(3.0 * MACHINE.wheel_radius, rel=0.05)
    np.testing.assert_allclose(state.qd[9:], 3.0, atol=0.05)
    flat_sim.set_command(wheel_speeds=(2.0, -2.0))  # left forward, right back: turn right
    np.testing.assert_array_equal(flat_sim.data.ctrl[ix.wheel_actuators], [2, 2, -2, -2])
    flat_sim.step(500)
    state, _ = flat_sim.measure()
    assert state.base_twist[5] < -0.03  # skid steering against lateral friction: slowly


def test_rates_are_limited_by_the_valve(flat_sim):
    flat_sim.reset()
    flat_sim.set_command(cylinder_rates={"slew": 10.0})
    flat_sim.step(200)
    state, _ = flat_sim.measure()
    assert 0.0 < state.qd[NAMES.index("slew")] <= MACHINE.chains["slew"].cylinder.velocity_range[
        1] * 1.05


def test_suspension_forces_are_the_cylinder_forces(flat_sim):
    flat_sim.reset()
    state, _ = flat_sim.measure()
    np.testing.assert_array_equal(state.suspension_force, flat_sim.actuator_forces()[:2])
    assert state.suspension_force[0] == pytest.approx(state.suspension_force[1], rel=1e-3)
    lo, hi = MACHINE.chains["bogie_L"].cylinder.force_range
    assert lo <= state.suspension_force[0] <= hi


def test_settles_on_a_side_slope_without_sliding():
    sim = Simulator(MACHINE, T.side_slope(15.0))
    state, contacts = sim.measure()
    assert contacts.in_contact.all()
    roll = math.atan2(state.base_rotation[2, 1], state.base_rotation[2, 2])
    assert roll == pytest.approx(math.radians(15.0), abs=math.radians(0.5))
    assert contacts.normal_force.sum() == pytest.approx(WEIGHT * math.cos(math.radians(15.0)),
                                                        rel=0.01)
    start = state.base_position.copy()
    sim.step(500)
    assert np.linalg.norm(sim.measure()[0].base_position - start) < 0.01


def test_noise_reaches_the_measured_state_only():
    exact = Simulator(MACHINE, T.flat())
    noisy = Simulator(MACHINE, T.flat(), noise=MeasurementNoise(q=1e-3, contact_force=50.0,
                                                                 seed=1))
    (s_exact, c_exact), (s_noisy, c_noisy) = exact.measure(), noisy.measure()
    np.testing.assert_array_equal(c_exact.force_in_fb, c_noisy.force_in_fb)
    np.testing.assert_array_equal(s_exact.qd, s_noisy.qd)
    assert 0 < np.abs(s_exact.q - s_noisy.q).max() < 0.01
    assert 0 < np.abs(s_noisy.contacts.force_in_fb - c_noisy.force_in_fb).max() < 500


@pytest.mark.parametrize("call, error", [
    (lambda s: s.set_command(cylinder_rates=[0.1] * 5), CommandError),
    (lambda s: s.set_command(cylinder_rates={"boom": 0.1}), CommandError),
    (lambda s: s.set_command(wrist_rates=[0.0, float("nan"), 0.0]), CommandError),
    (lambda s: s.set_command(wheel_speeds="fast"), CommandError),
    (lambda s: s.apply((0.1, 0.2)), CommandError),
    (lambda s: s.step(0), SimulatorError),
    (lambda s: s.step(2.5), SimulatorError),
    (lambda s: s.reset(settle_time=-1.0), SimulatorError),
    (lambda s: s.reset(q_ind=np.zeros(4)), StateError),
    (lambda s: s.reset(base_xy_yaw=(60.0, 0.0, 0.0)), PlacementError),
])
def test_bad_input_raises_typed_errors(flat_sim, call, error):
    with pytest.raises(error):
        call(flat_sim)


@pytest.mark.parametrize("kwargs", [dict(q=-1.0), dict(qd=float("inf")), dict(seed=-3)])
def test_bad_noise_raises(kwargs):
    with pytest.raises(SimulatorError):
        MeasurementNoise(**kwargs)


def test_command_holds_its_values():
    command = ActuatorCommand(np.arange(6) * 0.01, [0.1, 0.2, 0.3], [1.0, -1.0])
    np.testing.assert_array_equal(command.servo_rates, np.r_[np.arange(6) * 0.01, 0.1, 0.2, 0.3])
    with pytest.raises(ValueError):
        command.cylinder_rates[0] = 1.0


def test_command_of_servo_rates_is_the_constructors():
    """The closed loop's one-copy command: the constructor's fields, read-only, a copy."""
    rates, wheels = np.linspace(-0.3, 0.5, 9), np.array([1.5, -0.5])
    fast = ActuatorCommand.of_servo_rates(rates, wheels)
    slow = ActuatorCommand(rates[:6], rates[6:9], wheels)
    for name in ("cylinder_rates", "wrist_rates", "wheel_speeds", "servo_rates"):
        a, b = getattr(fast, name), getattr(slow, name)
        assert a.shape == b.shape and a.tobytes() == b.tobytes()
        with pytest.raises(ValueError):
            a[0] = 1.0
    rates[0] = 9.0  # the caller's buffer is not the command's
    assert fast.cylinder_rates[0] == -0.3
    with pytest.raises(CommandError, match="cylinder_rates"):
        ActuatorCommand.of_servo_rates(np.r_[np.nan, np.zeros(8)], wheels)
    with pytest.raises(CommandError, match="wheel_speeds"):
        ActuatorCommand.of_servo_rates(np.zeros(9), np.zeros(3))
