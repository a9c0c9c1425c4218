"""The observer's per-tick `MachineState` and `WheelContacts`, built without copies.

The validating constructors copy and check every array (~20 us a state, ~15 us a contact
set); the observer builds three states and two contact sets per tick from numbers it has
just computed and holds no other reference to. `StateBuffer` holds a state's float fields in
one fresh array (one finiteness test for them all; the fields are read-only views of it);
`with_fields` and `wheel_contacts` freeze fresh arrays in place. When a test fails they call
the validating constructor with the same arguments, which raises its usual error. The
results hold the same values, field for field, as the constructors would make.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from models.coordinates import N_INDEPENDENT
from models.state import MachineState, WheelContacts, check_rotation

__all__ = ["STATE_SIZE", "StateBuffer", "trusted_state", "wheel_contacts", "with_fields"]

# The float fields' places in a `StateBuffer`: the base's position (always zero: the
# observer does not know it), rotation (row-major), twist, acceleration; then q, qd, qdd as
# the rows of a (3, 13) block; the suspension forces last.
_POSITION, _ROTATION, _TWIST, _ACCELERATION = slice(0, 3), slice(3, 12), slice(12, 18), \
    slice(18, 24)
_BASE = slice(3, 24)
_JOINTS = slice(24, 24 + 3 * N_INDEPENDENT)
_SUSPENSION = slice(_JOINTS.stop, _JOINTS.stop + 2)
STATE_SIZE = _SUSPENSION.stop
_STATE_NAMES = tuple(f.name for f in dataclasses.fields(MachineState))


class StateBuffer:
    """One tick's state fields in one array, filled in place, then frozen into a state.

    Args:
        values: The fields in this layout (`STATE_SIZE`,), a fresh array taken over; None:
            zeros.

    Attributes:
        joints: The (3, 13) block of q, qd and qdd (rows), to be written.
    """

    def __init__(self, values: np.ndarray | None = None):
        self._buf = np.zeros(STATE_SIZE) if values is None else values
        self.joints = self._buf[_JOINTS].reshape(3, N_INDEPENDENT)

    def set_base(self, fields: np.ndarray) -> None:
        """The base's rotation (9, row-major), twist (6) and acceleration (6), (21,)."""
        self._buf[_BASE] = fields

    def set_suspension(self, forces: np.ndarray) -> None:
        """The two suspension cylinders' forces [N], the first two of ``forces``."""
        self._buf[_SUSPENSION] = forces[:2]

    def state(self, time: float, servo_setpoint: np.ndarray,
              rotation_valid: bool = False) -> MachineState:
        """The `MachineState` of the buffer (taken over: not written afterwards).

        ``servo_setpoint``: a read-only checked array (`SensorReadings`'), shared; a writable
        one, or a non-finite field, takes the validating constructor. ``rotation_valid``:
        the rotation passed `check_rotation`'s test (`BaseFilter.rotation_valid`); False:
        tested here.
        """
        buf = self._buf
        buf.flags.writeable = False  # views made from now on are read-only too
        rotation = buf[_ROTATION].reshape(3, 3)
        joints = buf[_JOINTS].reshape(3, N_INDEPENDENT)
        fields = (buf[_POSITION], rotation, buf[_TWIST], buf[_ACCELERATION], joints[0],
                  joints[1], joints[2])
        if servo_setpoint.flags.writeable or not np.isfinite(buf).all():
            return MachineState(*fields, float(time), None, buf[_SUSPENSION],
                                servo_setpoint)
        if not rotation_valid:
            check_rotation("base_rotation", rotation)
        # `MachineState._trusted` less its freezing: every view of `buf` is read-only
        new = object.__new__(MachineState)
        new.__dict__.update(zip(_STATE_NAMES, (*fields, float(time), None, buf[_SUSPENSION],
                                               servo_setpoint)))
        return new


def trusted_state(buf: np.ndarray, time: float, servo_setpoint: np.ndarray,
                  contacts: WheelContacts) -> MachineState:
    """`StateBuffer.state` of a fresh buffer known valid, with ``contacts``.

    The buffer (`STATE_SIZE`,) is taken over: finite, its rotation checked
    (`BaseFilter.rotation_valid`), ``servo_setpoint`` read-only (the caller's tests).
    """
    buf.flags.writeable = False
    joints = buf[_JOINTS].reshape(3, N_INDEPENDENT)
    new = object.__new__(MachineState)
    new.__dict__.update(zip(_STATE_NAMES, (
        buf[_POSITION], buf[_ROTATION].reshape(3, 3), buf[_TWIST], buf[_ACCELERATION],
        joints[0], joints[1], joints[2], float(time), contacts, buf[_SUSPENSION],
        servo_setpoint)))
    return new


def with_fields(state: MachineState, **changes) -> MachineState:
    """``state.replace(**changes)`` for values known valid.

    Each a `WheelContacts`, or a fresh finite float array of the field's shape (frozen here);
    not the time. The other fields are shared, frozen since ``state`` was made.
    """
    for value in changes.values():
        if type(value) is np.ndarray:
            value.setflags(write=False)
    new = object.__new__(MachineState)
    new.__dict__.update(state.__dict__)
    new.__dict__.update(changes)
    return new


def wheel_contacts(in_contact: np.ndarray, force: np.ndarray, point: np.ndarray,
                   normal: np.ndarray, finite: bool) -> WheelContacts:
    """`WheelContacts` of fresh arrays: taken over (frozen, not copied).

    ``in_contact`` bool (4,), ``force``, ``point`` and ``normal`` float (4, 3); ``finite``:
    whether the last three are finite (the caller's test).
    """
    if not finite:
        return WheelContacts(in_contact, force, point, normal)
    for a in (in_contact, force, point, normal):
        a.flags.writeable = False
    c = object.__new__(WheelContacts)
    c.__dict__.update(in_contact=in_contact, force_in_fb=force, point_in_fb=point,
                      normal_in_fb=normal)
    return c
