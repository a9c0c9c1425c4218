"""The pick reserve: armed by the grapple command, the rated load's margin, hand-over, lapse."""

import numpy as np
import pytest

from models import build_reference_machine
from models.load_chart import rated_payload
from wbc.errors import ConfigurationError
from wbc.pick_reserve import (
    MIN_HOLD_SECONDS,
    PICK_SEEN_KG,
    RAMP_SECONDS,
    SETTLED_STD_KG,
    TIMEOUT_SECONDS,
    PickReserve,
)

MACHINE = build_reference_machine()
THRESHOLD = 1262.0


def _pose() -> np.ndarray:
    ch = MACHINE.chains
    q = MACHINE.coordinates.home()
    q[2] = ch["slew"].chain.stroke_from_angle(np.radians(45.0))
    q[3] = ch["lift"].chain.stroke_from_angle(np.radians(20.0))
    q[4] = ch["tilt"].chain.stroke_from_angle(np.radians(-40.0))
    q[5] = 0.9
    return q


def test_no_margin_until_the_grapple_closes_then_the_rated_loads_ramped_in():
    q, rot = _pose(), np.eye(3)
    res = PickReserve(MACHINE, THRESHOLD)
    assert not res.update(0.0, q, rot, 10.0, 5.0, None).any()
    res.close_grapple(1.0)
    assert not res.update(1.0, q, rot, 10.0, 5.0, None).any()  # the ramp starts at zero
    half = res.update(1.0 + RAMP_SECONDS / 2, q, rot, 10.0, 5.0, None)
    margin = res.update(1.0 + RAMP_SECONDS, q, rot, 10.0, 5.0, None)
    rated = rated_payload(MACHINE, q, THRESHOLD, rot)
    expected = np.maximum(-rated.sensitivity * (rated.mass - 10.0), 0.0)
    np.testing.assert_allclose(margin, expected)
    np.testing.assert_allclose(half, expected / 2)
    assert margin.max() > 1000.0 and (margin == 0).sum() >= 1  # only the unloaded wheels


def test_the_rating_keeps_the_other_margins_and_holds_from_the_grapple_command():
    """Rated with the controller's margins on top of the threshold, at the pick's pose."""
    c, s = np.cos(-0.15), np.sin(-0.15)  # a side slope on which the margins bind
    q, rot = _pose(), np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    plain, kept = PickReserve(MACHINE, THRESHOLD), PickReserve(MACHINE, THRESHOLD)
    for res in (plain, kept):
        res.close_grapple(0.0)
    plain.update(0.0, q, rot, 10.0, 5.0, None)
    kept.update(0.0, q, rot, 10.0, 5.0, None, margin=np.full(4, 2000.0))
    assert plain.rated == pytest.approx(rated_payload(MACHINE, q, THRESHOLD, rot).mass)
    assert kept.rated == pytest.approx(rated_payload(MACHINE, q, THRESHOLD + 2000.0, rot).mass)
    assert kept.rated < plain.rated
    inward = q.copy()
    inward[5] = 0.1  # the telescope pulled in: a higher rating there, but the pick's holds
    plain.update(1.0, inward, rot, 10.0, 5.0, None)
    assert plain.rated == pytest.approx(rated_payload(MACHINE, q, THRESHOLD, rot).mass)
    assert rated_payload(MACHINE, inward, THRESHOLD, rot).mass > plain.rated
    np.testing.assert_allclose(plain.sensitivity,
                               rated_payload(MACHINE, inward, THRESHOLD, rot).sensitivity)


def test_the_estimate_takes_over_once_the_pick_is_seen_and_settled():
    q, rot = _pose(), np.eye(3)
    res = PickReserve(MACHINE, THRESHOLD)
    res.close_grapple(0.0)
    assert res.update(0.5, q, rot, 10.0, 5.0, None).any()
    assert res.update(1.0, q, rot, 250.0, 300.0, "pick").any()  # just seen: unsettled
    t = 1.0 + MIN_HOLD_SECONDS / 2
    assert res.update(t, q, rot, 250.0, SETTLED_STD_KG / 2, None).any()  # too early
    t = 1.0 + MIN_HOLD_SECONDS
    assert not res.update(t, q, rot, 250.0, SETTLED_STD_KG / 2, None).any()
    assert not res.active


def test_a_pick_without_an_event_is_seen_by_the_estimate_and_handed_over():
    """A load taken up gradually raises no event; the estimate's rise says it was picked."""
    q, rot = _pose(), np.eye(3)
    res = PickReserve(MACHINE, THRESHOLD)
    res.close_grapple(0.0)
    res.update(0.0, q, rot, 10.0, 5.0, None)  # the estimate at the grapple command
    assert res.update(1.0, q, rot, 10.0 + PICK_SEEN_KG / 2, 5.0, None).any()  # not yet
    assert res.update(1.5, q, rot, 10.0 + 2 * PICK_SEEN_KG, 5.0, None).any()  # seen: held
    assert not res.update(1.5 + MIN_HOLD_SECONDS, q, rot, 10.0 + 2 * PICK_SEEN_KG, 5.0,
                          None).any()
    assert not res.active


def test_an_empty_grab_lapses():
    q, rot = _pose(), np.eye(3)
    res = PickReserve(MACHINE, THRESHOLD)
    res.close_grapple(2.0)
    assert res.update(2.0 + TIMEOUT_SECONDS - 0.1, q, rot, 10.0, 5.0, None).any()
    assert not res.update(2.0 + TIMEOUT_SECONDS + 0.1, q, rot, 10.0, 5.0, None).any()


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf")])
def test_bad_threshold_is_a_typed_error(bad):
    with pytest.raises(ConfigurationError, match="threshold_n"):
        PickReserve(MACHINE, bad)
