"""The pick reserve: armed by the grapple command, the rated load's margin, hand-over, lapse."""

import numpy as np
import pytest

from models import build_reference_machine
from models.load_chart import rated_payload
from wbc.errors import ConfigurationError
from wbc.pick_reserve import MIN_HOLD_SECONDS, SETTLED_STD_KG, TIMEOUT_SECONDS, PickReserve

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


def test_no_margin_until_the_grapple_closes_then_the_rated_loads():
    q, rot = _pose(), np.eye(3)
    res = PickReserve(MACHINE, THRESHOLD)
    assert not res.update(0.0, q, rot, 10.0, 5.0, None).any()
    res.close_grapple(1.0)
    margin = res.update(1.0, q, rot, 10.0, 5.0, None)
    rated = rated_payload(MACHINE, q, THRESHOLD, rot)
    expected = np.maximum(-rated.sensitivity * (rated.mass - 10.0), 0.0)
    np.testing.assert_allclose(margin, expected)
    assert margin.max() > 1000.0 and (margin == 0).sum() >= 1  # only the unloaded wheels


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
