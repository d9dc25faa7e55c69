"""Servos without current control driven by their torque through PWM: the simulated servo's every
operating mode against its firmware's law, written here from the e-manual and the data sheet (not
from hal/motor.py), the measured XL330 gain scaling, the HAL's duty from the controller's torque, the
validator's saturation against the simulator's, and the built-in configuration replica_pwm."""

import math

import pytest

from servodyn.hal.dynamixel.control_table import (PWM_FULL, TICKS_PER_REV, VELOCITY_UNIT, XL330_M288, XL430_W250,
                                                  XM430_W350, OperatingMode)
from servodyn.hal.servos import RPM
from servodyn.sim.dynamixel import Servo
from servodyn.hal.dynamixel import ErrorNumber, pack_field

DT = 1e-3                         # one step of the plant, s: the firmware's sample (drive.CONTROL_PERIOD)
MODES = [OperatingMode.CURRENT, OperatingMode.VELOCITY, OperatingMode.POSITION, OperatingMode.EXTENDED_POSITION,
         OperatingMode.CURRENT_POSITION, OperatingMode.PWM]
MODELS = [XM430_W350, XL330_M288, XL430_W250]


def le(value: int, size: int) -> bytes:
    return pack_field(value, size, signed=True)


def datasheet_current(model, duty: float, speed: float) -> float:
    """BAM's DC motor at the data sheet's nominal row, from the data sheet alone: R = V / I_stall,
    k_e = V / ω₀, I = (d·V − k_e·ω) / R."""
    volts = model.nominal_voltage
    resistance, back_emf = volts / model.stall_current, volts / (model.no_load_speed_rpm * RPM)
    return (duty * volts - back_emf * speed) / resistance


def servo_in(model, mode) -> Servo:
    servo = Servo(model, supply_voltage=model.nominal_voltage, temperature=25.0)
    servo.write(11, bytes([mode]))
    servo.write(64, bytes([1]))
    return servo


def test_xl330_present_pwm_follows_p_over_256():
    """A real XL330's Present PWM = P/256 × error in ticks (data/servo-logs/xl330-pendulum, within 0.8 %
    on 12 of 16 recordings): the simulated one's, at every P gain the recordings used."""
    for p_gain in (100, 200, 400, 800):
        servo = servo_in(XL330_M288, OperatingMode.POSITION)
        servo.write(84, le(p_gain, 2))
        servo.write(116, le(TICKS_PER_REV // 2 + 150, 4))       # 150 ticks ahead of the horn at 0 rad
        servo.output_current(0.0, 0.0, DT)
        assert servo.get("present_pwm") == round(p_gain / 256 * 150), f"P = {p_gain}: P/256 x 150 ticks, not P/128"


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.name.lower())
def test_each_mode_follows_its_firmware_law(model, mode):
    """Each mode's output (the motor current and Present PWM) for one state is the e-manual's law over
    the data sheet's DC motor, to 1e-9 A; a mode the servo has not is refused (data range)."""
    if mode not in model.operating_modes:
        servo = Servo(model)
        with pytest.raises(Exception) as refused:
            servo.write(11, bytes([mode]))
        assert getattr(refused.value, "error_number", None) == ErrorNumber.DATA_RANGE, f"{model.name} has no {mode.name} mode"
        return
    servo = servo_in(model, mode)
    speed = 0.3 * model.no_load_speed_rpm * RPM            # rad/s at the horn: a third of its no-load speed
    ticks = speed * TICKS_PER_REV / (2 * math.pi)           # the same in ticks/s
    if mode == OperatingMode.CURRENT:
        servo.write(102, le(200, 2))
        amps = 200 * model.current_unit
        duty = None
    elif mode == OperatingMode.VELOCITY:
        goal = 40                                           # velocity units
        servo.write(104, le(goal, 4))
        error = goal - speed / VELOCITY_UNIT
        duty = (100 / 128 * error + 1920 / 65536 * error) / PWM_FULL   # P 100, I 1920 (defaults), one sample
    elif mode == OperatingMode.PWM:
        servo.write(100, le(-600, 2))
        duty = -600 / PWM_FULL
    else:
        goal = TICKS_PER_REV // 2 + (9000 if mode == OperatingMode.EXTENDED_POSITION else 90)
        servo.write(116, le(goal, 4))
        servo.write(80, le(16, 2))                           # D = 16: KD = 1, acting on the measured speed
        law = min(PWM_FULL, 800 / model.p_gain_divisor * (goal - TICKS_PER_REV // 2) - ticks * 1e-3)
        if mode == OperatingMode.CURRENT_POSITION:
            amps, duty = min(law, model.current_limit_max) * model.current_unit, None
        else:
            duty = law / PWM_FULL
    got = servo.output_current(0.0, speed, DT)
    want = datasheet_current(model, duty, speed) if duty is not None else amps
    assert got == pytest.approx(want, abs=1e-9), f"{model.name} {mode.name}: the firmware's law"
    if duty is None:                                         # a current loop: the duty its demand takes
        volts = model.nominal_voltage
        duty = (amps * volts / model.stall_current + volts / (model.no_load_speed_rpm * RPM) * speed) / volts
    assert servo.get("present_pwm") == round(duty * PWM_FULL), f"{model.name} {mode.name}: Present PWM"


def test_pwm_mode_obeys_pwm_limit_and_the_watchdog():
    """PWM Limit(36) bounds Goal PWM (a data limit error beyond it); a tripped Bus Watchdog drops Goal PWM to 0."""
    servo = Servo(XL430_W250, supply_voltage=12.0)
    servo.write(11, bytes([OperatingMode.PWM]))
    servo.write(36, le(400, 2))
    servo.write(64, bytes([1]))
    with pytest.raises(Exception) as refused:
        servo.write(100, le(401, 2))
    assert getattr(refused.value, "error_number", None) == ErrorNumber.DATA_LIMIT, "beyond PWM Limit"
    servo.write(100, le(400, 2))
    servo.write(98, bytes([1]))                              # 20 ms
    servo.heard(0.0)
    servo.clock(0.05)
    assert servo.get("goal_pwm") == 0 and servo.output_current(0.0, 0.0, DT) == 0.0, "watchdog: no drive"
