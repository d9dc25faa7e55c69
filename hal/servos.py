"""What every servo's data sheet says, in SI: the fields the configuration, the HAL, the simulator
and the offline validator need whatever wire the servo speaks. A backend's catalogue subclasses
`ServoSpec` with its own registers and units (`hal/dynamixel/control_table.py`).

The motor is a DC motor behind a gear (output-referred, at the horn): at supply voltage V its
no-load speed ω₀(V) and stall torque τ_s(V) come from the data sheet's rows at the voltages it
lists (ROBOTIS: 11.1, 12 and 14.8 V), linear between them and in proportion to V beyond; driving,
|τ| ≤ τ_s(V)·(1 − |ω|/ω₀(V)). The winding resistance R = V_nom/I_stall at the nominal voltage.
The current it draws is I = τ/K_t + I₀ (I₀ the no-load current), and its winding heats as a
first-order body: C_th·dT/dt = I²·R·(1 + α(T − 25 °C)) − (T − T_amb)/R_th, τ_th = R_th·C_th."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RPM = 2.0 * math.pi / 60.0          # rad/s per rpm


@dataclass(frozen=True, kw_only=True)
class ServoSpec:
    """A servo model at its nominal supply voltage; torque and speed at the horn (its output)."""
    name: str
    kind: str                     # the bus kind that speaks to it
    gear_ratio: float             # the servo's internal reduction (the horn is its output)
    stall_torque: float           # N m
    stall_current: float          # A
    no_load_speed_rpm: float      # rpm
    nominal_voltage: float = 12.0  # V
    no_load_current: float = 0.0  # A drawn with no load (friction, iron losses)
    temperature_limit: float = 80.0      # °C: over it the servo faults
    thermal_resistance: float = 0.0      # K/W, winding to ambient (0: not modelled)
    thermal_time_constant: float = 0.0   # s, R_th·C_th
    # the data sheet's rows at other supply voltages: (V, stall torque N m, stall current A,
    # no-load speed rpm); the nominal row above counts as one of them
    ratings: tuple[tuple[float, float, float, float], ...] = ()
    # what the backend needs of it to drive it as it drives the others: a torque (current)
    # command. A servo without one (a position-only servo) is in the catalogue for sizing's
    # report but never chosen or accepted as a joint.
    current_control: bool = True
    # V: the supply range the data sheet allows (min, max); a supply outside it burns or browns
    # out the servo. None: not published (then only the nominal voltage is known safe).
    supply_range: tuple[float, float] | None = None

    @property
    def datasheet_torque_constant(self) -> float:
        """N m per A at the horn the data sheet implies: stall torque / stall current (gear losses at
        stall included); what the validator judges against (hal.motor.MotorModel.from_datasheet)."""
        return self.stall_torque / self.stall_current

    @property
    def torque_constant(self) -> float:
        """Default N m per A at the horn, what converts a current the servo reads into torque: the
        data sheet's (calibrate per joint), or an identified motor's where the servo's entry says so."""
        return self.datasheet_torque_constant

    @property
    def no_load_speed(self) -> float:
        """rad/s at the horn."""
        return self.no_load_speed_rpm * RPM

    @property
    def winding_resistance(self) -> float:
        """Ω at 25 °C: what limits the stall current at the nominal voltage."""
        return self.nominal_voltage / self.stall_current

    def _rows(self) -> np.ndarray:
        rows = {self.nominal_voltage: (self.stall_torque, self.stall_current, self.no_load_speed_rpm)}
        rows.update({v: (t, i, w) for v, t, i, w in self.ratings})
        return np.array([(v, *rows[v]) for v in sorted(rows)])

    def _at(self, voltage: float, column: int) -> float:
        """A data-sheet figure at `voltage`: linear between the data sheet's rows, and beyond
        them in proportion to the voltage from the nearest row (a DC motor's speed and stall
        torque scale with its voltage)."""
        rows = self._rows()
        if voltage < rows[0, 0]:
            return float(rows[0, column] * voltage / rows[0, 0])
        if voltage > rows[-1, 0]:
            return float(rows[-1, column] * voltage / rows[-1, 0])
        return float(np.interp(voltage, rows[:, 0], rows[:, column]))

    def no_load_speed_at(self, voltage: float) -> float:
        """rad/s at the horn with no load, at supply `voltage`."""
        return self._at(voltage, 3) * RPM

    def stall_torque_at(self, voltage: float) -> float:
        """N m at the horn at stall, at supply `voltage`."""
        return self._at(voltage, 1)

    @property
    def max_current(self) -> float:
        """A: the largest current limit the servo accepts (its register's range)."""
        return self.stall_current
