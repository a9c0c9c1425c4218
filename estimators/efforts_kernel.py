r"""The actuator efforts and link accelerations of `estimators.efforts`, compiled to C.

The same rigid-body dynamics as the estimator's kernels (`estimators.tree`, the recursion of
eqs. 9-11 run with `estimators._symbolic.CasadiOps`), closed through the chains (eqs. 5-7),
for one flat input row (`INPUTS`: the base's rotation (row-major world <- fb), twist and
acceleration; q and qd (13 each); the wheels' accelerations (4)), with the nine servo axes'
accelerations ``u`` as the free variable. Two kernels:

* ``efforts``: the nine efforts ``e = E u + e_0`` (``e_i = J_i^T tau``, the tree's joint
  forces through the chain's Jacobian entries ``k1, k2, 1``) at the payload estimator's two
  anchor masses (`estimators.payload.anchor_machines`; the efforts are affine in the payload
  mass). ``E`` is CasADi's exact Jacobian ``de/du``, ``e_0`` the efforts at ``u = 0``. Out:
  ``E_a`` (81, row-major), ``e_0a`` (9), ``E_b``, ``e_0b``, checksum.
* ``points_<k>``: the specific force ``R_b^T (a_p - g)`` at k points fixed to the
  description's bodies (the link accelerometers), ``f = A u + b``: out ``A`` (3k x 9,
  row-major), ``b`` (3k), checksum. The tree's body accelerations carry gravity as a base
  offset (`estimators.spatial`), so the linear part at a body is already ``R^T (a - g)`` of
  its origin; the point adds ``w_dot x p + w x (w x p)``.

Like Pinocchio's model of `estimators.efforts` (its reference, `tests/test_efforts_kernel.py`),
the joints' armature and damping (the simulator's) are not in these efforts. Each kernel is
compiled once per machine description (and set of points) with the system compiler, cached
on disk (`models.cbuild`); without a compiler `kernels_for` returns None and the caller keeps
Pinocchio.
"""

from __future__ import annotations

import ctypes
import logging
import math
import subprocess
import threading

import casadi as ca
import numpy as np

from estimators._kernel_calls import Compiled
from estimators._symbolic import CasadiOps, _packed, checked_row, kernel_source, row_major
from estimators.errors import EstimatorError
from estimators.payload import ANCHOR_MASSES, anchor_machines
from estimators.tree import TreeModel
from models.cbuild import compile_shared
from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.state import N_SERVO_AXES

__all__ = ["INPUTS", "EffortKernels", "kernels_for"]

_log = logging.getLogger(__name__)
_join = b"".join

N_REST = N_INDEPENDENT - N_SERVO_AXES  # the wheels' accelerations, an input
INPUTS = _packed([("rotation", 9), ("twist", 6), ("acceleration", 6), ("q", N_INDEPENDENT),
                  ("qd", N_INDEPENDENT), ("qdd_rest", N_REST)])
_EFFORT_SIZE = 2 * (N_SERVO_AXES * N_SERVO_AXES + N_SERVO_AXES)


def _symbols():
    z = ca.SX.sym("z", INPUTS["size"])
    u = ca.SX.sym("u", N_SERVO_AXES)
    rot = ca.reshape(z[INPUTS["rotation"]], 3, 3).T  # row-major input
    qdd = ca.vertcat(u, z[INPUTS["qdd_rest"]])
    return z, u, (rot, z[INPUTS["twist"]], z[INPUTS["acceleration"]], z[INPUTS["q"]],
                  z[INPUTS["qd"]], qdd)


def efforts_function(machine: Machine) -> ca.Function:
    """The ``efforts`` kernel of ``machine`` (module docstring)."""
    z, u, args = _symbols()
    parts = []
    for variant in anchor_machines(machine):
        tree = TreeModel(variant)
        dyn = tree.dynamics(CasadiOps, *args)
        tau = dyn.joint_force
        e = [None] * N_SERVO_AXES
        for i, b in tree.direct:
            if i < N_SERVO_AXES:
                e[i] = tau[b]
        for k, c in enumerate(tree.chains):
            if c.coordinate < N_SERVO_AXES:
                e[c.coordinate] = dyn.k1[k] * tau[c.driven] + dyn.k2[k] * tau[c.barrel] \
                    + tau[c.piston]
        e = ca.vertcat(*e)
        jac = ca.jacobian(e, u)
        parts += [row_major(jac), ca.substitute(e, u, ca.DM.zeros(N_SERVO_AXES))]
    return ca.Function("efforts", [z], [checked_row(*parts)])


def _host(tree: TreeModel, body: str) -> tuple[int, np.ndarray]:
    """(tree index, 4x4 pose of ``body`` in it): a fixed body's moving host (`TreeModel.hosts`)."""
    if body in tree.index:
        return tree.index[body], np.eye(4)
    if body not in tree.hosts:
        raise EstimatorError(f"no body {body!r} in the machine description")
    host, pose = tree.hosts[body]
    return tree.index[host], pose


def points_function(machine: Machine, mounts) -> ca.Function:
    """The ``points_<k>`` kernel of ``machine`` for ``mounts`` ((body, point) pairs)."""
    z, u, args = _symbols()
    tree = TreeModel(machine)
    dyn = tree.dynamics(CasadiOps, *args)
    rows = []
    for body, point in mounts:
        i, t = _host(tree, body)
        p_host = t[:3, :3] @ np.asarray(point, float) + t[:3, 3]
        p = ca.DM(p_host)
        v, w = dyn.twist[i][:3], dyn.twist[i][3:]
        a, dw = dyn.acceleration[i][:3], dyn.acceleration[i][3:]
        f_host = a + ca.cross(dw, p) + ca.cross(w, v + ca.cross(w, p))
        rows.append(ca.DM(t[:3, :3].T) @ f_host)  # in the mount body's axes
    f = ca.vertcat(*rows)
    jac = ca.jacobian(f, u)
    return ca.Function(f"points_{len(mounts)}", [z],
                       [checked_row(row_major(jac), ca.substitute(f, u,
                                                              ca.DM.zeros(N_SERVO_AXES)))])


class EffortKernels:
    """The compiled ``efforts`` kernel of one machine, and its ``points`` kernels.

    Made by `kernels_for` (shared by every caller of the same description). ``call(row)``
    style: fill `row` (`INPUTS`) with `fill`, then `efforts` or `points`.
    """

    def __init__(self, machine: Machine):
        self.machine = machine
        self._efforts = self._compile(efforts_function(machine), "-O2")
        self._points: dict[tuple, Compiled] = {}
        self._last_points: tuple = (None, None)  # (mounts object, its kernel)
        self._lock = threading.Lock()

    @staticmethod
    def _compile(fun: ca.Function, opt: str) -> Compiled:
        lib = compile_shared(kernel_source(fun), fun.name(), opt)
        return Compiled(ctypes.CDLL(str(lib)), fun)

    def points_kernel(self, mounts) -> Compiled:
        """The compiled ``points`` kernel of ``mounts`` (built on first use: ask early)."""
        try:
            key = tuple((str(b), tuple(float(x) for x in np.ravel(p))) for b, p in mounts)
        except (TypeError, ValueError) as exc:
            raise EstimatorError(f"mounts must be (body, point) pairs: {exc}") from exc
        bad = [p for _, p in key if len(p) != 3 or not all(map(math.isfinite, p))]
        if bad:
            raise EstimatorError(f"a mount's point must be 3 finite numbers [m], got {bad[0]}")
        k = self._points.get(key)
        if k is None:
            with self._lock:
                k = self._points.get(key)
                if k is None:
                    k = self._points[key] = self._compile(points_function(self.machine, key),
                                                          "-O2")
        return k

    @staticmethod
    def fill(inp: np.ndarray, state) -> None:
        """Write ``state``'s fields into the kernel input ``inp`` (`INPUTS`).

        As one join of their bytes (`estimators.packing`: a `MachineState`'s arrays are
        read-only C-contiguous float64 copies), the bytes the slices' assignments write, at
        half their cost; else by the slices, which convert or raise as before.
        """
        try:
            row = _join((state.base_rotation, state.base_twist, state.base_acceleration,
                         state.q, state.qd, state.qdd[N_SERVO_AXES:]))
        except (TypeError, ValueError, BufferError):
            row = b""
        if len(row) == inp.nbytes:
            memoryview(inp).cast("B")[:] = row
            return
        inp[0:9] = state.base_rotation.ravel()
        inp[9:15] = state.base_twist
        inp[15:21] = state.base_acceleration
        inp[21:34] = state.q
        inp[34:47] = state.qd
        inp[47:51] = state.qdd[N_SERVO_AXES:]

    def efforts(self, state) -> tuple | None:
        """``((E_a, e_0a), (E_b, e_0b))`` at the `ANCHOR_MASSES`, or None if not finite."""
        k = self._efforts
        inp, out = k.buffers()
        self.fill(inp, state)
        k.call_buffers()
        if not math.isfinite(out[-1]):
            return None
        n = N_SERVO_AXES
        o = out.copy()
        half = n * n + n
        return tuple((o[s:s + n * n].reshape(n, n), o[s + n * n:s + half])
                     for s in (0, half))

    def points(self, state, mounts) -> tuple[np.ndarray, np.ndarray] | None:
        """``(A (3k, 9), b (3k,))`` at ``mounts``, or None if not finite."""
        out = self.points_row(state, mounts)
        if out is None:
            return None
        m = 3 * len(mounts)
        o = out.copy()
        return o[:m * N_SERVO_AXES].reshape(m, N_SERVO_AXES), o[m * N_SERVO_AXES:-1]

    def points_row(self, state, mounts) -> np.ndarray | None:
        """The ``points`` kernel's output row (A row-major, b, checksum), or None if not finite.

        This thread's output buffer, not a copy: valid until the kernel runs again on it.
        """
        last, k = self._last_points
        if mounts is not last or not isinstance(mounts, tuple):  # a tuple cannot change
            k = self.points_kernel(mounts)
            self._last_points = (mounts, k)
        inp, out = k.buffers()
        self.fill(inp, state)
        k.call_buffers()
        return out if math.isfinite(out[-1]) else None


_REGISTRY: dict[str, EffortKernels | None] = {}
_REGISTRY_LOCK = threading.Lock()
ANCHORS = ANCHOR_MASSES  # [kg] the payload masses of `EffortKernels.efforts`' two results


def kernels_for(machine: Machine) -> EffortKernels | None:
    """The compiled kernels of ``machine``'s description (made once per process), or None.

    Keyed by the description at the first anchor mass, so machines that differ only in the
    payload's mass share them. None when the C compiler is missing or fails (logged).
    """
    key = anchor_machines(machine)[0].fingerprint
    with _REGISTRY_LOCK:
        if key not in _REGISTRY:
            try:
                _REGISTRY[key] = EffortKernels(machine)
            except (OSError, subprocess.SubprocessError) as exc:
                _log.warning("effort kernels not compiled (%s); using Pinocchio", exc)
                _REGISTRY[key] = None
        return _REGISTRY[key]
