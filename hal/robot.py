"""The robot: every bus of a configuration behind one interface, in the model's dof order — as
ros2_control's controller manager runs several hardware interfaces in one loop.

    with Robot(load_config("replica_mixed"), options={"wrist": {"port": "/dev/ttyUSB0"}}) as robot:
        robot.enable_torque(True)
        state = robot.read_state()       # every bus read, one state for all dofs
        robot.write(JointCommand.torque(tau))   # every bus written
        robot.stop()                     # the safe stop on every bus, whatever failed; never raises

A tick is one read of every bus, one control step, one write of every bus. A failure on any bus
raises as that bus raised it; the caller's stop() then stops them all.
"""

from __future__ import annotations

import threading

import numpy as np

from .bus import BusStats, JointCommand, JointState, ServoBus, make_bus


class Robot:
    def __init__(self, config, options: dict | None = None, **common):
        """options: bus name -> that backend's keyword options; common: options for every bus."""
        options = options or {}
        self.config = config
        self.buses: dict[str, ServoBus] = {name: make_bus(config, name, **{**common, **options.get(name, {})})
                                           for name in config.buses}
        self.dof_names = tuple(config.model.dof_names)
        self.n = len(self.dof_names)
        self._reads = self._writes = 0
        # one bus holding every dof in the model's order: its states and commands are the robot's
        # as they are, without a copy into the robot's order
        only = next(iter(self.buses.values())) if len(self.buses) == 1 else None
        self._only = only if only is not None and list(only.dof_index) == list(range(self.n)) else None

    @property
    def stats(self) -> BusStats:
        limited = np.zeros(self.n, dtype=np.int64)
        retried = 0
        for bus in self.buses.values():
            limited[bus.dof_index] += bus.stats.limited
            retried += bus.stats.reads_retried
        return BusStats(reads=self._reads, writes=self._writes, reads_retried=retried, limited=limited)

    def open(self) -> None:
        try:
            for bus in self.buses.values():
                bus.open()
        except BaseException:
            self.stop()
            raise

    def close(self) -> None:
        for bus in self.buses.values():
            bus.close()

    def __enter__(self) -> "Robot":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def enable_torque(self, on: bool) -> None:
        for bus in self.buses.values():
            bus.enable_torque(on)

    def read_state(self) -> JointState:
        if self._only is not None:
            state = self._only.read_state()
            self._reads += 1
            return state
        q, qd, current, tau = (np.zeros(self.n) for _ in range(4))
        temperature = np.full(self.n, np.nan)
        read = False                       # whether any bus reads temperatures
        t = 0.0
        for bus in self.buses.values():
            s = bus.read_state()
            k = bus.dof_index
            q[k], qd[k], current[k], tau[k] = s.q, s.qd, s.current, s.tau
            if s.temperature is not None:
                temperature[k], read = s.temperature, True
            t = max(t, s.t)
        self._reads += 1
        return JointState(t=t, q=q, qd=qd, current=current, tau=tau, temperature=temperature if read else None)

    def write(self, command: JointCommand) -> None:
        if command.q.shape != (self.n,):
            raise ValueError(f"JointCommand for {command.q.shape[0]} joints, the robot has {self.n}")
        if self._only is not None:
            self._only.write(command)
            self._writes += 1
            return
        for bus in self.buses.values():
            k = bus.dof_index
            bus.write(JointCommand(q=command.q[k], qd=command.qd[k], tau_ff=command.tau_ff[k], kp=command.kp[k],
                                   kd=command.kd[k]))
        self._writes += 1

    def stop(self) -> bool:
        """The safe stop on every bus at once (each never raises); True if every device confirmed.
        One thread a bus: a bus that is dead or stalled waits out its own time-outs (seconds, on a
        Dynamixel bus's retries) while the others' torque goes off now, within their devices'
        watchdog time (BUS_WATCHDOG); buses not known lost are started first."""
        buses = sorted(self.buses.values(), key=lambda bus: bus.lost is not None)
        if len(buses) == 1:
            return buses[0].stop()
        done = [False] * len(buses)

        def stop(k):
            done[k] = buses[k].stop()
        threads = [threading.Thread(target=stop, args=(k,), name=f"servodyn-stop-{bus.bus.name}", daemon=True)
                   for k, bus in enumerate(buses)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        return all(done)
