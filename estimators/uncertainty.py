r"""How uncertain the normal forces are: the sensors' errors propagated through the model.

The estimate reads a state made by the observer from real sensors. Its errors (documented by
the observer from the sensors' datasheet figures and its filters' noise gains) reach the
normal forces through the estimator's own first-order sensitivities:

.. math::

    \sigma_{f,i}^2 = \sum_k (G_{ik} \sigma_{a,k})^2 + \sum_j (\partial_{\dot q_j} f_i\,
        \sigma_{\dot q,j})^2 + \sum_s (\partial_{F_s} f_i\, \sigma_{F,s})^2
        + (\partial_m f_i\, \sigma_m)^2

with ``a = [base acceleration (6), qdd (13)]`` (``G = df/da``, exact: the forces are affine in
``a``), the joint velocities, the two suspension cylinder forces of the closure's fourth row
and the payload mass. The base's linear acceleration enters only as the specific force the
IMU measures (see `estimators.observer`), so its standard deviation is the specific force's.
The errors are treated as independent (a diagonal covariance): their sources are separate
sensors, and the payload error, which moves every wheel's force together, is kept whole.

Left out, with their size on the reference machine: the attitude error (the dynamics see
gravity only through the measured specific force; the attitude enters the contact points'
geometry, 0.5 deg moves a force by < 0.1 % of the static load) and the angular-rate error
(centripetal terms, < 1 N at the gyroscopes' 0.01 deg/s).

The controller turns ``sigma`` into its per-wheel margin ``z sigma`` (`force_margin`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from estimators.errors import EstimatorError
from estimators.linearization import N_GENERALIZED, ForceLinearization
from estimators.margin_kernel import MARGIN_STEP
from estimators.suspension_response import stepped_forces
from models.coordinates import N_INDEPENDENT
from models.state import MachineState, frozen_array

__all__ = ["StateUncertainty", "closure_margin", "force_margin", "model_normal_forces",
           "normal_force_std", "numpy_closure_margin", "prepare_margin",
           "suspension_sensitivity"]

# [N] the forces are affine in the cylinder forces: any step works (`margin_terms`' kernel
# is built for this one)
_SUSPENSION_STEP = MARGIN_STEP


@dataclass(frozen=True, eq=False)
class StateUncertainty:
    """Standard deviations of the observer's errors at one tick (zero: exact).

    Attributes:
        acceleration: Of ``a = [specific force / base linear acceleration (3), base angular
            acceleration (3), qdd (13)]`` [m/s^2, rad/s^2], shape (19,).
        qd: Of the joint velocities [m/s, rad/s], shape (13,).
        suspension_force: Of the two suspension cylinder forces [N], shape (2,), the
            mechanism's force (the transducers' errors and the unknown seal friction).
        payload_mass: Of the payload mass [kg].
    """

    acceleration: np.ndarray
    qd: np.ndarray
    suspension_force: np.ndarray
    payload_mass: float = 0.0

    def __post_init__(self):
        for name, shape in (("acceleration", (N_GENERALIZED,)), ("qd", (N_INDEPENDENT,)),
                            ("suspension_force", (2,))):
            a = frozen_array(name, getattr(self, name), shape)
            if (a < 0).any():
                raise EstimatorError(f"StateUncertainty.{name} must be >= 0 (a standard "
                                     f"deviation), got {a}")
            object.__setattr__(self, name, a)
        m = float(self.payload_mass)
        if not (np.isfinite(m) and m >= 0):
            raise EstimatorError(f"StateUncertainty.payload_mass must be a finite std >= 0 "
                                 f"[kg], got {self.payload_mass!r}")
        object.__setattr__(self, "payload_mass", m)

    @classmethod
    def exact(cls) -> StateUncertainty:
        """No error at all (the simulator's oracle state)."""
        return cls(np.zeros(N_GENERALIZED), np.zeros(N_INDEPENDENT), np.zeros(2))

    def with_payload_mass(self, payload_mass) -> StateUncertainty:
        """This uncertainty with another payload std [kg], sharing the (read-only) arrays.

        The observer's per tick: only the payload's std changes, so only it is checked
        (an invalid one raises as the constructor does).
        """
        m = payload_mass
        if not (type(m) is float and math.isfinite(m) and m >= 0):
            return dataclasses.replace(self, payload_mass=payload_mass)
        new = object.__new__(StateUncertainty)
        new.__dict__.update(self.__dict__)
        new.__dict__["payload_mass"] = m
        return new


def suspension_sensitivity(estimator, state: MachineState) -> np.ndarray:
    """``df/dF_s`` of the forces to the two suspension cylinder forces [N/N], shape (4, 2).

    Zero when the state carries no cylinder forces or the estimator's fourth row does not
    read them. The forces are affine in them, so one step per force is exact.
    """
    out = np.zeros((4, 2))
    if state.suspension_force is None:
        return out
    # One packed row per payload anchor (`estimators.suspension_response`): the same forces.
    stepped = (estimator.stepped_suspension_forces(state, _SUSPENSION_STEP)
               if hasattr(estimator, "stepped_suspension_forces")
               else stepped_forces(estimator, state, _SUSPENSION_STEP))
    if stepped is not None:
        out[:] = ((stepped[1:] - stepped[0]) / _SUSPENSION_STEP).T
        return out
    f0 = np.asarray(model_normal_forces(estimator, state), float)
    for s in range(2):
        fs = np.array(state.suspension_force, float)
        fs[s] += _SUSPENSION_STEP
        f1 = model_normal_forces(estimator, state.replace(suspension_force=fs))
        out[:, s] = (np.asarray(f1, float) - f0) / _SUSPENSION_STEP
    return out


def closure_margin(closure, model, state: MachineState, uncertainty: StateUncertainty,
                   confidence: float) -> np.ndarray:
    """``z sigma`` [N] (4,) of forces predicted by ``model``, corrected by ``closure``'s.

    The closed loop's margin (`scenarios.closed_loop`): the controller predicts with
    ``model`` and corrects by the load split ``closure`` measures.
    `normal_force_std` of the closure's linearization at ``state`` with ``G = G_c - G_m``
    (the acceleration errors enter only through the load split the two models disagree on;
    ``G_c`` alone when ``model`` is ``closure``), the closure's suspension and payload
    sensitivities, and `force_margin`. One compiled pass (`estimators.uncertainty_c`, the
    same bits) where the closure has stepped suspension forces, on what the closure's
    ``margin_terms`` makes in one kernel call where it has them (the linearization's ``G``,
    ``d_qd`` and contact flags and the stepped forces: `estimators.margin_kernel`, the same
    bits); else numpy.
    """
    fused = _margin_pass() if hasattr(closure, "stepped_suspension_forces") else None
    if fused is not None and state.suspension_force is not None:
        # The closure's G, d_qd, contact flags and stepped forces in one kernel call where
        # it has it (`margin_terms`, the same bits), with the model's linearization where
        # the model has that (`linearize_with_margin`), else its linearization and steps.
        joint = (model.linearize_with_margin(state, closure, _SUSPENSION_STEP)
                 if model is not closure and hasattr(model, "linearize_with_margin")
                 and hasattr(closure, "margin_terms") else None)
        if joint is not None:
            model_g, terms = joint[0].G, joint[1]
        else:
            model_g = None if model is closure else model.linearize(state).G
            terms = (closure.margin_terms(state, _SUSPENSION_STEP)
                     if hasattr(closure, "margin_terms") else None)
        if terms is None:
            lin = closure.linearize(state)
            terms = (lin.G, lin.d_qd, lin.in_contact,
                     closure.stepped_suspension_forces(state, _SUSPENSION_STEP))
        g, d_qd, in_contact, stepped = terms
        d_m = (closure.payload_sensitivity(state) if hasattr(closure, "payload_sensitivity")
               else None)
        if stepped is not None:
            margin = fused(g, model_g, d_qd, stepped, d_m, in_contact, uncertainty,
                           _quantile(_confidence(confidence)))
            if margin is not None:
                return margin
    return numpy_closure_margin(closure, model, state, uncertainty, confidence)


def numpy_closure_margin(closure, model, state: MachineState, uncertainty: StateUncertainty,
                         confidence: float) -> np.ndarray:
    """`closure_margin` in numpy.

    Its path where the compiled pass does not apply, and the reference its compiled pass is
    tested against, bit for bit.
    """
    model_g = None if model is closure else model.linearize(state).G
    lin = closure.linearize(state)
    if model_g is not None:
        lin = dataclasses.replace(lin, G=lin.G - model_g)  # checks that it is finite
    d_susp = suspension_sensitivity(closure, state)
    d_m = (closure.payload_sensitivity(state) if hasattr(closure, "payload_sensitivity")
           else None)
    return force_margin(normal_force_std(lin, uncertainty, d_susp, d_m), confidence)


def prepare_margin(closure, model) -> None:
    """Make what `closure_margin`'s first call with these makes of them alone, now.

    This thread's compiled margin pass and, where ``model`` shares a kernel call with
    ``closure`` (its ``prepare_margin``, `estimators.payload.PayloadEstimator`), that
    call's buffers: before a closed loop's clock starts. Nothing of a state.
    """
    if not hasattr(closure, "stepped_suspension_forces") or _margin_pass() is None:
        return
    prepare = getattr(model, "prepare_margin", None)
    if model is not closure and prepare is not None and hasattr(closure, "margin_terms"):
        prepare(closure, _SUSPENSION_STEP)


@functools.cache
def _compiled_margin():
    from estimators.uncertainty_c import compiled_margin

    return compiled_margin()


_PASSES = threading.local()  # each thread's `MarginPass` (its buffers are written per call)


def _margin_pass():
    """This thread's `estimators.uncertainty_c.MarginPass`, or None without a compiler."""
    try:
        return _PASSES.margin
    except AttributeError:
        from estimators.uncertainty_c import MarginPass

        fun = _compiled_margin()
        _PASSES.margin = None if fun is None else MarginPass(fun, N_GENERALIZED,
                                                             N_INDEPENDENT, _SUSPENSION_STEP)
        return _PASSES.margin


def model_normal_forces(model, state: MachineState) -> np.ndarray:
    """``model.estimate(state).normal_forces`` [N] (4,), by ``model.normal_forces`` if any.

    (`estimators.payload.PayloadEstimator`'s mixes only the forces: the same numbers, ~20 us
    less than the whole mixed `Estimate`.)
    """
    if hasattr(model, "normal_forces"):
        return model.normal_forces(state)
    return model.estimate(state).normal_forces


def normal_force_std(lin: ForceLinearization, uncertainty: StateUncertainty,
                     d_suspension: np.ndarray | None = None,
                     d_payload: np.ndarray | None = None) -> np.ndarray:
    """Standard deviation of each normal force [N], shape (4,) (module docstring).

    Args:
        lin: The estimator's linearization at the observed state.
        uncertainty: The observer's error model at that state.
        d_suspension: ``df/dF_s`` (4, 2) (`suspension_sensitivity`); None: zero.
        d_payload: ``df/dm`` [N/kg] (4,); None: zero.
    """
    if not isinstance(uncertainty, StateUncertainty):
        raise EstimatorError(f"uncertainty must be a StateUncertainty, got "
                             f"{type(uncertainty).__name__}")
    var = (lin.G * uncertainty.acceleration) ** 2
    total = var.sum(axis=1) + ((lin.d_qd * uncertainty.qd) ** 2).sum(axis=1)
    if d_suspension is not None:
        total += ((np.asarray(d_suspension, float) * uncertainty.suspension_force) ** 2
                  ).sum(axis=1)
    if d_payload is not None:
        total += (np.asarray(d_payload, float) * uncertainty.payload_mass) ** 2
    std = np.sqrt(total)
    std[~lin.in_contact] = 0.0  # a wheel off the ground has no force to be unsure of
    return std


def force_margin(std: np.ndarray, confidence: float) -> np.ndarray:
    """Per-wheel margin ``z sigma`` [N] for a one-sided confidence (e.g. 0.99 -> z = 2.33).

    Args:
        std: Standard deviations [N], shape (4,).
        confidence: Probability that the true force exceeds ``estimate - margin``, in
            [0.5, 1).
    """
    return _quantile(_confidence(confidence)) * np.asarray(std, float)


def _confidence(confidence) -> float:
    if not (isinstance(confidence, (int, float)) and 0.5 <= confidence < 1.0):
        raise EstimatorError(f"confidence must be in [0.5, 1), got {confidence!r}")
    return float(confidence)


@functools.lru_cache(maxsize=16)
def _quantile(confidence: float) -> float:
    """The standard normal ``confidence`` quantile, kept: a closed loop asks every tick."""
    return NormalDist().inv_cdf(confidence)
