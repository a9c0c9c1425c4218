"""The quasi-static baseline of the paper's ref. [13] (Petrovic & Mattila, IEEE Access 2022).

Our reading of [13], as the paper under implementation describes it (a "hybrid approach
combining dynamic and quasi-static aspects", improved upon by contributions (a)-(c)):

* the crane's wrench on the carrier is computed with the crane's *own* joint velocities and
  accelerations, on a base at rest (no base twist, no base acceleration) - contribution (a)
  is what [13] lacks;
* the wheels contribute their weight only: no spin velocity or acceleration - (b);
* the chassis, bogies and suspension cylinders contribute their weight at the current
  geometry only: no suspension motion - (c);
* gravity is taken along the true vertical, i.e. the chassis tilt is used;
* the measured friction forces, the contact geometry, the closing fourth equation (D-beta or
  cylinder forces) and the contact-loss handling are the same as in the full method, so the
  two differ only in the dynamics they keep.

In practice the baseline is the full method evaluated on a *masked* state: base twist and
acceleration zeroed, suspension and wheel velocities and accelerations zeroed. Its
constraint form ``f_z = G a + g0`` therefore has zero columns for the base and for the
suspension and wheel coordinates.
"""

from __future__ import annotations

import numpy as np

from models.description import Machine

__all__ = ["QuasiStaticMask"]


class QuasiStaticMask:
    """Which rates the quasi-static baseline keeps.

    Attributes:
        coordinates: 1.0 for kept independent coordinates (the crane), 0.0 for the
            suspension strokes and wheel angles, shape (13,).
        accelerations: Mask of the generalised accelerations ``[base (6), qdd (13)]``,
            shape (19,): zeros for the base, then `coordinates`.
    """

    def __init__(self, machine: Machine):

        names = machine.coordinates.independent_names
        dropped = set(machine.suspension_coordinates) | set(machine.wheels)
        self.coordinates = np.array([0.0 if n in dropped else 1.0 for n in names])
        self.accelerations = np.concatenate([np.zeros(6), self.coordinates])
        self.dropped_index = np.flatnonzero(self.coordinates == 0.0)

    def apply(self, twist, acceleration, qd, qdd):
        """Masked copies of (base twist, base acceleration, qd, qdd); leading dims allowed."""
        qd = np.array(qd, float, copy=True)
        qdd = np.array(qdd, float, copy=True)
        qd[..., self.dropped_index] = 0.0
        qdd[..., self.dropped_index] = 0.0
        return np.zeros_like(twist, dtype=float), np.zeros_like(acceleration, dtype=float), \
            qd, qdd
