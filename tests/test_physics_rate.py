"""Physics-rate ground truth: the recorder against MuJoCo's contacts, and what it catches."""

import numpy as np
import pytest

from models import build_reference_machine
from models import terrain as T
from scenarios.closed_loop_scenarios import SCENARIOS
from scenarios.metrics import TIP_CONTACT_SECONDS, closed_loop_metrics
from scenarios.physics_rate import NormalForceRecorder
from scenarios.simulator import Simulator


@pytest.fixture(scope="module")
def sim():
    return Simulator(build_reference_machine(), T.flat())


def test_recorder_matches_the_ground_truth_contacts_at_every_step(sim):
    sim.reset()
    rec = NormalForceRecorder(sim)
    try:
        sim.set_command(cylinder_rates={"slew": 0.1, "lift": 0.05}, wheel_speeds=(1.0, -1.0))
        for _ in range(25):
            sim.step(1)
            truth = sim.measure()[1]
            np.testing.assert_allclose(rec.normal_force[-1], truth.normal_force, rtol=1e-6,
                                       atol=1e-6)
            assert rec.time[-1] == pytest.approx(sim.measure()[0].time)
    finally:
        rec.close()
    assert len(rec) == 25
    sim.step(1)
    assert len(rec) == 25  # closed: no longer called


def test_recorder_sums_are_np_add_at_to_the_bit():
    """On rough ground (merged contacts without rows, several per wheel) each step's sums are
    those of `np.add.at` over the wheels' contacts in MuJoCo's order."""
    from scenarios.closed_loop_scenarios import scenario_terrain

    sc = SCENARIOS["swing-out"]
    machine = build_reference_machine(payload_mass=sc.payload_mass)
    rough = Simulator(machine, scenario_terrain(sc, 0))
    rough.reset(sc.start_pose.q(machine), sc.start, settle_time=0.2)
    rec = NormalForceRecorder(rough)
    wheel_of_geom = np.full(rough.model.ngeom, -1)
    wheel_of_geom[rough.index.wheel_geoms] = np.arange(4)
    expected, merged = [], []

    def reference(sim, qpos, qvel, t):
        c, f = sim.data.contact, np.zeros(4)
        wheel = np.maximum(wheel_of_geom[c.geom[:, 0]], wheel_of_geom[c.geom[:, 1]])
        keep = (wheel >= 0) & (c.efc_address >= 0)
        np.add.at(f, wheel[keep], sim.data.efc_force[c.efc_address[keep]])
        expected.append(f)
        merged.append(int((c.efc_address < 0).sum()))

    rough.add_step_listener(reference)
    rough.set_command(cylinder_rates={"slew": 0.2}, wheel_speeds=(1.5, 1.5))
    rough.step(150)
    rec.close()
    assert rec.normal_force.tobytes() == np.array(expected).tobytes()
    assert max(merged) > 0 and np.all(rec.normal_force > 0)


def _log(n_ctrl: int = 300, per_tick: int = 5) -> dict:
    """A synthetic closed-loop log: all wheels at 10 kN, at the control and physics rates."""
    t = np.arange(n_ctrl) * 0.01
    ts = np.arange(n_ctrl * per_tick) * 0.002
    return {
        "time": t, "normal_force": np.full((n_ctrl, 4), 1e4),
        "in_contact": np.ones((n_ctrl, 4), bool),
        "base_rotation": np.repeat(np.eye(3)[None], n_ctrl, axis=0),
        "tcp_error": np.zeros(n_ctrl), "last_goal_given": np.ones(n_ctrl),
        "distance": np.zeros(n_ctrl), "speed_scale": np.ones(n_ctrl),
        "physics_time": ts, "physics_normal_force": np.full((ts.size, 4), 1e4),
    }


def test_a_short_drop_between_control_samples_is_counted():
    log = _log()
    log["physics_normal_force"][751:753, 2] = 0.0  # 4 ms at 0 N, between two 10 ms samples
    m = closed_loop_metrics(log, SCENARIOS["swing-out"], 1000.0)
    assert m["metrics_rate_hz"] == pytest.approx(500.0)
    assert m["min_normal_force_N"]["FR"] == 0.0
    assert m["time_below_threshold_s"]["FR"] == pytest.approx(0.004)
    assert m["longest_below_threshold_s"]["FR"] == pytest.approx(0.004)
    assert not m["tipped"]
    control_only = {k: v for k, v in log.items() if not k.startswith("physics_")}
    m = closed_loop_metrics(control_only, SCENARIOS["swing-out"], 1000.0)
    assert m["min_normal_force_N"]["FR"] == 1e4  # what a 100 Hz metric sees


@pytest.mark.parametrize("seconds, tipped", [(TIP_CONTACT_SECONDS - 0.004, False),
                                             (TIP_CONTACT_SECONDS, True)])
def test_tipped_is_two_wheels_off_for_the_tip_time(seconds, tipped):
    log = _log()
    n = int(round(seconds / 0.002))
    log["physics_normal_force"][600:600 + n, :2] = 0.0
    assert closed_loop_metrics(log, SCENARIOS["swing-out"], 1000.0)["tipped"] is tipped


def test_a_standing_task_completes_although_the_base_moved_back_a_little():
    log = _log()
    log["distance"][:] = -0.004  # creep, not driving
    scenario = SCENARIOS["pick-place-slope"]
    assert scenario.drive_distance == 0.0
    assert closed_loop_metrics(log, scenario, 1000.0)["task_completed"]


def test_the_held_drive_keeps_the_machine_on_a_slope():
    sim = Simulator(build_reference_machine(), T.side_slope(-12.0))
    sim.reset(None, (8.0, 0.0, 1.5708))  # facing across the contour lines: rolling downhill
    p0 = sim.measure()[0].base_position.copy()
    sim.step(2500)  # 5 s with a zero drive command
    creep = np.linalg.norm(sim.measure()[0].base_position - p0)
    assert creep < 0.03, creep  # a velocity servo alone lets it roll 0.3 m in 5 s
