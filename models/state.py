"""Typed, immutable machine state in the paper's terms, and per-wheel contact quantities.

Every per-wheel array is ordered FL, RL, FR, RR (paper eq. 1, `WHEEL_ORDER`). Twists are
[v; w] (linear first, as in the paper), expressed in the floating-base frame fb.

Both types are frozen and validated once, at construction: every array is converted to a
read-only float (or bool) array of the documented shape with finite entries, and the base
rotation must be a proper rotation. Change a field with `dataclasses.replace`, which
validates the new value.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from models.coordinates import N_INDEPENDENT
from models.description import WHEEL_ORDER
from models.errors import StateError

__all__ = ["MachineState", "WheelContacts", "WHEEL_ORDER", "N_SERVO_AXES",
           "ROTATION_TOLERANCE", "contact_flags", "frozen_array", "shaped_array"]

N_SERVO_AXES = 9  # the servo-driven axes: 2 suspension strokes, 7 crane coordinates
ROTATION_TOLERANCE = 1e-6  # max |R R^T - I| entry of a valid rotation matrix
_F64 = np.dtype(float)


def _all_finite(flat: np.ndarray) -> bool:
    """Whether every entry of the 1-D float array is finite."""
    return bool(np.isfinite(flat).all())


def shaped_array(name: str, value, shape: tuple[int, ...], dtype=float) -> np.ndarray:
    """``value`` as a new array of ``shape``; `StateError` naming the field otherwise."""
    try:
        if np.iscomplexobj(value):
            raise TypeError("complex values")
        a = np.array(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise StateError(f"'{name}' must be real numbers with shape {shape}: {exc}") from None
    if a.shape != shape:
        raise StateError(f"'{name}' must have shape {shape}, got {a.shape}")
    return a


def frozen_array(name: str, value, shape: tuple[int, ...], dtype=float) -> np.ndarray:
    """``value`` as a read-only array of ``shape`` with finite entries.

    Raises:
        StateError: Not numeric, wrong shape, or a NaN/inf entry (the message names the field).
    """
    if dtype is float and type(value) is np.ndarray and value.dtype == _F64 \
            and value.shape == shape:
        # The common case, a float array of the right shape: a copy and one finiteness test.
        a = value.copy()
        if not _all_finite(a.reshape(-1)):
            raise StateError(f"'{name}' has non-finite entries (NaN or inf): {a}")
        a.flags.writeable = False
        return a
    a = shaped_array(name, value, shape, dtype)
    if dtype is float and not np.all(np.isfinite(a)):
        raise StateError(f"'{name}' has non-finite entries (NaN or inf): {a}")
    a.flags.writeable = False
    return a


def contact_flags(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a read-only bool array of ``shape``; only booleans or 0/1 are accepted.

    Raises:
        StateError: Wrong shape, or an entry that is not a boolean, 0 or 1 (a string, 0.5, 2).
    """
    if type(value) is np.ndarray and value.dtype == bool and value.shape == shape:
        flags = value.copy()
        flags.flags.writeable = False
        return flags
    try:
        flags = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise StateError(f"'{name}' must hold booleans (or 0/1) with shape {shape}: "
                         f"{exc}") from None
    if flags.shape != shape:
        raise StateError(f"'{name}' must have shape {shape}, got {flags.shape}")
    if flags.dtype != bool and (flags.dtype.kind not in "iuf"
                                or not np.all((flags == 0) | (flags == 1))):
        raise StateError(f"'{name}' must hold booleans (or 0/1), got {flags}")
    flags = flags.astype(bool)
    flags.flags.writeable = False
    return flags


def check_rotation(name: str, r: np.ndarray) -> None:
    """Raise `StateError` unless ``r`` (3, 3) is a proper rotation (orthonormal, det +1)."""
    (a, b, c), (d, e, f), (g, h, i) = r.tolist()  # nine floats: cheaper than array calls
    if max(abs(a), abs(b), abs(c), abs(d), abs(e), abs(f), abs(g), abs(h), abs(i)) \
            <= 1.0 + ROTATION_TOLERANCE:
        err = max(abs(a * a + b * b + c * c - 1.0), abs(d * d + e * e + f * f - 1.0),
                  abs(g * g + h * h + i * i - 1.0), abs(a * d + b * e + c * f),
                  abs(a * g + b * h + c * i), abs(d * g + e * h + f * i))
        det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
        if err <= ROTATION_TOLERANCE and det > 0:
            return
    if np.abs(r).max() > 1.0 + ROTATION_TOLERANCE:  # also keeps R R^T from overflowing
        raise StateError(f"'{name}' is not a rotation matrix (an entry of magnitude "
                         f"{np.abs(r).max():.3g} > 1; valid: orthonormal with det +1): {r}")
    err = np.abs(r @ r.T - np.eye(3)).max()
    if err > ROTATION_TOLERANCE or np.linalg.det(r) < 0:
        raise StateError(f"'{name}' is not a rotation matrix (|R R^T - I| = {err:.3g}, "
                         f"det {np.linalg.det(r):.3g}; valid: orthonormal with det +1): {r}")


def _set(obj, name: str, value) -> None:
    object.__setattr__(obj, name, value)


def _freeze_fields(obj, fields) -> None:
    """Set each ``(name, shape)`` field of ``obj`` to its read-only, finite float array.

    Float arrays of the right shape (the common case) are copied and tested for finiteness
    together (one sum of squares); anything else goes through `frozen_array` one by one.
    """
    fast = []
    for name, shape in fields:
        v = getattr(obj, name)
        if type(v) is np.ndarray and v.dtype == _F64 and v.shape == shape:
            a = v.copy()
            a.flags.writeable = False
            fast.append(a.reshape(-1))
        else:
            a = frozen_array(name, v, shape)
        _set(obj, name, a)
    if fast:
        flat = np.concatenate(fast)
        if not _all_finite(flat):  # a NaN or inf somewhere: find it
            for name, shape in fields:
                frozen_array(name, getattr(obj, name), shape)


def _owned(arrays, fields) -> bool:
    """Whether each array is a float array of its field's shape, all entries finite."""
    for a, (_, shape) in zip(arrays, fields):
        if not (type(a) is np.ndarray and a.dtype == _F64 and a.shape == shape):
            return False
    return _all_finite(np.concatenate([a.reshape(-1) for a in arrays]))


_CONTACT_FIELDS = (("force_in_fb", (4, 3)), ("point_in_fb", (4, 3)), ("normal_in_fb", (4, 3)))
_STATE_FIELDS = (("base_position", (3,)), ("base_rotation", (3, 3)), ("base_twist", (6,)),
                 ("base_acceleration", (6,)), ("q", (N_INDEPENDENT,)),
                 ("qd", (N_INDEPENDENT,)), ("qdd", (N_INDEPENDENT,)))


@dataclass(frozen=True, eq=False)
class WheelContacts:
    """Per-wheel contact quantities, measured (simulator, sensors) or estimated.

    Attributes:
        in_contact: Contact flags, shape (4,), order FL, RL, FR, RR.
        force_in_fb: Total ground force on each wheel in fb axes [N], shape (4, 3).
        point_in_fb: Force-weighted contact point of each wheel in fb [m], shape (4, 3);
            the wheel's lowest point when out of contact.
        normal_in_fb: Terrain normal at each contact in fb axes, shape (4, 3).
    """

    in_contact: np.ndarray
    force_in_fb: np.ndarray
    point_in_fb: np.ndarray
    normal_in_fb: np.ndarray

    def __post_init__(self):
        _set(self, "in_contact", contact_flags("in_contact", self.in_contact, (4,)))
        _freeze_fields(self, _CONTACT_FIELDS)

    @classmethod
    def from_owned(cls, in_contact, force_in_fb, point_in_fb, normal_in_fb) -> WheelContacts:
        """The constructor for arrays made for this object alone: checked, not copied.

        For the simulator's ground truth at every control tick: a bool array (4,) and float
        arrays (4, 3) with finite entries are made read-only in place and kept; anything
        else goes through the constructor (which copies, converts or names what is wrong).
        """
        arrays = (force_in_fb, point_in_fb, normal_in_fb)
        if not (type(in_contact) is np.ndarray and in_contact.dtype == bool
                and in_contact.shape == (4,) and _owned(arrays, _CONTACT_FIELDS)):
            return cls(in_contact, force_in_fb, point_in_fb, normal_in_fb)
        for a in (in_contact,) + arrays:
            a.flags.writeable = False
        new = object.__new__(cls)
        new.__dict__.update(in_contact=in_contact, force_in_fb=force_in_fb,
                            point_in_fb=point_in_fb, normal_in_fb=normal_in_fb)
        return new

    @property
    def normal_force(self) -> np.ndarray:
        """Force along the terrain normal [N], shape (4,)."""
        return np.einsum("ij,ij->i", self.force_in_fb, self.normal_in_fb)

    @property
    def fz_in_fb(self) -> np.ndarray:
        """Force along the fb z axis [N], shape (4,): the paper's f_z (eqs. 22-24)."""
        return self.force_in_fb[:, 2].copy()

    @property
    def friction_in_fb(self) -> np.ndarray:
        """The x-y (fb) part of each wheel force [N], shape (4, 3): the paper's F_a."""
        f = self.force_in_fb.copy()
        f[:, 2] = 0.0
        return f


@dataclass(frozen=True, eq=False)
class MachineState:
    """State of the machine in the paper's independent coordinates.

    Attributes:
        base_position: fb origin in the world [m], shape (3,).
        base_rotation: Rotation world <- fb, shape (3, 3), proper (det +1).
        base_twist: Body twist [v; w] of fb in fb [m/s, rad/s], shape (6,).
        base_acceleration: Time derivative of `base_twist` [m/s^2, rad/s^2], shape (6,)
            (the body-frame spatial acceleration, Pinocchio's free-flyer ``a``).
        q: Independent coordinates, shape (13,), order in `models.coordinates`.
        qd: Their velocities, shape (13,).
        qdd: Their accelerations, shape (13,).
        time: Time of the instant [s], finite.
        contacts: Measured wheel contacts (friction and flags), if known.
        suspension_force: Measured suspension cylinder forces [N], shape (2,), if known
            (order L, R; positive pushes the rod out).
        servo_setpoint: The nine axis servos' own setpoints at this instant [m, rad],
            shape (9,) (order of `q[:9]`), if the servos report them.
    """

    base_position: np.ndarray
    base_rotation: np.ndarray
    base_twist: np.ndarray
    base_acceleration: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    time: float = 0.0
    contacts: WheelContacts | None = None
    suspension_force: np.ndarray | None = None
    servo_setpoint: np.ndarray | None = None

    def __post_init__(self):
        self._check(_STATE_NAMES)

    def _check(self, names) -> None:
        """Validate and freeze the fields ``names`` (`StateError` names the bad one)."""
        arrays = [(n, shape) for n, shape in _STATE_FIELDS if n in names]
        if arrays:
            _freeze_fields(self, arrays)
        if "base_rotation" in names:
            check_rotation("base_rotation", self.base_rotation)
        if "time" in names:
            try:
                t = float(self.time)
            except (TypeError, ValueError):
                raise StateError(f"'time' must be a finite number [s], got "
                                 f"{self.time!r}") from None
            if not np.isfinite(t):
                raise StateError(f"'time' must be a finite number [s], got {t}")
            _set(self, "time", t)
        if "contacts" in names and self.contacts is not None and not isinstance(
                self.contacts, WheelContacts):
            raise StateError(f"'contacts' must be a WheelContacts or None, got "
                             f"{type(self.contacts).__name__}")
        if "suspension_force" in names and self.suspension_force is not None:
            _set(self, "suspension_force",
                 frozen_array("suspension_force", self.suspension_force, (2,)))
        if "servo_setpoint" in names and self.servo_setpoint is not None:
            _set(self, "servo_setpoint",
                 frozen_array("servo_setpoint", self.servo_setpoint, (N_SERVO_AXES,)))

    @classmethod
    def _trusted(cls, base_position, base_rotation, base_twist, base_acceleration, q, qd,
                 qdd, time: float, contacts: WheelContacts | None = None,
                 suspension_force=None, servo_setpoint=None) -> MachineState:
        """A state of fields already valid, without the checks and copies of construction.

        Private: for the many states per tick a controller derives from a validated one
        (the MPC's nominal states), from float arrays of the documented shapes it built
        itself. The arrays are frozen in place and shared; public paths keep validating.
        """
        values = (base_position, base_rotation, base_twist, base_acceleration, q, qd, qdd,
                  float(time), contacts, suspension_force, servo_setpoint)
        for value in values:
            if type(value) is np.ndarray:
                value.setflags(write=False)
        new = object.__new__(cls)
        new.__dict__.update(zip(_STATE_NAMES, values))  # what a frozen dataclass holds
        return new

    @classmethod
    def from_owned(cls, base_position, base_rotation, base_twist, base_acceleration, q, qd,
                   qdd, time: float, contacts: WheelContacts | None = None,
                   suspension_force=None, servo_setpoint=None) -> MachineState:
        """The constructor for arrays made for this state alone: checked, not copied.

        For the simulator's measured state at every control tick: float arrays of the
        documented shapes with finite entries, a proper rotation and a finite time are made
        read-only in place and kept (the constructor's checks, one finiteness test for all,
        without its copies); anything else goes through the constructor, which converts or
        names what is wrong. The caller must not write the arrays afterwards.
        """
        arrays = (base_position, base_rotation, base_twist, base_acceleration, q, qd, qdd)
        fields = _STATE_FIELDS
        if suspension_force is not None:
            arrays, fields = arrays + (suspension_force,), fields + (("", (2,)),)
        if servo_setpoint is not None:
            arrays, fields = arrays + (servo_setpoint,), fields + (("", (N_SERVO_AXES,)),)
        if not (_owned(arrays, fields) and type(time) is float and np.isfinite(time)
                and (contacts is None or isinstance(contacts, WheelContacts))):
            return cls(base_position, base_rotation, base_twist, base_acceleration, q, qd,
                       qdd, time, contacts, suspension_force, servo_setpoint)
        check_rotation("base_rotation", base_rotation)
        return cls._trusted(base_position, base_rotation, base_twist, base_acceleration, q,
                            qd, qdd, time, contacts, suspension_force, servo_setpoint)

    def replace(self, **changes) -> MachineState:
        """A copy with ``changes``, as `dataclasses.replace`, checking only what changed.

        The other fields were checked and frozen when this state was built and are shared.

        Raises:
            StateError: A changed field is invalid, or not a field of `MachineState`.
        """
        unknown = sorted(set(changes) - set(_STATE_NAMES))
        if unknown:
            raise StateError(f"MachineState has no field {unknown[0]!r}; fields: "
                             f"{', '.join(_STATE_NAMES)}")
        new = object.__new__(MachineState)
        for name in _STATE_NAMES:
            _set(new, name, changes[name] if name in changes else getattr(self, name))
        new._check(changes)
        return new

    @property
    def acceleration(self) -> np.ndarray:
        """The generalised accelerations ``a = [base_acceleration (6), qdd (13)]``, (19,)."""
        return np.concatenate([self.base_acceleration, self.qdd])


_STATE_NAMES = tuple(f.name for f in fields(MachineState))  # checked by `MachineState._check`
