"""The side pairs' reserve: the swing of each side pair's load sum and the MPC's late rows."""


import dataclasses

import numpy as np
import pytest

from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state
from wbc import ConfigurationError, ControllerConfig, ForceConfig, MpcController
from wbc.constraints import SideReserveConstraint
from wbc.force_models.feedback import DIAGONAL, ClosureFeedback
from wbc.force_models.fluctuation import SideLoadFluctuation

DT = 0.01
CONTACT = (True,) * 4
MEAN = np.array([9000.0, 6000.0, 4000.0, 3000.0])
ROLL = np.array([1.0, 1.0, -1.0, -1.0]) / 2  # load from the right pair to the left


def _drive(meas, pattern, amplitude, speed, seconds, start=0.0, contact=CONTACT):
    """Loads ``MEAN + amplitude pattern sin(2 pi 2 t)`` (2 Hz, far above the high-pass)."""
    n = int(round(seconds / DT))
    for i in range(n):
        t = start + i * DT
        meas.update(MEAN + amplitude * pattern * np.sin(2 * np.pi * 2.0 * t), contact, t,
                    speed)
    return start + n * DT


def test_side_swing_is_the_rms_of_the_side_sums_not_per_unit_speed():
    gain = 1.0 / np.sqrt(1.0 + 1.0 / (2 * np.pi * 2.0 * 0.2) ** 2)  # the 0.2 s high-pass
    for speed in (0.05, 0.5):  # the same swing at a tenth of the speed: the same measure
        meas = SideLoadFluctuation(high_pass=0.2, window=1.0)
        _drive(meas, ROLL, 2000.0, speed, 12.0)
        # Each side sum swings by 2 kN (half of the four wheels' pattern each): RMS A/sqrt 2.
        np.testing.assert_allclose(meas.sigma, 2000.0 / np.sqrt(2) * gain, rtol=0.04)
        # The slow sums keep the low-pass filter's ripple, 37 % of the swing at 2 Hz.
        np.testing.assert_allclose(meas.mean, [15000.0, 7000.0], atol=0.38 * 2000.0)


def test_a_warp_swing_does_not_count_and_standing_keeps_the_measure():
    meas = SideLoadFluctuation()
    t = _drive(meas, DIAGONAL.astype(float), 3000.0, 0.4, 6.0)  # within each pair
    np.testing.assert_allclose(meas.sigma, 0.0, atol=1e-6)
    t = _drive(meas, ROLL, 1000.0, 0.4, 6.0, start=t)
    sigma = meas.sigma.copy()
    assert np.all(sigma > 500.0)
    t = _drive(meas, ROLL, 4000.0, 0.0, 3.0, start=t)  # standing: kept
    np.testing.assert_array_equal(meas.sigma, sigma)
    _drive(meas, ROLL, 4000.0, 0.4, 3.0, start=t, contact=(True, False, True, True))
    np.testing.assert_array_equal(meas.sigma, sigma)  # on three wheels: kept
    meas.reset()
    assert meas.mean is None and np.all(meas.sigma == 0.0)


def _controller(machine, **force):
    st = make_state(machine)
    model = AffineForceModel.reference(machine, st.q)
    cfg = ControllerConfig(force=ForceConfig(side_reserve_z=2.0, **force))
    return MpcController(machine, cfg, force_model=model), st, model


def test_rows_close_the_nominal_plans_shortfall_at_every_later_node(machine):
    ctrl, st, model = _controller(machine)
    assert ctrl.layout.n_slack == 10 and ctrl.side_reserve is not None
    res = ctrl.side_reserve
    ctrl.step(st)
    ctx = ctrl.context(st)
    ctrl.force_constraint.compute(ctx)
    assert res.compute(ctx) is None  # no reserve: no rows
    thresholds = ctrl.force_constraint.thresholds[2:].sum()
    need = 2 * model.f_static[0] + 1500.0  # 1.5 kN more than the right pair carries
    res.set_reserve([0.0, need - thresholds])
    ineq = res.compute(ctx)
    A, b = ctrl.force_constraint.last_forces_map
    nodes, times = res.nodes(ctx, A.shape[0] // 4)
    assert nodes[0] == 1 and nodes[-1] == A.shape[0] // 4 - 1  # after now, the terminal
    assert ineq.G.shape == (nodes.size, ctrl.layout.n)  # the right pair only
    f_nom = (A @ res.nominal(ctx) + b).reshape(-1, 4)[nodes]
    short = need - f_nom[:, 2] - f_nom[:, 3]
    np.testing.assert_allclose(short, 1500.0, atol=1e-6)  # the machine stands still
    wanted = need - short * np.exp(-times / res.time_constant)
    rng = np.random.default_rng(0)
    x = rng.normal(size=ctrl.layout.n)
    x[ctrl.layout.slack] = 0.0
    f = (A @ x + b).reshape(-1, 4)
    fs = ctrl.force_constraint.force_scale
    # G x - h = (wanted - (f_FR + f_RR)) / f_s at every constrained node.
    np.testing.assert_allclose(ineq.G @ x - ineq.h, (wanted - f[nodes, 2] - f[nodes, 3]) / fs,
                               atol=1e-9)
    slack = ctrl.layout.slack.start + 9  # the right pair's own slack
    np.testing.assert_array_equal(ineq.G[:, slack], -1.0)
    assert np.all(ineq.G[:, ctrl.layout.slack.start:slack] == 0.0)
    # A wheel off the ground: no side rows (the lifted wheel's rule applies instead).
    ctrl.force_constraint.last_in_contact = np.array([True, True, False, True])
    assert res.compute(ctx) is None


def test_the_crane_slews_load_back_to_the_side_that_needs_room(machine):
    ctrl, st, model = _controller(machine)
    w = model.f_static[0]
    # The reference model moves 3 kN/m per wheel from right to left with the slew stroke:
    # 600 N more on the right pair means 0.1 m less slew stroke.
    reserve = 2 * w + 600.0 - ctrl.force_constraint.thresholds[2:].sum()
    plant = KinematicPlant(st, DT)
    for _ in range(500):
        ctrl.side_reserve.set_reserve([0.0, reserve])
        plant.apply(ctrl.step(plant.measure()))
    slew = plant.measure().q[2] - st.q[2]
    assert -0.11 < slew < -0.09  # in about T = 1 s and held (5 s here)
    f_now = model.estimate(plant.measure()).normal_forces
    assert f_now[2] + f_now[3] == pytest.approx(2 * w + 600.0, abs=60.0)
    assert np.all(ctrl.last_plan.slack[8:] < 1e-6)
    # Off by default: eight slacks and no side rows.
    off = MpcController(machine, ControllerConfig(), force_model=model)
    assert off.side_reserve is None and off.layout.n_slack == 8


def test_the_reserve_is_the_floor_or_the_measured_swing_while_driving(machine):
    st0 = make_state(machine)
    model = AffineForceModel(MEAN, st0.q)
    cfg = ControllerConfig(force=ForceConfig(side_reserve=3000.0, side_reserve_z=2.0))
    ctrl = MpcController(machine, cfg, force_model=model, feedback=ClosureFeedback(model))
    assert ctrl.layout.n_slack == 10
    ctrl.step(st0)
    np.testing.assert_array_equal(ctrl.side_reserve.reserve, 0.0)  # standing: none
    for i in range(300):  # driving at 0.1 m/s; the right pair's load swings by 4 kN
        # The model's own sums swing (the closure measures the diagonal split only).
        swung = AffineForceModel(MEAN + 4000.0 * ROLL * np.sin(2 * np.pi * 2.0 * i * DT),
                                 st0.q)
        ctrl.force_model = ctrl.force_constraint.model = swung
        ctrl.feedback = ClosureFeedback(swung)
        ctrl.step(dataclasses.replace(st0, time=i * DT,
                                      base_twist=np.array([0.1, 0, 0, 0, 0, 0])))
    sigma = ctrl.side_swing.sigma
    assert np.all(2.0 * sigma > 3000.0)  # ~2.4 kN RMS: the measure is above the floor
    np.testing.assert_allclose(ctrl.side_reserve.reserve, 2.0 * sigma)
    off = MpcController(machine, ControllerConfig(force=ForceConfig(side_reserve=3000.0)),
                        force_model=model, feedback=ClosureFeedback(model))
    for i in range(150):
        off.step(dataclasses.replace(st0, time=i * DT,
                                     base_twist=np.array([0.1, 0, 0, 0, 0, 0])))
    np.testing.assert_array_equal(off.side_reserve.reserve, 3000.0)  # z = 0: the floor


def test_side_reserve_settings_are_checked():
    with pytest.raises(ConfigurationError, match="side_reserve_z"):
        ForceConfig(side_reserve_z=-1.0)
    with pytest.raises(ConfigurationError, match="soft"):
        ForceConfig(side_reserve_z=2.0, soft=False)
    with pytest.raises(ConfigurationError, match="soft"):
        ForceConfig(side_reserve=1000.0, soft=False)
    for junk in (np.ones(2), "yes", None):  # not a flag: said so, not numpy's truth error
        with pytest.raises(ConfigurationError, match="soft must be True or False"):
            ForceConfig(side_reserve=1000.0, soft=junk)
    res = SideReserveConstraint(None)
    with pytest.raises(ConfigurationError, match="side reserve"):
        res.set_reserve([1.0, -1.0])
    with pytest.raises(ConfigurationError, match="time_constant"):
        SideReserveConstraint(None, time_constant=0.0)
