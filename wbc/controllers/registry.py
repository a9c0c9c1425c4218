"""Controllers by name."""

from __future__ import annotations

from models.description import Machine
from wbc.controllers.config import ControllerConfig
from wbc.controllers.controller import Controller
from wbc.controllers.mpc import MpcController
from wbc.controllers.tracking import WholeBodyQPController
from wbc.errors import ConfigurationError, UnknownControllerError
from wbc.force_models.estimator import load_closure, load_estimator
from wbc.force_models.feedback import ClosureFeedback
from wbc.force_models.protocol import NormalForceModel
from wbc.kinematics.tcp_kinematics import TcpKinematics

__all__ = ["CONTROLLER_NAMES", "estimator_models", "make_controller"]

CONTROLLER_NAMES = ("tracking", "mpc-quasi-static", "mpc-full")


def make_controller(name: str, machine: Machine, config: ControllerConfig | None = None, *,
                    force_model: NormalForceModel | None = None,
                    tcp_kinematics: TcpKinematics | None = None) -> Controller:
    """A controller by name.

    * ``tracking``: the whole-body QP without the force constraint.
    * ``mpc-quasi-static``, ``mpc-full``: the MPC with
      ``estimators.NormalForceEstimator(machine, method="quasi-static" | "full")`` (d-beta
      fourth row, strokes clipped into their ranges) along the horizon, corrected by the
      same method's cylinder-force closure at the measured state (`ClosureFeedback`); or with
      ``force_model`` when given (e.g. a test double), then without the feedback.

    Raises:
        UnknownControllerError: ``name`` is not in `CONTROLLER_NAMES`.
        ConfigurationError: A force model given to ``tracking``.
    """
    if not isinstance(name, str) or name not in CONTROLLER_NAMES:
        raise UnknownControllerError(repr(name) if not isinstance(name, str) else name,
                                     CONTROLLER_NAMES)
    if name == "tracking":
        if force_model is not None:
            raise ConfigurationError("the 'tracking' controller uses no force model; use "
                                     "WholeBodyQPController(force_model=...) for a QP with "
                                     "the force constraint")
        return WholeBodyQPController(machine, config, tcp_kinematics=tcp_kinematics)
    method = name.removeprefix("mpc-")
    feedback = None
    if force_model is not None:
        model = force_model
    else:
        model, feedback = estimator_models(machine, method)
    return MpcController(machine, config, force_model=model, tcp_kinematics=tcp_kinematics,
                         name=name, feedback=feedback)


def estimator_models(machine: Machine, method: str) -> tuple[NormalForceModel,
                                                              ClosureFeedback]:
    """The MPC's force model and load-split feedback for ``machine`` (see `make_controller`).

    For `MpcController.set_force_model` when the machine changes (a new payload mass).
    """
    return load_estimator(machine, method), ClosureFeedback(load_closure(machine, method))
