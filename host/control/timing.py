"""The loop's timing and stiffness, defined once: the host loop, the simulated plant, the firmware's
generated tables (`servodyn codegen`), the experiments and the demo all read them from here."""

SMALL_TIME_STEP = 1e-3   # s: the control period (one servo read and write) and the plant's RK4 step
TIME_STEP = 1e-2         # s: the inverse dynamics period (paper: ~10 small steps), held in between
BANDWIDTH = 20.0         # rad/s of each joint's PD on its own inertia, at least
MAX_BANDWIDTH = 100.0    # rad/s: at 1 kHz the discrete loop keeps its damping up to about here
MIN_STIFFNESS = 2.0      # N m/rad: a servo's friction (~0.02 N m) then leaves ~0.01 rad of error
HOME_DURATION = 2.0      # s to move from wherever the arm is to a motion's start pose
GAIN_PERIOD = 0.1        # s between two knots of a gain schedule (on the played, scaled clock)
BUS_WATCHDOG = 0.1       # s of bus silence after which the servos drop torque by themselves
