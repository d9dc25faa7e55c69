"""The servo a bench log was recorded on, as the replay and identification need it, whichever bus
speaks to it: its motor (hal.motor), its position law's gain (duty per P unit per rad of error)
with where that gain comes from, its PWM register's full scale, and its data sheet's no-load
current. The catalogues are the backends' (hal.dynamixel, hal.feetech); this only reads them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import InputError
from ..hal.dynamixel import control_table as dxl
from ..hal.feetech import table as sts
from ..hal.motor import MotorModel
from .bench import read_bench_log, twos_complement


@dataclass(frozen=True)
class BenchServo:
    name: str
    motor: MotorModel             # the catalogue's (identified where a recording identified it)
    gain_per_p: float             # duty per P unit per rad of error (the position law, I = D = 0)
    law: str                      # the law in the servo's units, and its source
    pwm_full: float               # Present PWM (or Present Load) units at 100 % duty
    no_load_current: float        # A, the data sheet's (0: not published)
    decode_load: Callable         # a log's raw `load` register → signed PWM units

    def read(self, path):
        """A bench log of this servo (its `load` decoded as the servo writes it)."""
        return read_bench_log(path, self.decode_load)

    def duty_per_rad(self, p_gain):
        return p_gain * self.gain_per_p


def _present_load(load: np.ndarray) -> np.ndarray:
    """A Feetech's Present Load (its applied duty in 0.1 % units, sign-magnitude), signed."""
    return np.array([sts.item_value("present_load", int(raw)) for raw in load], dtype=float)


def _feetech(spec) -> BenchServo:
    motor = MotorModel(torque_constant=spec.motor_kt, resistance=spec.motor_resistance,
                       back_emf_constant=spec.motor_ke, armature=spec.armature, friction_coulomb=spec.friction_coulomb,
                       friction_viscous=spec.friction_viscous, max_duty=sts.MAX_DUTY)
    law = (f"duty = {sts.POSITION_GAIN:g} x P x error (rad), capped at {sts.MAX_DUTY:g}: BAM's oscilloscope "
           "figures for the STS3215 (Feetech's table: P/4 per step in 0.1 % units, 0.163)")
    return BenchServo(spec.name, motor, sts.POSITION_GAIN, law, sts.DUTY_FULL, spec.no_load_current, _present_load)


def _dynamixel(spec) -> BenchServo:
    law = f"Present PWM = P/{spec.p_gain_divisor} x error (ticks), {dxl.PWM_FULL} = 100 %: {spec.p_gain_source}"
    return BenchServo(spec.name, spec.motor_model, spec.duty_per_rad(1.0), law, dxl.PWM_FULL, spec.no_load_current,
                      twos_complement)


def bench_servo(name: str) -> BenchServo:
    """The catalogue servo `name` (Dynamixel or Feetech), in any case; an InputError naming the choices."""
    for catalogue, make in ((dxl.SERVOS, _dynamixel), (sts.SERVOS, _feetech)):
        found = next((s for n, s in catalogue.items() if n.lower() == name.lower()), None)
        if found is not None:
            return make(found)
    raise InputError(f"unknown servo {name!r}: one of {', '.join(sorted([*dxl.SERVOS, *sts.SERVOS]))}")
