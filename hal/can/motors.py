"""The CAN motors servodyn knows: each one's data sheet in SI at its output shaft, and the MIT
ranges its firmware uses by default (a Damiao motor keeps them in registers PMAX, VMAX, TMAX).

Sources, each entry's own `source` saying which figure comes from where: Damiao's instruction
manuals (the characteristics table on the last page; the PDFs in Damiao's dmBots/DM-J* repositories
and its documentation wiki), Seeed's Damiao wiki for the DM-J4310's and DM-J4340's torque constant
and phase resistance, the vendor's MIT defaults as openarm_can's dm_motor_constants.hpp has them;
CubeMars' "AK Series Module Driver User Manual" V1.0.15.X (its driver's supply range, section 1.1;
the MIT ranges of every AK model, section 5.3) and CubeMars' product pages. Neither vendor gives
thermal figures: the thermal resistance and time constant below are estimates for a motor of the
size in a closed housing (marked so), good enough for the simulator's over-temperature fault, not
for sizing a motor. A motor's mass and size are the model's (host/model/parts.toml: the solid its
housing is in a model of the arm).

Torque constant (output side): the vendor's where it publishes one (Damiao via Seeed; CubeMars'
motor Kt x gear ratio); where it does not (the DM-J6006's and DM-J8009's manuals), the manual's peak
torque / peak current. stall_current is then peak torque / Kt. CubeMars' phase resistance is its
"phase-to-phase" (line-to-line) figure, Damiao's its phase resistance, each as printed.
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

# CubeMars' driver (every AK model's): "Maximum Allowed Voltage 18 ~ 52V", AK Series Module Driver
# User Manual V1.0.15.X, section 1.1 (the AK60-6 V1.1's product page rates it at 24 V only, so its
# range is left unpublished)
_AK_DRIVER_SUPPLY = (18.0, 52.0)

AK80_9 = MotorSpec(
    name="AK80-9", kind="can", dialect="cubemars", gear_ratio=9.0,
    stall_torque=18.0, stall_current=18.0 / 0.819, no_load_speed_rpm=390.0, nominal_voltage=48.0,
    rated_torque=9.0, phase_resistance=0.17, supply_range=_AK_DRIVER_SUPPLY,
    temperature_limit=100.0, thermal_resistance=2.0, thermal_time_constant=500.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=50.0, t_max=18.0),
    source="CubeMars AK80-9 manual: rated 9 N m, peak 18 N m, gear 9, Kt 0.091 N m/A x 9, "
           "MIT 12.5 / 50 / 18 (AK Series Module Driver User Manual V1.0.15.X, 5.3); phase-to-phase "
           "R 0.17 ohm (CubeMars' AK80-9 KV100 data sheet, goods.php?id=982); supply 18-52 V (the "
           "driver manual, 1.1). No-load 390 rpm at 48 V: an ESTIMATE from below, CubeMars' rated "
           "speed (its AK80-9 V3.0 page: rated 390, no-load 570 rpm, peak 22 N m); the no-load speed "
           "of this MIT-firmware 18 N m AK80-9 was not found")

DM_J6006 = MotorSpec(
    name="DM-J6006", kind="can", dialect="damiao", gear_ratio=6.0,
    stall_torque=12.0, stall_current=13.0, no_load_speed_rpm=240.0, nominal_voltage=24.0,
    rated_torque=4.0, phase_resistance=0.33, supply_range=(24.0, 48.0),
    temperature_limit=100.0, thermal_resistance=2.5, thermal_time_constant=500.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=45.0, t_max=20.0),
    source="Damiao DM-J6006-2EC user manual V1.0 (2023-07-10, dmBots/DM-J6006-2EC), characteristics "
           "table: rated 24 V (supports 24-48 V), rated 4 A / 4 N m, peak 13 A / 12 N m, rated 150 rpm, "
           "no-load 240 rpm, gear 6:1, 14 pole pairs, phase R 0.33 ohm, L 305 uH (25 C); Kt 12 / 13 = "
           "0.92 N m/A (peak torque / peak current: the manual gives no Kt); MIT 12.5 / 45 / 20 "
           "(openarm_can dm_motor_constants.hpp, DM6006)")

DM_J8009 = MotorSpec(
    name="DM-J8009", kind="can", dialect="damiao", gear_ratio=9.0,
    stall_torque=40.0, stall_current=50.0, no_load_speed_rpm=160.0, nominal_voltage=24.0,
    ratings=((48.0, 40.0, 50.0, 320.0),),
    rated_torque=20.0, phase_resistance=0.09, supply_range=(24.0, 48.0),
    temperature_limit=100.0, thermal_resistance=1.5, thermal_time_constant=700.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=45.0, t_max=54.0),
    source="Damiao DM-J8009-2EC user manual V1.0 (dmBots/DM-J8009-2EC), characteristics table: rated "
           "24 V (supports 24-48 V), rated 20 A / 20 N m, peak 50 A / 40 N m, rated 100 rpm at 24 V "
           "(200 at 48 V), no-load 160 rpm at 24 V (320 at 48 V), gear 9:1, 21 pole pairs, phase R "
           "0.09 ohm, L 61 uH (25 C; the DM-J8009P's manual: 0.145 ohm, 80 uH); Kt 40 / 50 = 0.8 N m/A "
           "(peak torque / peak current: the manual gives no Kt); MIT 12.5 / 45 / 54 (openarm_can "
           "dm_motor_constants.hpp, DM8009)")

AK60_6 = MotorSpec(
    name="AK60-6", kind="can", dialect="cubemars", gear_ratio=6.0,
    stall_torque=9.0, stall_current=9.0 / (0.078 * 6), no_load_speed_rpm=320.0, nominal_voltage=24.0,
    rated_torque=3.0, phase_resistance=0.202,
    temperature_limit=100.0, thermal_resistance=2.5, thermal_time_constant=500.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=45.0, t_max=15.0),
    source="CubeMars AK60-6 V1.1 KV80 product page (cubemars.com/product/ak60-6-v1-1-kv80-robotic-"
           "actuator.html, as transcribed in nathmo/highTorqueDensityMotorReview research/"
           "cubemars_rich.csv): 24 V, rated 3 N m / 3.8 A, peak 9 N m / 13.1 A (DC), rated 233 rpm, "
           "no-load 320 rpm, gear 6:1, motor Kt 0.078 N m/A (x 6 at the output), phase-to-phase R "
           "0.202 ohm, 14 pole pairs; MIT 12.5 / 45 / 15 (AK Series Module Driver User Manual "
           "V1.0.15.X, 5.3: the AK60-6's speed range changed to 45 in V1.0.6; older firmware 50)")

AK70_10 = MotorSpec(
    name="AK70-10", kind="can", dialect="cubemars", gear_ratio=10.0,
    stall_torque=24.8, stall_current=24.8 / (0.123 * 10), no_load_speed_rpm=240.0, nominal_voltage=24.0,
    ratings=((48.0, 24.8, 24.8 / (0.123 * 10), 480.0),),
    rated_torque=8.3, phase_resistance=0.272, supply_range=_AK_DRIVER_SUPPLY,
    temperature_limit=100.0, thermal_resistance=2.5, thermal_time_constant=500.0,   # thermal: estimates
    ranges=Ranges(p_max=12.5, v_max=50.0, t_max=25.0),
    source="CubeMars AK70-10 KV100 product page (cubemars.com/product/ak70-10-kv100-robotic-actuator."
           "html, as transcribed in nathmo/highTorqueDensityMotorReview research/cubemars_rich.csv): "
           "24/48 V, rated 8.3 N m / 7.2 A, peak 24.8 N m / 23.2 A (DC), rated 148/310 rpm, no-load "
           "240/480 rpm, gear 10:1, motor Kt 0.123 N m/A (x 10 at the output), phase-to-phase R "
           "0.272 ohm, 21 pole pairs; supply 18-52 V (the driver manual, 1.1); MIT 12.5 / 50 / 25 "
           "(AK Series Module Driver User Manual V1.0.15.X, 5.3)")

MOTORS = {m.name: m for m in (DM_J4340, DM_J4310, AK80_9, DM_J6006, DM_J8009, AK60_6, AK70_10)}
