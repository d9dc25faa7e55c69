"""Motion and control: trajectories and keyframe motions, closed-form control (the C core's
controller step), homing and gain schedules, and the loop's timing.

    >>> from servodyn.control import ControlConfig, Controller
    >>> from servodyn.control.motion import load_motion
"""

from .controller import DEFAULT_MODE, MODES, ControlConfig, ControlFault, Controller, RunResult

__all__ = ["DEFAULT_MODE", "MODES", "ControlConfig", "ControlFault", "Controller", "RunResult"]
