"""The load chart: affine efforts against MuJoCo's servo forces, limits, and bad input."""

import numpy as np
import pytest

from models import build_reference_machine
from models import terrain as T
from models.errors import ModelError
from models.load_chart import _efforts_and_wrench, _models, load_chart, rated_payload
from models.state import MachineState
from scenarios.simulator import Simulator

MACHINE = build_reference_machine()
THRESHOLD = 1262.0


def _pose(telescope: float) -> np.ndarray:
    chart = {(r["slew_deg"], r["telescope_m"]) for r in load_chart(MACHINE, THRESHOLD)}
    assert (0.0, 0.8) in chart
    ch = MACHINE.chains
    q = MACHINE.coordinates.home()
    q[2] = ch["slew"].chain.stroke_from_angle(0.0)
    q[3] = ch["lift"].chain.stroke_from_angle(np.radians(20.0))
    q[4] = ch["tilt"].chain.stroke_from_angle(np.radians(-40.0))
    q[5] = telescope
    q[6] = -np.radians(-20.0)
    return q


def test_the_lift_force_at_the_rated_load_is_its_limit_in_mujoco():
    q = _pose(0.8)
    rated = rated_payload(MACHINE, q, THRESHOLD)
    assert rated.limit == "lift" and 200.0 < rated.mass < 1000.0
    mass = 0.9 * rated.mass
    heavy = build_reference_machine(payload_mass=mass)
    sim = Simulator(heavy, T.flat())
    sim.reset(q, settle_time=2.0)
    lift = MACHINE.coordinates.independent_names.index("lift")
    measured = sim.actuator_forces()[lift]
    zero = np.zeros(13)
    state = MachineState(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6),
                         sim.measure()[0].q, zero, zero)
    p0, p1 = _models(MACHINE)
    e0, _ = _efforts_and_wrench(p0, state)
    e1, _ = _efforts_and_wrench(p1, state)
    predicted = e0[lift] + (mass - 1.0) * (e1[lift] - e0[lift])
    assert measured == pytest.approx(predicted, rel=0.02)
    assert predicted == pytest.approx(0.9 * MACHINE.chains["lift"].cylinder.force_range[1]
                                      + 0.1 * (e0[lift] - (e1[lift] - e0[lift])), rel=0.02)


def test_the_chart_falls_with_reach_and_tipping_binds_on_a_slope():
    chart = load_chart(MACHINE, THRESHOLD, slews_deg=(0.0,))
    masses = [r["rated_kg"] for r in chart]
    assert masses == sorted(masses, reverse=True)
    c, s = np.cos(0.2), np.sin(0.2)  # an 11.5 deg side slope
    tilt = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    q = _pose(1.05)
    q[2] = MACHINE.chains["slew"].chain.stroke_from_angle(np.radians(60.0))
    level = rated_payload(MACHINE, q, THRESHOLD)
    steep = [rated_payload(MACHINE, q, THRESHOLD, base_rotation=r) for r in (tilt, tilt.T)]
    assert min(s.mass for s in steep) < level.mass
    assert any(s.limit == "tipping" for s in steep)
    assert np.all(min(steep, key=lambda s: s.mass).forces >= THRESHOLD - 1e-6)


def test_bad_threshold_raises():
    with pytest.raises(ModelError, match="threshold_n"):
        rated_payload(MACHINE, MACHINE.coordinates.home(), float("nan"))
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ModelError, match="effort_fraction"):
            rated_payload(MACHINE, MACHINE.coordinates.home(), THRESHOLD,
                          effort_fraction=bad)


def test_an_effort_fraction_puts_the_limiting_force_at_that_share_of_its_range():
    q = _pose(0.8)
    full = rated_payload(MACHINE, q, THRESHOLD)
    part = rated_payload(MACHINE, q, THRESHOLD, effort_fraction=0.9)
    assert part.limit == full.limit == "lift" and part.mass < full.mass
    zero = np.zeros(13)
    state = MachineState(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), q, zero, zero)
    p0, p1 = _models(MACHINE)
    e0, _ = _efforts_and_wrench(p0, state)
    e1, _ = _efforts_and_wrench(p1, state)
    lift = MACHINE.coordinates.independent_names.index("lift")
    at = e0[lift] + (part.mass - 1.0) * (e1[lift] - e0[lift])  # p0 carries 1 kg
    assert at == pytest.approx(0.9 * MACHINE.chains["lift"].cylinder.force_range[1], rel=1e-9)


def test_wbc_machine_load_chart_prints_and_plots(tmp_path, capsys):
    from wbc_hdmm.cli import main

    png = tmp_path / "chart.png"
    assert main(["machine", "--load-chart", str(png), "--slope", "8"]) == 0
    out = capsys.readouterr().out
    assert "rated payload" in out and png.stat().st_size > 1000
    assert len([line for line in out.splitlines() if "(lift" in line or "(tilt" in line
                or "(tipping" in line]) == 6
    assert main(["machine", "--load-chart", str(png), "--slope", "90"]) == 2



def test_the_payload_sensitivity_carries_the_payload_weight():
    """One kilogram more adds g newtons over the wheels at the payload's centre of mass."""
    import pinocchio as pin

    from models.load_chart import _ground_rows

    q = _pose(0.8)
    r = rated_payload(MACHINE, q, THRESHOLD)
    zero = np.zeros(13)
    state = MachineState(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), q, zero, zero)
    p0, p1 = _models(MACHINE)
    moments = []
    for pm in (p0, p1):  # the whole machine's mass and centre of mass (Pinocchio)
        qp, _, _ = pm.configuration(state)
        c = pin.centerOfMass(pm.model, pm.data, qp)
        moments.append((pin.computeTotalMass(pm.model), c))
    (m0, c0), (m1, c1) = moments
    com = (m1 * c1 - m0 * c0) / (m1 - m0)  # the payload's centre of mass, in fb
    rows, _ = _ground_rows(p0, state)
    g = MACHINE.gravity
    np.testing.assert_allclose(rows @ r.sensitivity, [g, g * com[1], -g * com[0]],
                               rtol=1e-6, atol=1e-6)
    assert r.sensitivity.min() < 0 < r.sensitivity.max()  # the load tilts the machine


@pytest.mark.parametrize("slope_deg", [10.0, -10.0])
def test_the_equilibrium_rows_match_mujoco_on_a_side_slope(slope_deg):
    """The forces the rows fix (total, roll, pitch) against MuJoCo's, 200 kg out on a slope.

    The least-norm forces carry everything but the diagonal split (statically indeterminate
    here, set by the suspension): MuJoCo's forces projected on the rows' space are the
    oracle. Without the tangential forces' moment the error is 2 kN per wheel.
    """
    from models.load_chart import _ground_rows, _normal_rows

    heavy = build_reference_machine(payload_mass=200.0)
    q = _pose(0.8)
    q[2] = MACHINE.chains["slew"].chain.stroke_from_angle(np.radians(30.0))
    sim = Simulator(heavy, T.side_slope(slope_deg))
    sim.reset(q, settle_time=2.0)
    measured, contacts = sim.measure()
    assert contacts.in_contact.all()
    zero = np.zeros(13)
    state = MachineState(np.zeros(3), measured.base_rotation, np.zeros(6), np.zeros(6),
                         measured.q, zero, zero)
    p0, p1 = _models(MACHINE)
    (_, w0), (_, w1) = _efforts_and_wrench(p0, state), _efforts_and_wrench(p1, state)
    wrench = w0 + (200.0 - 1.0) * (w1 - w0)  # p0 carries 1 kg, p1 2 kg
    rows, height = _ground_rows(p0, state)
    pinv = np.linalg.pinv(rows)
    predicted = pinv @ _normal_rows(wrench, height)
    oracle = pinv @ (rows @ contacts.normal_force)
    static = heavy.total_mass * heavy.gravity / 4
    assert np.abs(predicted - oracle).max() < 0.02 * static
