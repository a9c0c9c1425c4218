"""The observer's per-tick `MachineState` and `WheelContacts`, built without copies.

The validating constructors copy and check every array (~20 us a state, ~15 us a contact
set); the observer builds two of each per tick from arrays it has just made and holds no
other reference to. These helpers freeze such arrays in place after one finiteness test of
them all (and the rotation's check); when the test fails they call the validating
constructor with the same arguments, which raises its usual error. The results are the
same objects, field for field, as the constructors would make.
"""

from __future__ import annotations

import numpy as np

from models.state import MachineState, WheelContacts, check_rotation

__all__ = ["machine_state", "wheel_contacts", "with_fields"]


def _freeze(*arrays: np.ndarray) -> None:
    for a in arrays:
        a.setflags(write=False)


def machine_state(base_position: np.ndarray, base_rotation: np.ndarray,
                  base_twist: np.ndarray, base_acceleration: np.ndarray, q: np.ndarray,
                  qd: np.ndarray, qdd: np.ndarray, time: float,
                  suspension_force: np.ndarray, servo_setpoint: np.ndarray) -> MachineState:
    """`MachineState` of fresh float arrays of the right shapes (taken over, not copied).

    ``servo_setpoint``: a read-only checked array (`SensorReadings`'), shared; a writable
    one takes the validating constructor.
    """
    floats = (base_position, base_rotation, base_twist, base_acceleration, q, qd, qdd,
              suspension_force)
    if servo_setpoint.flags.writeable or not np.isfinite(
            np.concatenate([a.reshape(-1) for a in floats])).all():
        return MachineState(base_position, base_rotation, base_twist, base_acceleration, q,
                            qd, qdd, float(time), None, suspension_force, servo_setpoint)
    check_rotation("base_rotation", base_rotation)
    return MachineState._trusted(base_position, base_rotation, base_twist, base_acceleration,
                                 q, qd, qdd, time, None, suspension_force, servo_setpoint)


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
                   normal: np.ndarray) -> WheelContacts:
    """`WheelContacts` of fresh arrays: bool (4,), float (4, 3) each (taken over)."""
    if not np.isfinite(np.concatenate([force.reshape(-1), point.reshape(-1),
                                       normal.reshape(-1)])).all():
        return WheelContacts(in_contact, force, point, normal)
    _freeze(in_contact, force, point, normal)
    c = object.__new__(WheelContacts)
    c.__dict__.update(in_contact=in_contact, force_in_fb=force, point_in_fb=point,
                      normal_in_fb=normal)
    return c
