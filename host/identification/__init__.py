"""Identification: the arm's numbers from its own logs.

The joint torque is linear in each body's 10 inertial parameters (the core's regressor,
`Model.regressor`) and in each joint's friction and armature, so a log of q and of the motor
current (torque = current x torque constant x gear ratio) gives them by least squares:

  signals     zero-phase Butterworth (scipy sosfiltfilt) on q and on the current alike, q̇ and q̈ by
              central differences of the filtered q, then decimation (Gautier's IDIM-LS practice)
  estimate    the observation matrix of several logs; base parameters by QR with column pivoting
              (Gautier 1991); ordinary, then per-joint weighted least squares; standard errors;
              per joint Coulomb and viscous friction (on samples beyond a few velocity quanta),
              armature; a payload at a body (or the arm's base parameters); a torque-constant scale
              per joint when a log carries a known payload (Gautier & Briot 2011)
  thermal     a servo's thermal resistance and time constant from a heating run's temperature, on
              the winding model the validator and the simulated servos use (hal.thermal), fitted to
              the whole-degree readings with their worst-case error
  heating     the heating run: hold a pose gravity loads, then rest where the arm hangs
  excitation  Swevers' finite Fourier series, its coefficients chosen for a well conditioned
              observation matrix, at rest at both ends

Parameters the data cannot determine (a relative standard error above REL_SIGMA_MAX, a column the
logs never excite, a joint that never moves) are reported as such, never invented.
It takes arrays, not files: `servodyn identify` (tools/identify.py) reads the logs with the loop's
reader (loop.log.read_run_log) and `servodyn excite` checks its motion with the validator; beside the
validator and the simulator in the layers, it imports neither.
"""

from .estimate import (REL_SIGMA_MAX, STILL_SPEED, Estimate, IdentificationError, Parameter, identify,
                       measured_torque)
from .excitation import FourierExcitation, design_excitation
from .signals import FILTER_HZ, FILTER_ORDER, Prepared, prepare
from .heating import HeatingRun, design_heating
from .thermal import ThermalFit, fit_thermal, read_rows

__all__ = ["FILTER_HZ", "FILTER_ORDER", "REL_SIGMA_MAX", "STILL_SPEED", "Estimate", "FourierExcitation",
           "HeatingRun", "IdentificationError", "Parameter", "Prepared", "ThermalFit", "design_excitation",
           "design_heating", "fit_thermal", "identify", "measured_torque", "prepare", "read_rows"]
