"""The drive's speed governor: load fluctuation per unit speed and the speed-scale cap."""

import dataclasses

import numpy as np
import pytest

from testkit.force_models import AffineForceModel
from testkit.plant import make_state
from wbc import ConfigurationError, ControllerConfig, ForceConfig, MpcController
from wbc.constraints import SpeedScaleLimit
from wbc.force_models.feedback import DIAGONAL, ClosureFeedback
from wbc.force_models.fluctuation import SpeedGovernor

DT = 0.01
CONTACT = (True,) * 4


def _drive(gov, amplitude, speed, seconds, mean=(9000.0, 6000.0, 9000.0, 6000.0),
           scale=1.0, start=0.0, contact=CONTACT):
    """Loads ``mean + amplitude sin(2 pi 3 t)`` per wheel (3 Hz, far above the high-pass)."""
    n = int(round(seconds / DT))
    for i in range(n):
        t = start + i * DT
        f = np.asarray(mean) + np.asarray(amplitude) * np.sin(2 * np.pi * 3.0 * t)
        gov.update(f, contact, t, speed, scale)
    return start + n * DT


def test_fluctuation_per_unit_speed_is_the_rms_over_the_speed():
    gov = SpeedGovernor(z=2.0, high_pass=0.2, window=1.0)
    amp = np.array([800.0, 400.0, 0.0, 200.0])
    _drive(gov, amp, speed=0.5, seconds=12.0)
    # RMS of a sine is A / sqrt(2); the 0.2 s high-pass passes 3 Hz at 97 %.
    gain = 1.0 / np.sqrt(1.0 + 1.0 / (2 * np.pi * 3.0 * 0.2) ** 2)
    np.testing.assert_allclose(gov.per_speed, amp / np.sqrt(2) * gain / 0.5, rtol=0.04)
    # The slow load keeps the low-pass filter's ripple, 26 % of the amplitude at 3 Hz.
    assert np.all(np.abs(gov.mean - [9000.0, 6000.0, 9000.0, 6000.0]) <= 0.27 * amp + 1e-9)


def test_cap_leaves_z_fluctuations_of_headroom_at_the_commanded_speed():
    gov = SpeedGovernor(z=2.0)
    amp = np.array([0.0, 3000.0, 0.0, 0.0])  # only RL fluctuates: ~2.9 kN per 0.5 m/s
    _drive(gov, amp, speed=0.5, seconds=12.0)
    k = gov.per_speed[1]
    assert gov.cap(np.full(4, 500.0), 0.5, CONTACT) == 1.0  # ~5.5 kN of room: full speed
    # A heavier threshold leaves less room: the cap falls in proportion.
    low = gov.cap(np.full(4, 4000.0), 0.5, CONTACT)
    assert low == pytest.approx((gov.mean[1] - 4000.0) / (2.0 * k * 0.5), rel=1e-9)
    assert 0.0 < low < 1.0
    # No headroom at all: the drive is stopped; a lifted RL does not count.
    assert gov.cap(np.full(4, 7000.0), 0.5, CONTACT) == 0.0
    assert gov.cap(np.full(4, 7000.0), 0.5, (True, False, True, True)) == 1.0


def _cap_formula(gov, thresholds, speed, in_contact) -> float:
    """`SpeedGovernor.cap` as the module docstring writes it, on numpy arrays."""
    if gov.mean is None or not np.any(gov.per_speed > 0):
        return 1.0
    v_nom = speed / max(gov.scale_lag, 0.05)
    if not (np.isfinite(v_nom) and v_nom > 0):
        return 1.0
    need = gov.z * gov.per_speed * v_nom
    wheels = np.asarray(in_contact, bool) & (need > 0)
    if not np.any(wheels):
        return 1.0
    headroom = gov.mean - np.asarray(thresholds, float)
    return float(np.clip(np.min(headroom[wheels] / need[wheels]), 0.0, 1.0))


def test_cap_is_its_formula_to_the_bit():
    """Signed zeros, infinities and NaN included (the cap runs on Python floats)."""
    rng = np.random.default_rng(0)
    odd = [0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, -1.0, 5e3, 1e-300]
    gov = SpeedGovernor(2.0)
    for trial in range(20000):
        gov.mean = rng.choice(odd, 4) if trial % 2 else rng.normal(5e3, 3e3, 4)
        gov.per_speed = (rng.choice(odd, 4) if trial % 3 == 0
                         else np.abs(rng.normal(1e3, 1e3, 4)))
        gov.scale_lag = float(rng.choice([0.0, 0.5, 1.0, np.nan]))
        thresholds = gov.mean.copy() if trial % 7 == 0 else (
            rng.choice(odd, 4) if trial % 5 == 0 else rng.normal(3e3, 1e3, 4))
        contact = rng.random(4) < 0.8
        speed = float(rng.choice([0.3, 0.0, np.nan, 1e-3]))
        with np.errstate(all="ignore"):
            want = _cap_formula(gov, thresholds, speed, contact)
        got = gov.cap(thresholds, speed, contact)
        assert np.array(got).tobytes() == np.array(want).tobytes(), (trial, got, want)


def test_commanded_speed_is_inferred_through_the_drive_lag():
    gov = SpeedGovernor(z=2.0, drive_time_constant=0.5)
    t = _drive(gov, np.array([0.0, 1000.0, 0.0, 0.0]), speed=0.5, seconds=12.0)
    th = np.full(4, 3000.0)
    settled = gov.cap(th, 0.5, CONTACT)
    # The scale is commanded down to 0.5; the drive's speed follows with its lag. The
    # inferred commanded speed stays 0.5 m/s, so the cap does not run down with the speed.
    for i in range(300):
        tt = t + i * DT
        lag = 0.5 + 0.5 * np.exp(-(i + 1) * DT / 0.5)
        gov.update(gov.mean, CONTACT, tt, 0.5 * lag, 0.5)
        assert gov.cap(th, 0.5 * lag, CONTACT) == pytest.approx(settled, rel=0.03)


def test_standing_or_on_three_wheels_the_estimate_is_kept():
    gov = SpeedGovernor(z=2.0)
    assert gov.cap(np.full(4, 1000.0), 0.5, CONTACT) == 1.0  # nothing measured yet
    t = _drive(gov, np.full(4, 500.0), speed=0.5, seconds=5.0)
    k = gov.per_speed.copy()
    t = _drive(gov, np.full(4, 3000.0), speed=0.05, seconds=3.0, start=t)  # crawling
    np.testing.assert_array_equal(gov.per_speed, k)
    _drive(gov, np.full(4, 3000.0), speed=0.5, seconds=3.0, start=t,
           contact=(True, True, False, True))
    np.testing.assert_array_equal(gov.per_speed, k)
    assert gov.cap(np.full(4, 1000.0), 0.0, CONTACT) == 1.0  # standing: nothing to cap
    gov.reset()
    assert gov.mean is None and np.all(gov.per_speed == 0.0)


def test_speed_scale_limit_moves_towards_the_cap_at_its_rate():
    lim = SpeedScaleLimit(0.0, rate=0.5)
    lim.cap = 0.3
    assert lim.bounds(1.0, DT) == pytest.approx((0.995, 0.995))  # down at the rate limit
    assert lim.bounds(0.3, DT) == pytest.approx((0.295, 0.3))
    lim.cap = 1.0
    assert lim.bounds(0.3, DT) == pytest.approx((0.295, 0.305))


def test_mpc_derates_the_drive_on_a_rocking_load_split(machine):
    st0 = dataclasses.replace(make_state(machine), suspension_force=np.array([3e4, 3e4]))
    model = AffineForceModel(np.full(4, 9000.0), st0.q)
    ctrl = MpcController(machine, ControllerConfig(), force_model=model,
                         feedback=ClosureFeedback(model))
    assert ctrl.governor is not None and ctrl.governor.z == pytest.approx(2.33)
    # The measured split rocks at 3 Hz along the diagonal, 6 kN at the commanded 0.5 m/s and
    # in proportion to the speed; the drive follows the commanded scale with its 0.5 s lag.
    lag, scale = 1.0, 1.0
    for i in range(400):
        t = i * DT
        lag += DT / (0.5 + DT) * (scale - lag)
        st = dataclasses.replace(st0, time=t, base_twist=np.array([0.5 * lag, 0, 0, 0, 0, 0]))
        bias = 6000.0 * lag * np.sin(2 * np.pi * 3.0 * t)
        ctrl.feedback = ClosureFeedback(AffineForceModel(9000.0 + bias * DIAGONAL, st0.q))
        scale = ctrl.step(st).wheel_speed_scale
    gov = ctrl.governor
    headroom = np.min(gov.mean - ctrl.force_constraint.thresholds)
    need = np.max(gov.z * gov.per_speed * 0.5)  # at the commanded 0.5 m/s
    assert 0.5 < headroom / need < 0.9  # ~7.7 kN of room against ~9.7 kN at full speed
    assert ctrl.speed_limit.cap == pytest.approx(headroom / need, rel=0.05)
    # The scale follows the cap (which ripples with the slow load) at its rate limit.
    assert scale == pytest.approx(ctrl.speed_limit.cap, abs=0.05) and scale < 0.85
    # Off: no governor, no cap.
    off = MpcController(machine, ControllerConfig(force=ForceConfig(governor_z=0.0)),
                        force_model=model, feedback=ClosureFeedback(model))
    assert off.governor is None and off.speed_limit.cap == 1.0
    with pytest.raises(ConfigurationError, match="governor_z"):
        ForceConfig(governor_z=-1.0)
