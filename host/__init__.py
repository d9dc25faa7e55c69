"""servodyn: closed-form inverse and direct dynamics for a servo-driven humanoid arm.

    >>> import servodyn
    >>> arm = servodyn.load_model("human_arm")
    >>> tau = arm.inverse_dynamics(q, qd, qdd)        # recursive Newton-Euler, in C
    >>> qdd = arm.forward_dynamics(q, qd, tau)        # Armstrong-Green recursion, in C
    >>> q, qd = arm.step(q, qd, tau, 1e-3, "rk4")

The package is layered; each layer imports only the ones above it in this list (layers on one
line do not import each other; pyproject.toml's import-linter contracts hold it):
    servodyn.errors           the one error tree and its exit codes
    servodyn._core, _core32   the C core's binding (double and float builds)
    servodyn.model            rigid-body trees, model files, URDF, rotations, inverse kinematics
    servodyn.control          trajectories, keyframe motions, the controller, gain schedules, timing
    servodyn.hal | mocap      servo buses (the interface, configurations, Dynamixel, CAN, loopback,
                              bring-up); captured motion (BVH, skeletons, retargeting)
    servodyn.sim | validation | identification
                              simulated servos, buses and plant behind the same wire protocols;
                              offline validation and sizing; identification from run logs
    servodyn.loop             the control tick, the run, the log
    servodyn.tools            the commands and the CLI; tools.bench, the benchmarks
"""

from __future__ import annotations

from .model import Body, Dof, Model, ModelError, builtin_models, load_model

__version__ = "0.1.0"

__all__ = ["Body", "Dof", "Model", "ModelError", "builtin_models", "load_model"]
