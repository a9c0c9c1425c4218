"""Ground truth at every physics step: each wheel's normal force, for physics-rate metrics.

A control-rate sample (10 ms) misses a wheel's force dropping to 0 N for 2-4 ms; the safety
metrics therefore count at every simulator step. `NormalForceRecorder` is a step listener
(`Simulator.add_step_listener`) that reads, after each step, the normal rows of MuJoCo's
contact forces (``efc_force`` at each contact's ``efc_address``: for the model's elliptic
condim-3 contacts the first row is the force along the contact normal, >= 0) and sums them per
wheel. That is the wheel's force along the terrain normal when it touches at one point, as in
`scenarios.ground_truth` (which also forms the tangential parts, at the control rate).
"""

from __future__ import annotations

import numpy as np

from models.cbuild import BufferSlot
from scenarios.listeners_c import compiled_forces, forces_hooks
from scenarios.simulator import Simulator
from scenarios.step_c import StepHook

__all__ = ["NormalForceRecorder"]

_CHUNK = 4096  # samples per buffer growth


class NormalForceRecorder:
    """Records every physics step's four normal forces [N] (order FL, RL, FR, RR).

    Args:
        sim: The simulator; the recorder adds itself as a step listener (`close` removes it).
        compiled: Sum in C (`scenarios.listeners_c`, the same bits), if a compiler is there;
            False: in Python.
    """

    def __init__(self, sim: Simulator, compiled: bool = True):
        self._sim = sim
        model = sim.model
        wheel_of_geom = np.full(model.ngeom, -1)
        wheel_of_geom[sim.index.wheel_geoms] = np.arange(4)
        self._wheel_of_geom = wheel_of_geom.tolist()  # read per contact: Python ints
        self._wheel_of_geom_c = wheel_of_geom.astype(np.int64)  # kept alive: the C reads it
        self._record = compiled_forces() if compiled else None
        # n, capacity, the buffers' and the wheel table's addresses: `FORCES_C`'s forces_hook
        self._hook = np.zeros(5, np.int64)
        self._time = np.zeros(0)
        self._force = np.zeros((0, 4))
        self._grow()
        sim.add_step_listener(self)

    _n = BufferSlot("_hook", 0, int, doc="Samples recorded (the C hook counts them too).")

    def _grow(self) -> None:
        self._time = np.concatenate([self._time, np.zeros(_CHUNK)])
        self._force = np.concatenate([self._force, np.zeros((_CHUNK, 4))])
        self._hook[1:] = (self._time.shape[0], self._time.ctypes.data, self._force.ctypes.data,
                          self._wheel_of_geom_c.ctypes.data)

    def step_hook(self) -> StepHook | None:
        """The recorder in C for the simulator's compiled steps (`scenarios.step_c`)."""
        hooks = forces_hooks() if self._record is not None else None
        return None if hooks is None else StepHook(*hooks, self._hook.ctypes.data,
                                                     self._make_room)

    def _make_room(self, steps: int) -> None:
        while self._n + steps > self._time.shape[0]:
            self._grow()

    def __call__(self, sim: Simulator, qpos, qvel, t: float) -> None:
        """Record the step that started at ``t`` (a `Simulator` step listener)."""
        if self._n == self._time.shape[0]:
            self._grow()
        d = sim.data
        if self._record is not None:  # the loop below in C (`scenarios.listeners_c`)
            self._record(d._address, self._wheel_of_geom_c.ctypes.data,
                         self._force.ctypes.data + self._force.strides[0] * self._n)
            self._time[self._n] = t
            self._n += 1
            return
        # A handful of contacts: a loop over Python numbers costs half of numpy's calls on
        # arrays that small. Each wheel's sum in contact order, from 0.0, as `np.add.at`.
        wheel_of = self._wheel_of_geom
        f = [0.0, 0.0, 0.0, 0.0]
        c = d.contact
        efc_force = d.efc_force
        for (g0, g1), row in zip(c.geom.tolist(), c.efc_address.tolist()):
            w0, w1 = wheel_of[g0], wheel_of[g1]
            wheel = w0 if w0 > w1 else w1
            if wheel >= 0 and row >= 0:  # a wheel's contact not merged away
                f[wheel] += efc_force[row]
        self._force[self._n] = f
        self._time[self._n] = t
        self._n += 1

    def __len__(self) -> int:
        return self._n

    @property
    def time(self) -> np.ndarray:
        """Each sample's instant [s], shape (M,) (a copy)."""
        return self._time[:self._n].copy()

    @property
    def normal_force(self) -> np.ndarray:
        """Normal forces [N], shape (M, 4) (a copy)."""
        return self._force[:self._n].copy()

    def clear(self) -> None:
        """Forget the samples so far (e.g. those of the settling)."""
        self._n = 0

    def close(self) -> None:
        """Stop recording."""
        self._sim.remove_step_listener(self)
