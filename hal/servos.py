"""What every servo's data sheet says, in SI: the fields the configuration, the HAL, the simulator
and the offline validator need whatever wire the servo speaks. A backend's catalogue subclasses
`ServoSpec` with its own registers and units (`hal/dynamixel/control_table.py`).

The motor is a DC motor behind a gear (output-referred, at the horn): at supply voltage V its
no-load speed is ω₀(V) = ω₀·V/V_nom and its stall torque τ_s(V) = τ_s·V/V_nom (the winding
resistance R = V_nom/I_stall fixes the stall current, I_s = V/R); driving, |τ| ≤ τ_s(V)·(1 − |ω|/ω₀(V)).
The current it draws is I = τ/K_t + I₀ (I₀ the no-load current), and its winding heats as a
first-order body: C_th·dT/dt = I²·R·(1 + α(T − 25 °C)) − (T − T_amb)/R_th, τ_th = R_th·C_th."""

from __future__ import annotations

import math
from dataclasses import dataclass

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

    @property
    def torque_constant(self) -> float:
        """Default N m per A at the horn: stall torque / stall current (calibrate per joint)."""
        return self.stall_torque / self.stall_current

    @property
    def no_load_speed(self) -> float:
        """rad/s at the horn."""
        return self.no_load_speed_rpm * RPM

    @property
    def winding_resistance(self) -> float:
        """Ω at 25 °C: what limits the stall current at the nominal voltage."""
        return self.nominal_voltage / self.stall_current

    def no_load_speed_at(self, voltage: float) -> float:
        """rad/s at the horn with no load, at supply `voltage`."""
        return self.no_load_speed * voltage / self.nominal_voltage

    def stall_torque_at(self, voltage: float) -> float:
        """N m at the horn at stall, at supply `voltage`."""
        return self.stall_torque * voltage / self.nominal_voltage

    @property
    def max_current(self) -> float:
        """A: the largest current limit the servo accepts (its register's range)."""
        return self.stall_current
