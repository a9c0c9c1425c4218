"""The observer: the machine's sensor streams turned into the state the estimator reads."""

from estimators.observer.joint_filter import POSITION_FAULT, POSITION_GATE
from estimators.observer.observer import (
    CONTACT_LANDING_N,
    CONTACT_OFF_N,
    CONTACT_ON_N,
    CONTACT_TICKS,
    Observer,
    ObserverEstimate,
)

__all__ = ["CONTACT_LANDING_N", "CONTACT_OFF_N", "CONTACT_ON_N", "CONTACT_TICKS", "Observer",
           "ObserverEstimate", "POSITION_FAULT", "POSITION_GATE"]
