"""MuJoCo model: files, names, inertias, collisions, actuators, keyframes, servo design."""

import math

import mujoco
import numpy as np
import pytest

import models.mujoco as mm
from models import build_reference_machine
from models import terrain as T
from models.errors import ModelError, PlacementError, StateError

MACHINE = build_reference_machine()
COORDS = MACHINE.coordinates
WARNINGS = [w for name, w in mujoco.mjtWarning.__members__.items() if name != "mjNWARNING"]


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    return mm.write_mjcf(MACHINE, tmp_path_factory.mktemp("mjcf"))


@pytest.fixture(scope="module")
def flat_model():
    return mm.build_model(MACHINE, T.flat())


def _closure(model, data, index) -> float:
    pairs = index.loop_site_pairs
    return float(np.linalg.norm(data.site_xpos[pairs[:, 0]] - data.site_xpos[pairs[:, 1]],
                                axis=1).max())


def test_layout_is_menagerie_like(scene_files):
    root = scene_files["machine"].parent
    assert set(scene_files) == {"machine", "flat", "rough", "ramp", "side_slope"}
    for name in ("flat", "rough", "ramp", "side_slope"):
        text = scene_files[name].read_text()
        assert scene_files[name].name == f"scene_{name}.xml"
        assert '<include file="machine.xml"' in text and '<key name="home"' in text
    machine_text = scene_files["machine"].read_text()
    assert 'class="visual"' in machine_text and 'class="collision"' in machine_text
    assert sorted(p.name for p in (root / "assets").iterdir()) == [
        "terrain_ramp.bin", "terrain_rough.bin", "terrain_side_slope.bin"]


@pytest.mark.parametrize("name", ["flat", "rough", "ramp", "side_slope"])
def test_every_scene_compiles_and_steps_2s_without_warnings(scene_files, name):
    model = mujoco.MjModel.from_xml_path(str(scene_files[name]))
    data = mujoco.MjData(model)
    index = mm.MujocoIndex(model, MACHINE)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    worst = 0.0
    for _ in range(int(round(2.0 / model.opt.timestep))):
        mujoco.mj_step(model, data)
        worst = max(worst, _closure(model, data, index))
    assert [data.warning[w].number for w in WARNINGS] == [0] * len(WARNINGS)
    assert np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))
    assert worst < 1e-4  # the chains stay closed even with the standalone, undamped servos


@pytest.mark.parametrize("terrain", mm.default_terrains(), ids=lambda t: t.name)
def test_files_and_build_model_are_the_same_model(scene_files, terrain):
    built = mm.build_model(MACHINE, terrain)
    loaded = mujoco.MjModel.from_xml_path(str(scene_files[terrain.name]))
    for field in ("nq", "nv", "nu", "neq", "ntendon", "ngeom", "nsite", "nhfield"):
        assert getattr(built, field) == getattr(loaded, field), field
    for field in ("body_mass", "body_inertia", "body_ipos", "body_pos", "jnt_axis",
                  "jnt_range", "site_pos", "actuator_gainprm", "actuator_biasprm",
                  "actuator_forcerange", "geom_size", "geom_friction", "hfield_data",
                  "key_qpos", "key_ctrl", "eq_solref", "eq_solimp"):
        np.testing.assert_array_equal(getattr(built, field), getattr(loaded, field), field)


@pytest.mark.parametrize("terrain", mm.default_terrains(), ids=lambda t: t.name)
def test_home_keyframe_closes_the_chains_and_touches_the_ground(terrain):
    model = mm.build_model(MACHINE, terrain)
    data = mujoco.MjData(model)
    index = mm.MujocoIndex(model, MACHINE)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    assert _closure(model, data, index) < 1e-9
    np.testing.assert_allclose(data.qpos[index.tree_qpos], COORDS.joint_positions(COORDS.home()),
                               atol=1e-12)
    assert all(data.contact.dist[i] > -1e-6 for i in range(data.ncon))  # no penetration
    data.qpos[index.base_qpos[2]] -= 1e-3  # 1 mm lower, every wheel touches
    mujoco.mj_forward(model, data)
    touching = {int(data.contact.geom[i][1]) for i in range(data.ncon)
                if data.contact.dist[i] > -1.1e-3}
    assert touching == set(index.wheel_geoms.tolist())


def test_names_follow_the_description(flat_model):
    index = mm.MujocoIndex(flat_model, MACHINE)

    def names(objtype, n):
        return [mujoco.mj_id2name(flat_model, objtype, i) for i in range(n)]

    assert set(names(mujoco.mjtObj.mjOBJ_BODY, flat_model.nbody)[1:]) == {
        b.name for b in MACHINE.bodies}
    joints = names(mujoco.mjtObj.mjOBJ_JOINT, flat_model.njnt)
    assert set(joints) == set(MACHINE.moving_joints) | {MACHINE.bodies[0].name}
    assert names(mujoco.mjtObj.mjOBJ_ACTUATOR, flat_model.nu) == list(COORDS.independent_names)
    for name, adr in index.qpos_adr.items():
        assert flat_model.jnt_qposadr[flat_model.joint(name).id] == adr
    assert flat_model.jnt_type[flat_model.joint(MACHINE.bodies[0].name).id] == \
        mujoco.mjtJoint.mjJNT_FREE
    assert list(index.base_qpos) == list(range(7))


def test_loop_and_cylinder_sites_are_on_the_described_bodies(flat_model):
    index = mm.MujocoIndex(flat_model, MACHINE)
    for loop in MACHINE.loops:
        site_a, site_b = index.loop_sites[loop.name]
        assert flat_model.site_bodyid[site_a] == flat_model.body(loop.body_a).id
        assert flat_model.site_bodyid[site_b] == flat_model.body(loop.body_b).id
        np.testing.assert_allclose(flat_model.site_pos[site_a], loop.point_a, atol=1e-12)
        np.testing.assert_allclose(flat_model.site_pos[site_b], loop.point_b, atol=1e-12)


def test_inertias_match_the_description(flat_model):
    assert flat_model.body_mass.sum() == pytest.approx(MACHINE.total_mass, rel=1e-12)
    for b in MACHINE.bodies:
        body = flat_model.body(b.name)
        assert body.mass[0] == pytest.approx(b.inertia.mass, rel=1e-12)
        np.testing.assert_allclose(body.ipos, b.inertia.com, atol=1e-12)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, body.iquat)
        rot = rot.reshape(3, 3)
        np.testing.assert_allclose(rot @ np.diag(body.inertia) @ rot.T, b.inertia.inertia,
                                   atol=1e-8 * max(1.0, np.abs(b.inertia.inertia).max()))


def test_body_poses_in_fb_match_mujoco_kinematics(flat_model):
    data = mujoco.MjData(flat_model)
    index = mm.MujocoIndex(flat_model, MACHINE)
    rng = np.random.default_rng(3)
    q_ind = COORDS.home()
    for name in ("bogie_L", "slew", "lift", "tilt"):
        q_ind[COORDS.independent_names.index(name)] = rng.uniform(
            *MACHINE.chains[name].chain.stroke_range)
    q_tree = COORDS.joint_positions(q_ind)
    data.qpos[index.base_qpos] = [0, 0, 0, 1, 0, 0, 0]
    data.qpos[index.tree_qpos] = q_tree
    mujoco.mj_kinematics(flat_model, data)
    for name, (rot, pos) in mm.body_poses_in_fb(MACHINE, q_tree).items():
        np.testing.assert_allclose(data.xpos[flat_model.body(name).id], pos, atol=1e-12)
        np.testing.assert_allclose(data.xmat[flat_model.body(name).id].reshape(3, 3), rot,
                                   atol=1e-12)


def test_only_wheel_spheres_collide_with_the_terrain(flat_model):
    m = flat_model
    index = mm.MujocoIndex(m, MACHINE)
    colliding = {(a, b) for a in range(m.ngeom) for b in range(a + 1, m.ngeom)
                 if (m.geom_contype[a] & m.geom_conaffinity[b])
                 or (m.geom_contype[b] & m.geom_conaffinity[a])}
    assert colliding == {(index.terrain_geom, int(g)) for g in index.wheel_geoms}
    for g in index.wheel_geoms:
        assert m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE
        assert m.geom_size[g, 0] == MACHINE.wheel_radius
    terrain = index.terrain_geom
    assert m.geom_priority[terrain] > m.geom_priority[index.wheel_geoms].max()
    assert m.geom_friction[terrain, 0] == T.flat().friction


def test_contacts_take_the_terrain_parameters():
    terrain = T.Terrain("gravel", np.zeros((2, 2)), friction=0.6)
    model = mm.build_model(MACHINE, terrain)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    data.qpos[2] -= 0.01
    mujoco.mj_forward(model, data)
    assert data.ncon == 4
    for i in range(data.ncon):
        assert data.contact.friction[i][0] == 0.6
        np.testing.assert_array_equal(data.contact.solref[i], mm.CONTACT_SOLREF)
        assert data.contact.dim[i] == 3


def test_options_follow_the_timestep():
    model = mm.build_model(MACHINE, T.flat(), timestep=0.001)
    assert model.opt.timestep == 0.001
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert model.opt.tolerance == mm.constants.SOLVER_TOLERANCE
    np.testing.assert_allclose(model.eq_solref, [[0.002, 1.0]] * len(MACHINE.loops))
    np.testing.assert_allclose(model.eq_solimp[:, :3], [[0.99, 0.999, 0.001]] * 5)
    assert model.opt.gravity[2] == -MACHINE.gravity


def test_actuators_take_their_limits_from_the_description(flat_model):
    m = flat_model
    for name, binding in MACHINE.chains.items():
        a = m.actuator(name)
        assert a.trntype[0] == mujoco.mjtTrn.mjTRN_TENDON
        np.testing.assert_allclose(a.forcerange, binding.cylinder.force_range)
        # F = kp (u - x) with x = tendon length - (L_c0 + L_c): zero at u = x.
        chain = binding.chain
        offset = chain.dead_length + chain.rod_length
        assert a.biasprm[0] == pytest.approx(a.gainprm[0] * offset, rel=1e-12)
        assert a.biasprm[1] == -a.gainprm[0] and a.biasprm[2] == 0.0
    for name, drive in MACHINE.direct_drives.items():
        np.testing.assert_allclose(m.actuator(name).forcerange,
                                   (-drive.effort_limit, drive.effort_limit))
    vmax, tmax = MACHINE.wheel_drive
    for name in MACHINE.wheels:
        np.testing.assert_allclose(m.actuator(name).ctrlrange, (-vmax, vmax))
        np.testing.assert_allclose(m.actuator(name).forcerange, (-tmax, tmax))


def test_cylinder_tendon_length_is_the_pin_to_pin_length(flat_model):
    data = mujoco.MjData(flat_model)
    mujoco.mj_resetDataKeyframe(flat_model, data, 0)
    mujoco.mj_forward(flat_model, data)
    q_home = COORDS.home()
    for name, binding in MACHINE.chains.items():
        stroke = q_home[COORDS.independent_names.index(name)]
        length = data.ten_length[flat_model.tendon(f"{name}_cylinder").id]
        assert length == pytest.approx(binding.chain.state(stroke).length, abs=1e-9)


def test_servo_specs():
    specs = mm.servo_specs(MACHINE)
    assert [s.name for s in specs] == list(COORDS.independent_names[:9])
    for s in specs:
        if s.tendon is not None:
            cylinder = MACHINE.chains[s.name].cylinder
            assert s.rate_range == cylinder.velocity_range
            assert s.stroke_range == MACHINE.chains[s.name].chain.stroke_range
        assert 0.0 < s.damping_ratio <= mm.SERVO_DAMPING_RATIO + 1e-12
        # Deflection at full force is the documented servo compliance.
        kind = "slide" if MACHINE.body(s.joint).joint.kind == "prismatic" else "hinge"
        assert max(map(abs, s.force_range)) / s.kp == pytest.approx(
            mm.SERVO_POSITION_ERROR[kind])
    reduced = mm.servos.reduced_inertia(MACHINE)
    kp, kv = np.array([s.kp for s in specs]), np.array([s.kv for s in specs])
    assert mm.servos.explicit_step_radius(reduced, kp, kv, mm.DEFAULT_TIMESTEP) <= 1 + 1e-7
    assert mm.servos.explicit_step_radius(reduced, kp, 20 * kv, mm.DEFAULT_TIMESTEP) > 1.01


def test_gravity_loads_match_virtual_work_of_the_description():
    """tau_i = dU/dq_i with U from the description's own kinematics (finite differences)."""
    def potential(q_ind):
        poses = mm.body_poses_in_fb(MACHINE, COORDS.joint_positions(q_ind))
        return sum(b.inertia.mass * MACHINE.gravity * (poses[b.name][0] @ b.inertia.com
                                                       + poses[b.name][1])[2]
                   for b in MACHINE.bodies)

    q_ind = COORDS.home()
    loads = mm.gravity_loads(MACHINE, q_ind)
    eps = 1e-6
    for i in range(9):
        dq = np.zeros(13)
        dq[i] = eps
        expected = (potential(q_ind + dq) - potential(q_ind - dq)) / (2 * eps)
        assert loads[i] == pytest.approx(expected, rel=1e-6, abs=1e-3)


def test_reflected_inertia_is_twice_the_kinetic_energy_of_a_unit_rate():
    """m_i = 2 T for q_dot_i = 1, T from the description's body poses (finite differences)."""
    q_ind = COORDS.home()
    locked, free = mm.reflected_inertia(MACHINE, q_ind)
    eps = 1e-6
    for i in range(9):
        dq = np.zeros(13)
        dq[i] = eps
        plus = mm.body_poses_in_fb(MACHINE, COORDS.joint_positions(q_ind + dq))
        minus = mm.body_poses_in_fb(MACHINE, COORDS.joint_positions(q_ind - dq))
        energy = 0.0
        for b in MACHINE.bodies:
            (rp, pp), (rm, pm) = plus[b.name], minus[b.name]
            v_com = (pp + rp @ b.inertia.com - pm - rm @ b.inertia.com) / (2 * eps)
            skew = (rp - rm) / (2 * eps) @ rp.T  # [w] in fb axes
            w = np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
            inertia = rp @ b.inertia.inertia @ rp.T
            energy += 0.5 * (b.inertia.mass * v_com @ v_com + w @ inertia @ w)
        assert locked[i] == pytest.approx(2 * energy, rel=1e-5)
        assert 0 < free[i] <= locked[i] * (1 + 1e-9)


def test_place_on_a_side_slope_tilts_the_base():
    slope = T.side_slope(15.0)
    position, rotation = mm.place_on_terrain(MACHINE, slope, None, (5.0, 1.0, 0.0))
    roll = math.atan2(rotation[2, 1], rotation[2, 2])
    assert roll == pytest.approx(math.radians(15.0), abs=1e-9)
    assert position[:2] == pytest.approx([5.0, 1.0])
    # Every wheel sphere touches the plane: centre-to-plane distance = radius.
    poses = mm.body_poses_in_fb(MACHINE, COORDS.joint_positions(COORDS.home()))
    n = slope.normal(0.0, 0.0)
    for w in MACHINE.wheels:
        centre = position + rotation @ poses[w][1]
        height = slope.height(centre[0], centre[1])
        assert (centre[2] - height) * n[2] == pytest.approx(MACHINE.wheel_radius, abs=1e-9)


@pytest.mark.parametrize("call, error", [
    (lambda: mm.build_model(MACHINE, T.flat(), timestep=0.0), ModelError),
    (lambda: mm.build_model(MACHINE, T.flat(), timestep=0.02), ModelError),
    (lambda: mm.servo_specs(MACHINE, timestep=float("nan")), ModelError),
    (lambda: mm.write_mjcf(MACHINE, "/tmp", terrains=[T.flat(), T.flat()]), ModelError),
    (lambda: mm.place_on_terrain(MACHINE, T.flat(), None, (44.0, 0.0, 0.0)), PlacementError),
    (lambda: mm.place_on_terrain(MACHINE, T.flat(), None, (0.0, float("inf"), 0.0)),
     PlacementError),
    (lambda: mm.home_keyframe(MACHINE, T.flat(), np.zeros(12)), StateError),
    (lambda: mm.home_keyframe(MACHINE, T.flat(), np.r_[COORDS.home()[:5], 2.0, 0, 0, 0,
                                                       0, 0, 0, 0]), StateError),
    (lambda: mm.MujocoIndex(mujoco.MjModel.from_xml_string("<mujoco/>"), MACHINE), ModelError),
])
def test_bad_input_raises_typed_errors(call, error):
    with pytest.raises(error):
        call()


def _crane_pose(machine, lift_deg: float, tilt_deg: float, telescope: float) -> np.ndarray:
    """Independent coordinates at home with the crane's lift, tilt and telescope set."""
    q = machine.coordinates.home()
    chains = machine.chains
    q[3] = chains["lift"].chain.stroke_from_angle(math.radians(lift_deg))
    q[4] = chains["tilt"].chain.stroke_from_angle(math.radians(tilt_deg))
    q[5] = telescope
    return q


@pytest.mark.parametrize("payload_mass", [10.0, 300.0])
def test_damping_schedule_keeps_the_explicit_servo_step_stable_at_every_pose(payload_mass):
    """The designed damping is unstable with the crane upright; the scheduled one is not.

    Oracle: the spectral radius of the linearised explicit step (`explicit_step_radius`) on
    the bare tree's reduced inertia at each pose, independent of the schedule's own mass
    matrix (the compiled machine model's, from MuJoCo's state).
    """
    machine = build_reference_machine(payload_mass=payload_mass)
    model = mm.build_model(machine, T.flat())
    data = mujoco.MjData(model)
    specs = mm.servo_specs(machine)
    schedule = mm.DampingSchedule(model, mm.MujocoIndex(model, machine), machine, specs,
                                  model.opt.timestep)
    kp = np.array([s.kp for s in specs])
    h = mm.DEFAULT_TIMESTEP
    poses = [(45.0, -90.0, 0.5), (79.0, -18.0, 0.0), (79.0, -18.0, 1.0), (60.0, -18.0, 0.0),
             (79.0, -60.0, 0.0), (30.0, -140.0, 1.1), (0.0, -90.0, 0.0), (70.0, -40.0, 0.5)]
    designed = []
    for lift, tilt, tele in poses:
        q = _crane_pose(machine, lift, tilt, tele)
        data.qpos[:], _ = mm.home_keyframe(machine, T.flat(), q)
        mujoco.mj_forward(model, data)
        kv = schedule.damping(data, q)
        assert np.all(kv <= schedule.designed) and np.all(kv > 0)
        reduced = mm.servos.reduced_inertia(machine, q)
        assert mm.servos.explicit_step_radius(reduced, kp, kv, h) <= 1 + 1e-7, (lift, tilt, tele)
        designed.append(mm.servos.explicit_step_radius(reduced, kp, schedule.designed, h))
    # Home: the designed damping, untouched; upright: the designed damping diverges.
    q = COORDS.home()
    data.qpos[:], _ = mm.home_keyframe(machine, T.flat(), q)
    mujoco.mj_forward(model, data)
    np.testing.assert_array_equal(schedule.damping(data, q), schedule.designed)
    assert designed[0] <= 1 + 1e-7 and designed[1] > 1.2  # 1.40 at 10 kg, at the end stop


def test_damping_schedule_maps_the_inertia_through_the_coordinates_jacobian_to_the_bit():
    """Its own chain entries (`CylinderChain.driven_terms`) against `TreeCoordinates.jacobian`
    at random poses, strokes a little past their ends (clipped), and a non-finite one."""
    machine = build_reference_machine()
    model = mm.build_model(machine, T.flat())
    data = mujoco.MjData(model)
    index = mm.MujocoIndex(model, machine)
    schedule = mm.DampingSchedule(model, index, machine, mm.servo_specs(machine),
                                  model.opt.timestep)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(5)
    lo, hi = np.maximum(COORDS.lower, -3.0), np.minimum(COORDS.upper, 3.0)
    for _ in range(50):
        q = rng.uniform(lo - 0.05, hi + 0.05)
        schedule.damping(data, q)
        clipped = q.copy()
        clipped[:9] = np.clip(q[:9], schedule._stroke_range[0], schedule._stroke_range[1])
        expected = schedule._jac.copy()
        expected[index.tree_dof, 6:], _ = COORDS.jacobian(clipped)
        assert schedule._jac.tobytes() == expected.tobytes()
    with pytest.raises(StateError, match="non-finite"):
        schedule.damping(data, np.full(13, np.nan))
