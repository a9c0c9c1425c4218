"""`MachineState.from_owned` and `WheelContacts.from_owned`: the constructors' checks and
values without their copies; anything unusual goes through the constructors."""

import dataclasses

import numpy as np
import pytest

from models import StateError
from models.state import MachineState, WheelContacts


def _rotation(angle=0.3):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _contact_args(rng):
    return (rng.random(4) > 0.3, rng.normal(size=(4, 3)), rng.normal(size=(4, 3)),
            rng.normal(size=(4, 3)))


def _state_args(rng, contacts=None):
    return dict(base_position=rng.normal(size=3), base_rotation=_rotation(),
                base_twist=rng.normal(size=6), base_acceleration=rng.normal(size=6),
                q=rng.normal(size=13), qd=rng.normal(size=13), qdd=rng.normal(size=13),
                time=1.25, contacts=contacts, suspension_force=rng.normal(size=2),
                servo_setpoint=rng.normal(size=9))


def _same(a, b, cls):
    for f in dataclasses.fields(cls):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert type(x) is type(y), f.name
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), f.name
            assert not x.flags.writeable, f.name
        else:
            assert x is y or x == y, f.name


def test_owned_state_and_contacts_equal_the_constructed_ones_and_keep_the_arrays():
    rng = np.random.default_rng(0)
    args = _contact_args(rng)
    contacts = WheelContacts.from_owned(*args)
    _same(contacts, WheelContacts(*args), WheelContacts)
    assert contacts.force_in_fb is args[1]  # kept, not copied
    kwargs = _state_args(rng, contacts)
    state = MachineState.from_owned(**kwargs)
    _same(state, MachineState(**kwargs), MachineState)
    assert state.q is kwargs["q"] and state.contacts is contacts
    bare = dict(kwargs, contacts=None, suspension_force=None, servo_setpoint=None)
    _same(MachineState.from_owned(**bare), MachineState(**bare), MachineState)


@pytest.mark.parametrize("change", [
    dict(q=np.full(13, np.nan)), dict(base_rotation=2.0 * np.eye(3)), dict(time=float("inf")),
    dict(suspension_force=np.array([1.0, np.inf])), dict(qd=np.zeros(12)),
    dict(contacts="four wheels")])
def test_owned_state_refuses_what_the_constructor_refuses(change):
    kwargs = dict(_state_args(np.random.default_rng(1)), **change)
    with pytest.raises(StateError):
        MachineState.from_owned(**kwargs)


def test_owned_inputs_of_other_types_are_converted_as_by_the_constructor():
    rng = np.random.default_rng(2)
    kwargs = dict(_state_args(rng), q=list(range(13)), time=np.float64(2.0))
    _same(MachineState.from_owned(**kwargs), MachineState(**kwargs), MachineState)
    flags, force, point, normal = _contact_args(rng)
    _same(WheelContacts.from_owned(flags.astype(int), force, point, normal),
          WheelContacts(flags.astype(int), force, point, normal), WheelContacts)
    with pytest.raises(StateError):
        WheelContacts.from_owned(flags, force, point, np.full((4, 3), np.nan))
