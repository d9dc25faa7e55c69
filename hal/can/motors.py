"""The CAN motors servodyn knows: each one's data sheet in SI at its output shaft, and the MIT
ranges its firmware uses by default (a Damiao motor keeps them in registers PMAX, VMAX, TMAX).

Sources: Damiao's instruction manuals for the DM-J4310-2EC V1.1 and DM-J4340-2EC (Damiao's
documentation wiki, and Seeed's Damiao wiki for the torque constant and phase resistance), the
vendor's MIT defaults as openarm_can's dm_motor_constants.hpp has them; CubeMars' AK80-9 manual
(MIT firmware ranges). Neither vendor gives thermal figures: the thermal resistance and time
constant below are estimates for a 43 mm outrunner in a closed housing (marked so), good enough
for the simulator's over-temperature fault, not for sizing a motor. A motor's mass and size are
the model's (host/model/parts.toml: the solid its housing is in a model of the arm).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..servos import ServoSpec
from .frames import Ranges


@dataclass(frozen=True, kw_only=True)
class MotorSpec(ServoSpec):
    """A CAN motor with its driver; stall_torque is the peak torque, stall_current = peak torque /
    torque constant (so torque_constant is the vendor's output-side Kt)."""
    dialect: str                    # the dialect its firmware speaks by default
    ranges: Ranges                  # the MIT frame's default ranges
    phase_resistance: float         # Ω, winding (I²R heating)
    rated_torque: float             # N m, continuous
    source: str

    @property
    def winding_resistance(self) -> float:
        return self.phase_resistance


DM_J4340 = MotorSpec(
    name="DM-J4340", kind="can", dialect="damiao", gear_ratio=40.0,
    stall_torque=27.0, stall_current=27.0 / 4.074, no_load_speed_rpm=52.5, nominal_voltage=24.0,
    ratings=((48.0, 27.0, 27.0 / 4.074, 100.0),),
    rated_torque=9.0, phase_resistance=0.88,
    temperature_limit=100.0, thermal_resistance=3.0, thermal_time_constant=400.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=8.0, t_max=28.0),
    source="Damiao DM-J4340-2EC manual: rated 9 N m, peak 27 N m, 52.5 rpm at 24 V (100 at 48 V), "
           "gear 40; Kt 4.074 N m/A, R 0.88 ohm (Seeed Damiao wiki); MIT 12.5 / 8 / 28")

DM_J4310 = MotorSpec(
    name="DM-J4310", kind="can", dialect="damiao", gear_ratio=10.0,
    stall_torque=7.0, stall_current=7.0 / 0.945, no_load_speed_rpm=200.0, nominal_voltage=24.0,
    rated_torque=3.0, phase_resistance=0.85,
    temperature_limit=100.0, thermal_resistance=4.0, thermal_time_constant=300.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=30.0, t_max=10.0),
    source="Damiao DM-J4310-2EC V1.1 manual: rated 3 N m, peak 7 N m, 200 rpm at 24 V, gear 10; "
           "Kt 0.945 N m/A, R 0.85 ohm (Seeed Damiao wiki); MIT 12.5 / 30 / 10")

AK80_9 = MotorSpec(
    name="AK80-9", kind="can", dialect="cubemars", gear_ratio=9.0,
    stall_torque=18.0, stall_current=18.0 / 0.819, no_load_speed_rpm=390.0, nominal_voltage=48.0,
    rated_torque=9.0, phase_resistance=0.17,
    temperature_limit=100.0, thermal_resistance=2.0, thermal_time_constant=500.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=50.0, t_max=18.0),
    source="CubeMars AK80-9 manual: rated 9 N m, peak 18 N m, gear 9, Kt 0.091 N m/A x 9, "
           "MIT 12.5 / 50 / 18")

MOTORS = {m.name: m for m in (DM_J4340, DM_J4310, AK80_9)}
