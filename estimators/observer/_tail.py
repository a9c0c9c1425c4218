"""The observer's tick after the filters' pass in one C call (`tail_c`), and its outputs.

`Observer._update` runs, after `_tick.TickPass`, the link fit, the payload regression and
filter, the crane's accelerations from the pressures, the contact points and the flags
(`Observer._from_links` and the steps it hands on to): ~50 us of Python around ~10 us of
compiled work, three intermediate states and two contact sets. `TailPass` runs the same
steps on the state's buffer in ``tail_run`` (``tail_head`` up to the payload filter, the
filter on `payload_rls.PayloadRLS`'s state array, ``tail_end`` after it), then makes the
one `MachineState` and `ObserverEstimate`. Where its C hands back (`tail_c.HEAD_CODES`,
`tail_c.RUN_CODES`), the Python steps finish the tick from there. The same bits
(`tests/test_observer_tail_c.py`, `tests/test_payload_rls_c.py`).
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from estimators.efforts_kernel import ANCHORS
from estimators.observer import contacts_c, fusion_c, tail_c
from estimators.observer._states import StateBuffer, trusted_state, wheel_contacts
from estimators.observer.crane_pressures import SLIDING_SPEED
from estimators.observer.payload_rls import forgetting
from models.cbuild import address
from models.reference_machine import MAX_PAYLOAD_MASS

__all__ = ["TailPass", "tail_pass"]

_S = {name: i for i, name in enumerate(tail_c.SCALARS)}
_Z = slice(_S["z0"], _S["band1"] + 1)
_TIME, _LAM, _CRANE, _MASS, _STD, _SLIDING, _FLAGS_FINITE = (
    _S[n] for n in ("time", "lam", "crane", "mass", "std", "sliding", "flags_finite"))
_ALL_IN = np.ones(4, bool)


def _kernel_block(kernel, inp: np.ndarray) -> tuple:
    """A compiled CasADi kernel on buffers of its own, reading ``inp``.

    (fn, arg, res, iw, w) for `tail_c`'s table, the output buffer, and what keeps them.
    """
    out = np.zeros(kernel.n_out)
    iw = np.zeros(kernel.sz_iw, np.int64)
    w = np.zeros(kernel.sz_w)
    arg = (ctypes.c_void_p * kernel.sz_arg)(inp.ctypes.data)
    res = (ctypes.c_void_p * kernel.sz_res)(out.ctypes.data)
    block = (kernel.address, ctypes.addressof(arg), ctypes.addressof(res), iw.ctypes.data,
             w.ctypes.data)
    return block, out, (arg, res, iw, w, inp, out)


def tail_pass(observer) -> TailPass | None:
    """The observer's `TailPass`, or None where its C does not apply.

    It needs the filters' pass (`_tick`), the compiled contacts, link fit and efforts
    kernels, a `PayloadEstimator` force model on compiled kernels with the full method,
    numpy's BLAS (`tail_c.numpy_blas`) and a C compiler.
    """
    from estimators._kernel_calls import Compiled
    from estimators.payload import PayloadEstimator

    fm = observer.force_model
    if (observer._tick is None or observer.contacts._c is None
            or observer.efforts._kernels is None or type(fm) is not PayloadEstimator
            or (observer.links is not None and observer.links._c is None)):
        return None
    est = fm._est
    if est._kernels is None or est._packer.zeroed is not None or not est._kernels.compiled:
        return None
    kernel = est._kernels.kernel("nf_estimate")
    blas = tail_c.numpy_blas()
    lib = tail_c.compiled_tail()
    if not isinstance(kernel, Compiled) or blas is None or lib is None:
        return None
    return TailPass(observer, lib, kernel, blas)


class TailPass:
    """`tail_c`'s calls bound to an observer's buffers (module docstring).

    Args:
        observer: The `Observer` (its filters' pass, links, efforts, contacts, force model).
        lib: The loaded `tail_c` library.
        kernel: The force model's compiled ``nf_estimate`` kernel.
        blas: `tail_c.numpy_blas`'s addresses.
    """

    def __init__(self, observer, lib, kernel, blas):
        obs = self._obs = observer
        self._tick = obs._tick
        self._lib = lib
        self._est = obs.force_model._est
        ek = obs.efforts._kernels
        self._s = s = np.zeros(len(tail_c.SCALARS))
        s[_S["filter_time"]] = obs._payload_filter_time
        s[_S["sliding_speed"]] = SLIDING_SPEED
        s[_S["m1"]], s[_S["m2"]] = ANCHORS
        bounds = self._est._bounds
        s[_S["n_bounds"]] = len(bounds)
        s[_S["max_mass"]] = MAX_PAYLOAD_MASS  # `check_payload_mass`'s range
        s[_S["b0"]], s[_S["b1"]] = obs.payload.bias_std  # fixed (`PayloadRLS.std`)
        self._bounds = tuple(np.array([b[j] for b in bounds] or [0.0], float)
                             for j in range(3))
        self._row = np.zeros(ek._efforts.n_in)
        self._ek = _kernel_block(ek._efforts, self._row)
        self._nk_in = np.zeros(kernel.n_in)
        self._nk = _kernel_block(kernel, self._nk_in)
        self._pk = None
        if obs.links is not None:
            self._pk = _kernel_block(ek.points_kernel(obs.links._mounts), self._row)
            s[_S["link_m"]] = obs.links._mean.size
        self._selectors = np.zeros(16)
        self._db = None  # the (D, beta) `_selectors` holds
        self._out = np.zeros(36)  # the contacts: force | points | normals, each (4, 3)
        self._four = np.zeros(4)
        fus = fusion_c.compiled_fusion()
        con = contacts_c.compiled_contacts()
        self._fns = {"fn_link_mean": fus.link_mean, "fn_link_fuse": fus.link_fuse,
                     "fn_contact_points": con.contact_points,
                     "fn_contact_flags": con.contact_flags}
        self._blas = blas
        self._bind()

    def _bind(self) -> None:
        """The pointer table (`tail_c.POINTERS`) and the calls bound to it."""
        obs, tick, c = self._obs, self._tick, self._obs.contacts
        links = obs.links
        ptr = {"buf": tick._out, "s": self._s, "forces": tick.forces, "seal": obs._seal,
               "regression": obs._regression, "row": self._row,
               "selectors": self._selectors, "payload": self._est._packer.payload,
               "bound_index": self._bounds[0], "bound_lo": self._bounds[1],
               "bound_hi": self._bounds[2], "c_k": c._k, "c_touching": c._touching,
               "c_above": c._above_c, "c_drive": c._drive, "c_acc": tick.wheels[8:],
               "c_prev": obs._previous_four, "c_out": self._out, "c_four": self._four,
               "drive_samples": tick._samples[5], "tick_sc": tick._sc,
               "nk_in": self._nk_in, "rls": obs.payload._state, "rls_ring": obs.payload._ring}
        if links is not None:
            ptr.update(link_samples=links._samples, link_mean=links._mean, link_w=links._w,
                       link_prior=links._prior_diag, link_io=links._io)
        ptr = {k: address(v) for k, v in ptr.items()}
        ptr.update((k, ctypes.cast(f, ctypes.c_void_p).value) for k, f in self._fns.items())
        ptr.update(zip(("fn_gemv", "fn_ddot", "fn_gesv"), self._blas))
        for name, (block, out, _) in (("ek", self._ek), ("nk", self._nk), ("pk", self._pk)
                                      if self._pk is not None else ("pk", ((0,) * 5, None,
                                                                           None))):
            ptr.update(zip((f"{name}_fn", f"{name}_arg", f"{name}_res", f"{name}_iw",
                            f"{name}_w"), block))
            ptr[f"{name}_out"] = 0 if out is None else address(out)
        self._table = (ctypes.c_void_p * len(tail_c.POINTERS))(
            *(ptr.get(name, 0) for name in tail_c.POINTERS))
        at = ctypes.addressof(self._table)
        self._head = functools.partial(self._lib.tail_head, at)
        self._end = functools.partial(self._lib.tail_end, at)
        self._run = functools.partial(self._lib.tail_run, at)
        self._ring = obs.payload._ring
        self._s[_S["rls_cap"]] = self._ring.shape[1]
        self._tick_rows = tick._rows
        self._link_rows = 0 if links is None else links._samples.shape[0]
        self._keep = ptr
        if self._pk is not None:
            self._s[_S["pk_out_n"]] = self._pk[1].size

    def update(self, r, dt: float, stale: bool):
        """`Observer._update` after its first lines: the `ObserverEstimate` of ``r``.

        Raises:
            EstimatorError: As the Python steps.
        """
        obs, tick, s = self._obs, self._tick, self._s
        t = r.time
        tick.run(r, dt, copy=False)
        links = obs.links
        n = 0
        if links is not None and r.link_specific_force is not None:
            value = r.link_specific_force.value
            n = value.shape[0]
            if n:  # `LinkFusion._tick_mean`'s copy, its weights (`_fit_c`)
                if n > links._samples.shape[0]:
                    links._bind_samples(2 * n)
                links._samples[:n] = value
                if n != links._w_of:
                    links._w[:] = links._weights(n)[0]
                    links._w_of = n
        payload = obs.payload
        if tick._rows != self._tick_rows or n > self._link_rows or payload._ring is not \
                self._ring:
            self._bind()  # a samples buffer or the payload filter's ring grew
        if r.servo_setpoint.flags.writeable or not obs.base.rotation_valid:
            return self._python(1, r, dt, stale)
        est = self._est
        if (est.D, est.beta) != self._db:
            self._select(est)
        s[0:2] = dt, n  # dt, link_n
        s[_TIME], s[_LAM] = t, forgetting(dt)
        s[_CRANE] = 1.0 if obs.crane_from_pressures else 0.0
        code = self._run()  # the head, the payload filter, the mass, the end
        if s[3]:  # link_ok: the fit was taken
            links.std = links._io[9:].copy()
        if code in (1, 2, 3):
            return self._python(code, r, dt, stale)
        std = None  # `PayloadRLS.std`: the C's, or asked of the filter
        if code in (5, 6):  # the filter's update (5) or the mass's setting (6) in Python
            if code == 5:
                z = s[_Z].tolist()
                payload.update(t, dt, z[0:2], z[2:4], z[4:6], z[6:8])
            mass = min(max(payload.mass, 0.0), 1e4)
            est.payload_mass = mass
            s[_MASS] = mass
            code = self._end()
        else:
            mass, std = float(s[_MASS]), float(s[_STD])
        if s[_SLIDING]:
            obs.efforts.payload_mass = mass  # as `CranePressures.accelerations` sets it
        if code:
            return self._python(code, r, dt, stale, mass)
        out = self._out.copy().reshape(3, 4, 3)  # the contacts: force | points | normals
        contacts = wheel_contacts(obs.contacts._touching != 0.0, out[0], out[1], out[2],
                                  s[_FLAGS_FINITE] != 0.0)
        four = self._four.copy()
        obs._previous_four[:] = four
        buf = tick._out.copy()
        self._share_efforts(buf)
        return obs._estimate(trusted_state(buf, t, r.servo_setpoint, contacts), mass, four,
                             t, stale, std)

    def _select(self, est) -> None:
        """The packed selectors of four wheels in contact at the estimator's D and beta."""
        packed, sel, _ = est._packer.selectors(_ALL_IN, True, est.D, est.beta)
        if sel.tipping:  # not with four wheels: kept as `_regular_row`'s test
            raise AssertionError("four wheels in contact cannot tip")
        self._selectors[:] = packed
        self._db = (est.D, est.beta)

    def _share_efforts(self, buf: np.ndarray) -> None:
        """The efforts kernel's maps of this motion, for the next `ActuatorEfforts` asking.

        What `ActuatorEfforts.payload_regressor_at` keeps (`efforts._shared_last`): the MPC's
        effort limit asks about the same motion in the same tick.
        """
        o = self._ek[1].copy()
        shared = self._obs.efforts._shared
        shared[:] = [buf[0:50].tobytes() + buf[59:63].tobytes(),
                     ((o[0:81].reshape(9, 9), o[81:90]), (o[90:171].reshape(9, 9),
                                                          o[171:180])), ANCHORS]

    def _python(self, code: int, r, dt: float, stale: bool, mass: float | None = None):
        """The Python steps from where ``tail_head`` or ``tail_end`` handed back."""
        obs = self._obs
        buf = self._tick._out.copy()
        state = StateBuffer(buf).state(r.time, r.servo_setpoint, obs.base.rotation_valid)
        forces = self._tick.forces
        if code in (1, 2):
            return obs._from_links(state, r, forces, dt, stale)
        if code == 3:
            return obs._from_payload(state, r, forces, dt, stale)
        self._share_efforts(buf)
        return obs._from_contacts(state, r, mass, stale)
