"""The machine's compliance (`estimators.compliance`) against MuJoCo.

Oracles: MuJoCo's own constraint rows (the contact law), setpoint steps of the left
suspension servo on flat ground (the warp stiffness, at home and at long reach), penetration
against load (the tyre stiffness) and ground-truth normal forces of moving runs (the
compliance fourth row).
"""

from __future__ import annotations

import dataclasses
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pytest

from estimators import EstimatorInputError, NormalForceEstimator
from estimators.compliance import (
    ComplianceEstimator,
    WarpCompliance,
    compliance_forces,
    contact_force,
    contact_impedance,
    oil_column_stiffness,
    tyre_stiffness,
)
from models.terrain import flat, rough
from scenarios.scenario import CranePose
from scenarios.simulator import Simulator
from wbc.controllers.config import ForceConfig
from wbc.force_models.feedback import warp_stiffness

ROOT = Path(__file__).resolve().parents[1]
DIAGONAL = np.array([1.0, -1.0, -1.0, 1.0])
LONG_REACH = CranePose(0.0, 30.0, -30.0, 1.0)  # boom forward, telescope out: RL, RR at 5 kN


@pytest.fixture(scope="module")
def warp(machine):
    return WarpCompliance(machine)


@pytest.fixture(scope="module")
def sim(machine):
    return Simulator(machine, flat())


def _penetrations(sim) -> np.ndarray:
    """-dist of each wheel's contact [m], FL, RL, FR, RR."""
    m, d = sim.model, sim.data
    ids = {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, w): i
           for i, w in enumerate(sim.machine.wheels)}
    out = np.full(4, np.nan)
    for c in d.contact[:d.ncon]:
        for g in c.geom:
            if m.geom_bodyid[g] in ids:
                out[ids[m.geom_bodyid[g]]] = -c.dist
    return out


def test_contact_law_is_mujocos(sim, warp):
    """F(r) with body_invweight0 reproduces MuJoCo's settled contact rows exactly."""
    sim.reset()
    m, d = sim.model, sim.data
    r = _penetrations(sim)
    f, _ = contact_force(r, warp.inv_weight)
    np.testing.assert_allclose(f, sim.measure()[1].normal_force, rtol=2e-3)
    for c in d.contact[:d.ncon]:  # the regularizer's A_hat is the wheel's invweight0
        a, imp = c.efc_address, d.efc_KBIP[c.efc_address, 2]
        a_hat = d.efc_R[a] * imp / (1.0 - imp)
        assert a_hat == pytest.approx(m.body_invweight0[m.geom_bodyid[c.geom[1]], 0],
                                      rel=1e-9)
        assert d.efc_force[a] == pytest.approx(d.efc_aref[a] / d.efc_R[a], rel=1e-4)


def test_contact_derivatives_by_finite_differences(warp):
    r = np.array([2e-4, 6e-4, 0.99e-3, 1.01e-3, 1.6e-3, 3e-3])  # about the sigmoid's midpoint
    h = 1e-9
    _, dd = contact_impedance(r)
    fd = (contact_impedance(r + h)[0] - contact_impedance(r - h)[0]) / (2 * h)
    np.testing.assert_allclose(dd, fd, rtol=1e-5, atol=1e-3)
    _, k = contact_force(r, warp.inv_weight[0])
    fd = (contact_force(r + h, warp.inv_weight[0])[0]
          - contact_force(r - h, warp.inv_weight[0])[0]) / (2 * h)
    np.testing.assert_allclose(k, fd, rtol=1e-5)
    pen, _ = tyre_stiffness(np.array([5e3, 12.5e3]), warp.inv_weight[0])
    np.testing.assert_allclose(contact_force(pen, warp.inv_weight[0])[0], [5e3, 12.5e3],
                               rtol=1e-9)


@pytest.mark.parametrize("pose", [None, LONG_REACH], ids=["home", "long-reach"])
def test_warp_and_tyre_stiffness_match_mujoco(machine, sim, warp, pose):
    """Steps of 0.02-0.2 mm of the left setpoint: k_w and each tyre's stiffness within 10 %."""
    q = None if pose is None else pose.q(machine)
    h = sim.timestep
    for ds in (2e-5, 1e-4, 2e-4):
        sim.reset(q)
        s0, g0 = sim.measure()
        f0, r0 = g0.normal_force.copy(), _penetrations(sim)
        derived = warp.gains(s0.q, f0)
        sim.set_command(cylinder_rates={"bogie_L": ds / h})
        sim.step(1)
        sim.set_command()
        sim.step(int(1.0 / h))
        s1, g1 = sim.measure()
        df = g1.normal_force - f0
        step = ((s1.servo_setpoint[0] - s0.servo_setpoint[0])
                - (s1.servo_setpoint[1] - s0.servo_setpoint[1]))
        assert step == pytest.approx(ds, rel=1e-9)
        measured = DIAGONAL @ df / 4 / step
        assert measured == pytest.approx(derived.stiffness, rel=0.10)
        assert measured == pytest.approx(derived.stiffness, rel=0.01)  # in fact
        # the secant of a step against the tangent at the step's mean load
        tangent = warp.gains(s0.q, f0 + df / 2).tyre
        np.testing.assert_allclose(df / (_penetrations(sim) - r0), tangent, rtol=0.10)
    # the controller's default: the same derivation at home, static loads
    assert warp.stiffness() == pytest.approx(6.99e6, rel=0.01)


def test_warp_stiffness_depends_on_strokes(machine, warp):
    lo, hi = machine.chains["bogie_L"].chain.stroke_range
    q = machine.coordinates.home()
    k = []
    for x in np.linspace(lo + 0.01, hi - 0.01, 5):
        q[0] = q[1] = x
        g = warp.gains(q)
        assert g.gains[0] == pytest.approx(g.gains[1])
        k.append(g.stiffness)
    assert np.all(np.diff(k) < 0)  # k1 grows with the stroke, the servo softens faster
    assert 0.85 < min(k) / max(k) < 1.0  # -5 % / +8 % about home


def test_controller_uses_the_derived_value(machine):
    assert ForceConfig().warp_stiffness is None
    assert ForceConfig().warp_stiffness_for(machine) == pytest.approx(warp_stiffness(machine))
    assert ForceConfig(warp_stiffness=0.0).warp_stiffness_for(machine) == 0.0
    for flags, pattern in (("-rniE", r"measured (in|on) (the )?(mujoco|reference)"),
                           ("-rnE", r"WARP_STIFFNESS|6\.88e6|6\.99e6")):
        out = subprocess.run(["grep", flags, pattern, "wbc", "--include=*.py"],
                             cwd=ROOT, capture_output=True, text=True)
        assert out.stdout == ""


def test_servo_gain_is_of_the_order_of_the_oil_column(machine, warp):
    cyl = machine.chains["bogie_L"].cylinder
    for beta in (1.4e9, 1.6e9):
        for x in (0.06, 0.125, 0.19):
            ratio = oil_column_stiffness(cyl, x, beta) / warp.kp[0]
            assert 1.0 < ratio < 3.0  # no hoses: stiffer; 0.3 L of hoses: about kp
            assert 0.7 < oil_column_stiffness(cyl, x, beta, 3e-4) / warp.kp[0] < 2.0


def test_compliance_forces_match_the_actuators(machine, sim):
    sim.reset(LONG_REACH.q(machine))
    state, _ = sim.measure()
    np.testing.assert_allclose(compliance_forces(machine, state), state.suspension_force,
                               atol=100.0)  # 1 um of kp (s - x)
    big = dataclasses.replace(state, servo_setpoint=state.servo_setpoint + 0.05)
    hi = machine.chains["bogie_L"].cylinder.force_range[1]
    np.testing.assert_allclose(compliance_forces(machine, big), [hi, hi])


def _run(machine, terrain, drive):
    sim = Simulator(machine, terrain)
    sim.reset()
    states, truth = [], []
    for k in range(150):
        t = 0.02 * k
        sim.set_command(cylinder_rates={"bogie_L": 0.0005 * np.sin(2 * t),
                                        "bogie_R": -0.0005 * np.sin(1.3 * t),
                                        "slew": 0.1 * np.sin(0.8 * t),
                                        "lift": 0.02 * np.cos(1.1 * t)},
                        wheel_speeds=(drive, drive))
        sim.step(10)
        state, gt = sim.measure()
        if gt.in_contact.all():
            states.append(state)
            truth.append(gt.normal_force.copy())
    return states, np.array(truth)


@pytest.mark.parametrize("terrain, drive", [(flat(), 0.0), (rough(0, max_slope_deg=10.0), 1.0)],
                         ids=["flat", "rough"])
def test_compliance_row_on_stroke_sensors(machine, terrain, drive):
    """Mean |error| / static load: exact < 0.05 %, 1 um steps < 0.1 %, + 2 um noise < 0.3 %.

    Setpoints 0.25 mm about home (a warp of +-3 kN: every wheel stays loaded).
    """
    closure = NormalForceEstimator(machine, fourth="cylinder-force", strokes="clip")
    est = ComplianceEstimator(machine, closure)
    states, truth = _run(machine, terrain, drive)
    assert len(states) > 50
    load = machine.total_mass * machine.gravity / 4
    rng = np.random.default_rng(0)

    def error(noise: float | None) -> float:
        f = []
        for s in states:
            if noise is not None:
                q = s.q.copy()
                q[:2] = np.round((q[:2] + rng.normal(0.0, noise, 2)) / 1e-6) * 1e-6
                s = dataclasses.replace(s, q=q)
            f.append(est.estimate(s).normal_forces)
        return float(np.abs(np.array(f) - truth).mean() / load)

    assert error(None) < 5e-4
    assert error(0.0) < 1e-3
    assert error(2e-6) < 3e-3
    lin = est.linearize(states[0])
    np.testing.assert_allclose(lin.normal_forces, est.estimate(states[0]).normal_forces, rtol=1e-9)


def test_bad_inputs_raise(machine, warp):
    with pytest.raises(EstimatorInputError):
        tyre_stiffness([1e4, -1.0], warp.inv_weight[0])
    with pytest.raises(EstimatorInputError):
        warp.gains(np.zeros(3))
    with pytest.raises(EstimatorInputError):
        warp.gains(machine.coordinates.home(), [1.0, 2.0])
    with pytest.raises(EstimatorInputError):
        oil_column_stiffness(machine.chains["bogie_L"].cylinder, 0.0)
    state = dataclasses.replace(_settled_state(machine), servo_setpoint=None)
    with pytest.raises(EstimatorInputError):
        compliance_forces(machine, state)


def _settled_state(machine):
    return Simulator(machine, flat()).measure()[0]
