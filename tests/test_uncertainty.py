"""Force uncertainty: the linear propagation against a Monte Carlo of the estimator itself."""

from dataclasses import replace

import numpy as np
import pytest

from estimators import NormalForceEstimator
from estimators.errors import EstimatorError
from estimators.uncertainty import (
    StateUncertainty,
    force_margin,
    normal_force_std,
    suspension_sensitivity,
)
from models import build_reference_machine
from testkit.estimator_states import random_state

MACHINE = build_reference_machine()


@pytest.fixture(scope="module")
def estimator():
    return NormalForceEstimator(MACHINE, fourth="cylinder-force")


def _state(seed: int):
    rng = np.random.default_rng(seed)
    s = random_state(MACHINE, rng, max_tilt=0.2, speed=0.3)
    return replace(s, suspension_force=rng.uniform(2e4, 6e4, 2))


@pytest.mark.parametrize("seed", [0, 1])
def test_linear_propagation_matches_monte_carlo(estimator, seed):
    s = _state(seed)
    rng = np.random.default_rng(100 + seed)
    unc = StateUncertainty(acceleration=np.r_[0.05, 0.05, 0.05, 0.02, 0.02, 0.02,
                                              np.full(13, 0.05)],
                           qd=np.full(13, 0.01), suspension_force=np.array([800.0, 800.0]))
    std = normal_force_std(estimator.linearize(s), unc, suspension_sensitivity(estimator, s))
    samples = []
    for _ in range(400):
        a = s.acceleration + unc.acceleration * rng.normal(size=19)
        samples.append(estimator.estimate(replace(
            s, base_acceleration=a[:6], qdd=a[6:], qd=s.qd + unc.qd * rng.normal(size=13),
            suspension_force=s.suspension_force
            + unc.suspension_force * rng.normal(size=2))).normal_forces)
    empirical = np.std(np.array(samples), axis=0)
    # 400 draws: the sample std is within ~7 % (2 sigma) of the true one; qd enters
    # quadratically (centripetal), so its first-order part is the whole of it only nearly.
    np.testing.assert_allclose(std, empirical, rtol=0.12)
    assert (std > 10.0).all()


def test_each_source_adds_and_exact_is_zero(estimator):
    s = _state(3)
    lin = estimator.linearize(s)
    assert np.all(normal_force_std(lin, StateUncertainty.exact()) == 0.0)
    base = StateUncertainty(np.full(19, 0.01), np.zeros(13), np.zeros(2))
    more = replace(base, payload_mass=30.0)
    d_m = np.array([5.0, -2.0, 3.0, -1.0])
    s0 = normal_force_std(lin, base, d_payload=d_m)
    s1 = normal_force_std(lin, more, d_payload=d_m)
    np.testing.assert_allclose(s1 ** 2 - s0 ** 2, (30.0 * d_m) ** 2, rtol=1e-9)


def test_suspension_sensitivity_is_exact_and_zero_without_forces(estimator):
    s = _state(4)
    d = suspension_sensitivity(estimator, s)
    step = np.array([2500.0, -1300.0])
    f0 = estimator.estimate(s).normal_forces
    f1 = estimator.estimate(replace(s, suspension_force=s.suspension_force + step)).normal_forces
    np.testing.assert_allclose(f1 - f0, d @ step, atol=1e-6 * np.abs(f0).max())
    assert np.all(suspension_sensitivity(estimator, replace(s, suspension_force=None)) == 0)


def test_margin_and_bad_inputs():
    np.testing.assert_allclose(force_margin(np.array([100.0, 0, 0, 0]), 0.99)[0], 232.6,
                               atol=0.1)
    with pytest.raises(EstimatorError, match="confidence"):
        force_margin(np.ones(4), 1.0)
    with pytest.raises(EstimatorError, match=">= 0"):
        StateUncertainty(-np.ones(19), np.zeros(13), np.zeros(2))
    with pytest.raises(EstimatorError, match="payload_mass"):
        StateUncertainty(np.ones(19), np.zeros(13), np.zeros(2), payload_mass=float("nan"))
    with pytest.raises(EstimatorError, match="StateUncertainty"):
        normal_force_std(None, "big")


def test_suspension_sensitivity_from_one_packed_row_equals_the_estimates(estimator,
                                                                          monkeypatch):
    """The stepped forces of one packed kernel row (`estimators.suspension_response`) give the
    sensitivity of three separate estimates to the bit, for one estimator and for the
    payload estimator (its payload a kernel input); its df/dm too."""
    from estimators import uncertainty
    from estimators.payload import PayloadEstimator

    payload = PayloadEstimator(estimator.machine, fourth="cylinder-force")
    payload.payload_mass = 205.0
    states = [_state(k) for k in range(4)]
    fast = [[suspension_sensitivity(m, s) for s in states] for m in (estimator, payload)]
    d_m = payload.payload_sensitivity(states[-1])  # from the rows `stepped` kept
    assert np.abs(fast[0][0]).max() > 0.01  # the cylinder-force row reads them [N/N]
    monkeypatch.setattr(uncertainty, "stepped_forces", lambda *a: None)
    monkeypatch.setattr(PayloadEstimator, "stepped_suspension_forces", lambda *a: None)
    for m, got in zip((estimator, payload), fast):
        for s, d in zip(states, got):
            assert np.array_equal(d, suspension_sensitivity(m, s))
    fresh = PayloadEstimator(estimator.machine, fourth="cylinder-force")
    fresh.payload_mass = 205.0
    assert np.array_equal(d_m, fresh.payload_sensitivity(states[-1]))
