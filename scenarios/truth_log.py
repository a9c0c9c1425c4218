"""The ground-truth columns of a closed loop's log, filled in place row by row.

At every tick a closed loop logs what `Simulator.measure` reports (with the optional
`MeasurementNoise`), MuJoCo's exact wheel contacts, the loop-closure gap, ``qpos``, ``qvel``
and the machine's centre of mass: the columns `models.log.ScenarioLog.append` would make of
them, here written into arrays allocated once for the whole run. `TruthColumns.record` writes
a row with `scenarios.truth_c` (one C call) where it can, else with the Python path, which is
the reference (`tests/test_truth_log.py` compares the two to the bit).
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import address
from models.coordinates import N_INDEPENDENT
from models.state import ROTATION_TOLERANCE
from scenarios.ground_truth import CONTACT_FORCE_THRESHOLD
from scenarios.simulator import Simulator
from scenarios.truth_c import TruthSetup, compiled_truth

__all__ = ["TRUTH_COLUMNS", "TruthColumns"]

# The columns, in the order `ScenarioLog.append` writes them, and each row's shape.
_STATE = {"base_position": (3,), "base_rotation": (3, 3), "base_twist": (6,),
          "base_acceleration": (6,), "q": (N_INDEPENDENT,), "qd": (N_INDEPENDENT,),
          "qdd": (N_INDEPENDENT,)}
TRUTH_COLUMNS = (*_STATE, "time", "force_in_fb", "point_in_fb", "normal_in_fb", "in_contact",
                 "normal_force", "fz_in_fb", "suspension_force", "servo_setpoint",
                 "closure_violation", "qpos", "qvel", "com_world")


class TruthColumns:
    """Preallocated ground-truth columns; `record` fills row ``k`` at tick ``k``.

    Args:
        sim: The simulator (its measured instant is what a row holds).
        capacity: Rows.
        compiled: Write rows in C where possible (`scenarios.truth_c`); False: Python.

    Attributes:
        columns: The arrays by name (`TRUTH_COLUMNS`), ``capacity`` rows each.
        true_q: The row's independent coordinates as the task's error reads them: the truth
            (MuJoCo's, without measurement noise), strokes clipped into their ranges (13,).
    """

    def __init__(self, sim: Simulator, capacity: int, compiled: bool = True):
        self._sim = sim
        n_servo = len(sim.servos)
        shapes = {**_STATE, "time": (), "in_contact": (4,), "normal_force": (4,),
                  "fz_in_fb": (4,), "suspension_force": (2,), "servo_setpoint": (n_servo,),
                  "closure_violation": (), "qpos": (sim.model.nq,), "qvel": (sim.model.nv,),
                  "com_world": (3,)}
        self._contacts = np.zeros((capacity, 3, 4, 3))  # force, point, normal in fb
        self.columns = {}
        for name in TRUTH_COLUMNS:
            if name in ("force_in_fb", "point_in_fb", "normal_in_fb"):
                self.columns[name] = self._contacts[:, ("force_in_fb", "point_in_fb",
                                                       "normal_in_fb").index(name)]
            else:
                self.columns[name] = np.zeros((capacity, *shapes[name]),
                                              bool if name == "in_contact" else float)
        self.true_q = np.zeros(N_INDEPENDENT)
        self._strokes = list(sim.machine.coordinates.chain_indices)
        self._row = self._bind(compiled) if sim.noise is None else None

    def _bind(self, compiled: bool):
        """`TRUTH_C`'s ``truth_row`` bound to this simulator and these columns, or None."""
        sim, ix = self._sim, self._sim.index
        fun = compiled_truth() if compiled else None
        base_dof = np.asarray(ix.base_dof)
        if fun is None or not np.array_equal(base_dof, base_dof[0] + np.arange(6)):
            return None
        coords = sim.machine.coordinates
        chains = [(i, coords.binding(i)) for i in coords.chain_indices]
        wheel_of_geom = np.full(sim.model.ngeom, -1, np.int64)
        wheel_of_geom[ix.wheel_geoms] = np.arange(4)
        ints = [np.ascontiguousarray(a, np.int64) for a in (
            base_dof, ix.independent_qpos, ix.independent_dof, ix.suspension_actuators,
            wheel_of_geom, ix.loop_site_pairs.ravel(), [i for i, _ in chains],
            [ix.dof_adr[b.driven_joint] for _, b in chains])]
        floats = [np.array([[*b.chain.side_lengths, b.chain.dead_length + b.chain.rod_length,
                             b.chain.sigma] for _, b in chains], float).ravel(),
                  np.asarray(coords.lower, float).copy(), np.asarray(coords.upper, float).copy()]
        c = self.columns
        setup = TruthSetup(
            ix.base_body, sim.model.nq, sim.model.nv, len(sim.servos), len(ix.loop_site_pairs),
            len(chains), *(a.ctypes.data for a in ints + floats), CONTACT_FORCE_THRESHOLD,
            ROTATION_TOLERANCE, *(c[n].ctypes.data for n in (
                "time", "base_position", "base_rotation", "base_twist", "base_acceleration",
                "q", "qd", "qdd")), self._contacts.ctypes.data,
            *(c[n].ctypes.data for n in ("normal_force", "fz_in_fb", "suspension_force",
                                         "servo_setpoint", "closure_violation", "qpos", "qvel",
                                         "com_world")),
            self.true_q.ctypes.data, c["in_contact"].ctypes.data)
        self._keep = (ints, floats, setup)  # the C reads them
        return fun, (sim.model._address, sim.data._address, ctypes.addressof(setup))

    def record(self, k: int) -> None:
        """Row ``k`` of every column from the simulator's measured instant."""
        sim = self._sim
        if self._row is not None:
            fun, fixed = self._row
            qpos, qvel, t, setpoint = sim.measured_arrays()  # read only, here
            if fun(*fixed, k, address(qpos), address(qvel), t, address(setpoint)) == 0:
                return
        qpos, qvel, _ = sim.measured_instant
        self._record_python(k, qpos, qvel)

    def _record_python(self, k: int, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """`record` in Python: `Simulator.measure` and `ScenarioLog.append`'s rows of it."""
        sim, c = self._sim, self.columns
        state, truth = sim.measure()
        for name in _STATE:
            c[name][k] = getattr(state, name)
        c["time"][k] = state.time
        for name in ("force_in_fb", "point_in_fb", "normal_in_fb", "in_contact",
                     "normal_force", "fz_in_fb"):
            c[name][k] = getattr(truth, name)
        c["suspension_force"][k] = (np.nan if state.suspension_force is None
                                    else state.suspension_force)
        c["servo_setpoint"][k] = (np.nan if state.servo_setpoint is None
                                  else state.servo_setpoint)
        c["closure_violation"][k] = sim.closure_violation()
        c["qpos"][k], c["qvel"][k] = qpos, qvel
        c["com_world"][k] = sim.data.subtree_com[sim.index.base_body]
        # the truth, not the measured (noisy) state; MuJoCo's soft joint limits let a stroke
        # pass its end by a little, which the kinematics reject
        q = state.q.copy() if sim.noise is None else qpos[sim.index.independent_qpos]
        q[self._strokes] = sim.machine.coordinates.clip(q)[self._strokes]
        self.true_q[:] = q

    def rows(self, n: int) -> dict[str, np.ndarray]:
        """The first ``n`` rows of every column (views)."""
        return {name: a[:n] for name, a in self.columns.items()}
