"""The run's contact observer, built from a configuration: its `[safety]` table (gain, static
thresholds), its identified friction, and its sensors' resolution (the dynamic term of the
thresholds). One builder for the run's guard and for `servodyn contact`."""

from __future__ import annotations

import numpy as np

from ..control.contact import DEFAULT_GAIN, ContactObserver, Uncertainty
from ..hal.backend import joint_sensors


def contact_observer(config, watching: bool = True) -> ContactObserver:
    """The observer of `config`'s arm; `watching=False`: it keeps its residual and never detects (a
    calibration's clean runs)."""
    safety = config.guards
    friction = config.friction
    thresholds = np.inf if not watching else safety.contact_threshold
    return ContactObserver(config.model, config.control_period,
                           gain=DEFAULT_GAIN if safety.observer_gain is None else safety.observer_gain,
                           thresholds=thresholds,
                           friction=(friction["friction_coulomb"], friction["friction_viscous"]),
                           uncertainty=Uncertainty(velocity_resolution=joint_sensors(config).velocity_step))
