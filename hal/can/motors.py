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

# The motors below have no readable manual here (Damiao's are PDFs in dmBots/DM-J6006-2EC and
# DM-J8009P-2EC; CubeMars' AK60-6 and AK70-10 manuals were not found). Their MIT ranges are sourced
# (Damiao's defaults as openarm_can's dm_motor_constants.hpp has them; CubeMars' MIT ranges as
# TMotorCANControl's mit_can parameters have them); every other figure is an ESTIMATE, marked so in
# its source and derived by one rule from the motors above: peak torque 0.7 x the MIT TMAX (the
# DM-J4310's 7 of 10, the lower of the two Damiao motors above), rated torque a third of the peak
# (the DM-J4340's 9 of 27), no-load speed half the MIT VMAX (the DM-J4340's 5.5 of 10 rad/s
# rounded down), output torque constant 0.85 x V / no-load speed (the DM-J4310's 0.82 and the
# DM-J4340's 0.93), phase resistance and thermal figures as for a motor of its size.
_ESTIMATE = ("; ESTIMATES (manual not readable here): peak 0.7 x TMAX, rated peak / 3, no-load speed "
             "VMAX / 2, Kt 0.85 x V / no-load speed, R, thermal")


def _estimated(name: str, dialect: str, gear: float, voltage: float, ranges: Ranges, source: str,
               kt: float | None = None, peak: float | None = None, resistance: float = 0.5,
               thermal: tuple[float, float] = (2.5, 500.0)) -> MotorSpec:
    """A motor whose data sheet is estimated from its MIT ranges by the rule above; `kt` and
    `peak`, when a source gives them, replace the estimate."""
    peak = peak if peak is not None else round(0.7 * ranges.t_max, 1)
    no_load = ranges.v_max / 2 if kt is None else 0.85 * voltage / kt      # rad/s
    kt = kt if kt is not None else 0.85 * voltage / no_load
    return MotorSpec(name=name, kind="can", dialect=dialect, gear_ratio=gear, stall_torque=peak,
                     stall_current=peak / kt, no_load_speed_rpm=round(no_load * 60 / (2 * 3.141592653589793), 1),
                     nominal_voltage=voltage, rated_torque=round(peak / 3, 2), phase_resistance=resistance,
                     temperature_limit=100.0, thermal_resistance=thermal[0], thermal_time_constant=thermal[1],
                     ranges=ranges, source=source + _ESTIMATE)


DM_J6006 = _estimated(
    "DM-J6006", "damiao", 6.0, 24.0, Ranges(p_max=12.5, v_max=45.0, t_max=20.0),
    "Damiao DM-J6006-2EC: gear 6 (Damiao's naming: J6006 = 60 mm stator, 6:1), 24 V; MIT 12.5 / 45 / 20 "
    "(openarm_can dm_motor_constants.hpp, DM6006)")
DM_J8009 = _estimated(
    "DM-J8009", "damiao", 9.0, 24.0, Ranges(p_max=12.5, v_max=45.0, t_max=54.0),
    "Damiao DM-J8009-2EC: gear 9 (Damiao's naming: J8009 = 80 mm stator, 9:1), 24 V; MIT 12.5 / 45 / 54 "
    "(openarm_can dm_motor_constants.hpp, DM8009)", resistance=0.3, thermal=(1.5, 700.0))
AK60_6 = _estimated(
    "AK60-6", "cubemars", 6.0, 24.0, Ranges(p_max=12.5, v_max=50.0, t_max=15.0),
    "CubeMars AK60-6: gear 6, 24 V; peak 9 N m (T-Motor's specification, as IHMC's TMotorAK606Parameters "
    "cites it); motor Kt 0.068 N m/A x 6 (TMotorCANControl mit_can, 'from the TMotor website'); "
    "MIT 12.5 / 50 / 15 (TMotorCANControl; IHMC's parameters give 41.87 / 9 for another firmware)",
    kt=0.068 * 6, peak=9.0, resistance=0.3)
AK70_10 = _estimated(
    "AK70-10", "cubemars", 10.0, 24.0, Ranges(p_max=12.5, v_max=50.0, t_max=25.0),
    "CubeMars AK70-10: gear 10, 24 V; motor Kt 0.095 N m/A x 10 (TMotorCANControl mit_can, 'from the "
    "TMotor website'); MIT 12.5 / 50 / 25 (CubeMars manual section 5.3 as quoted by its users; "
    "TMotorCANControl)", kt=0.095 * 10, resistance=0.3)

MOTORS = {m.name: m for m in (DM_J4340, DM_J4310, AK80_9, DM_J6006, DM_J8009, AK60_6, AK70_10)}
